//! Pictures while training: every `eval_every` iterations a stage renders one whole view with
//! the current renderer, saves `[render | ground truth]` as a PNG and logs the view's PSNR as a
//! metrics row of its own (`<stage>-preview`), which the curve plot shows as its own column.

use std::path::Path;

use burn::module::Module;
use burn::prelude::*;
use neurofluid_core::metrics::{RgbImage, psnr};
use neurofluid_physnerf::{PhysNerf, render_image, save_png};

use super::context::ViewFrame;
use crate::metrics_log::{MetricsLog, MetricsRow};

/// Renders `view` from `particles` (`[N, 3]`, any device), writes
/// `<dir>/<stage>_<step>.png` and appends the row `<stage>-preview` with the PSNR.
#[allow(clippy::too_many_arguments)]
pub fn preview(
    stage: &str,
    step: u64,
    renderer: &PhysNerf,
    view: &ViewFrame,
    particles: &Tensor<2>,
    chunk: usize,
    dir: &Path,
    elapsed_s: f64,
    log: &mut MetricsLog,
) -> anyhow::Result<f64> {
    let renderer = renderer.valid();
    let cam = &view.camera;
    let image = render_image(&renderer, cam, particles, chunk, &mut |_, _| {})?;
    let pred = RgbImage::new(
        cam.width as usize,
        cam.height as usize,
        image.best().to_vec(),
    )?;
    let gt = RgbImage::new(
        cam.width as usize,
        cam.height as usize,
        view.image.rgb.clone(),
    )?;
    let value = psnr(&pred, &gt)?;
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut side = Vec::with_capacity(2 * w * h * 3);
    for row in 0..h {
        side.extend_from_slice(&pred.data[row * w * 3..(row + 1) * w * 3]);
        side.extend_from_slice(&gt.data[row * w * 3..(row + 1) * w * 3]);
    }
    save_png(
        dir.join(format!("{stage}_{step:07}.png")),
        2 * cam.width,
        cam.height,
        &side,
    )?;
    let mse = 10f64.powf(-value / 10.0);
    let mut row = MetricsRow::new(&format!("{stage}-preview"), step, mse, elapsed_s);
    row.psnr = Some(value);
    log.append(&row)?;
    tracing::info!(stage, step, psnr = value, "preview");
    Ok(value)
}
