//! Evaluation (spec §6): from the ground-truth state of the first test frame, roll the grounded
//! transition model and the DLF it started from (the baseline) out without feedback, and report
//! the particle distance d (GT→prediction nearest neighbour, ×1000) per frame, its mean over the
//! grounding window (t = 1 … T_train−1) and the prediction window (t = T_train … T_test−1),
//! PSNR/SSIM of the renders of the held-out views, renders beside ground truth (PNG) and the
//! predicted particles of every frame (PLY).

use anyhow::Context;
use burn::module::Module;
use neurofluid_core::camera::Camera;
use neurofluid_core::metrics::{RgbImage, gt_to_pred_distance, psnr, ssim};
use neurofluid_core::scene::Role;
use neurofluid_dlf::DlfNet;
use neurofluid_dlf::rollout::rollout;
use neurofluid_physnerf::{PhysNerf, render_image, save_png};

use super::joint::Grounded;
use super::run_folder::Run;
use super::views::{ViewFrame, check_sequence, points_tensor, side_by_side};
use crate::config::PlyEncoding;
use crate::ply::{PlyFormat, write_ply};
use crate::report::{EvalReport, FrameDistance, ImageScore, Windows};

/// Folder of the stage inside the run folder.
pub const STAGE: &str = "eval";

fn rollout_positions(
    run: &Run,
    net: &DlfNet,
    pos: &[[f32; 3]],
    vel: &[[f32; 3]],
    steps: usize,
    what: &str,
) -> anyhow::Result<Vec<Vec<[f32; 3]>>> {
    let net = net.valid();
    let b = run.scene.boundary()?;
    let boundary = net.boundary(&b.points, &b.normals, &net.device());
    let bar = indicatif::ProgressBar::new(steps as u64).with_prefix(what.to_string());
    let out = rollout(&net, pos, vel, &boundary, steps, |_| bar.inc(1));
    bar.finish_and_clear();
    Ok(out.pos)
}

/// An image of the renderer's fine output as [`RgbImage`] (8-bit quantised, as saved PNGs are).
fn as_image(width: u32, height: u32, rgb: &[f32]) -> anyhow::Result<RgbImage> {
    Ok(RgbImage::new(width as usize, height as usize, rgb.to_vec())?.quantised())
}

/// The camera and ground-truth colours of a view at `scale` × its resolution (the ground truth
/// resampled with a triangle filter; unchanged at scale 1).
fn scaled_view(view: &ViewFrame, scale: f64) -> (Camera, Vec<f32>) {
    let cam = view.camera;
    if (scale - 1.0).abs() < 1e-12 {
        return (cam, view.image.rgb.clone());
    }
    let w = ((cam.width as f64 * scale).round() as u32).max(1);
    let h = ((cam.height as f64 * scale).round() as u32).max(1);
    let scaled = Camera {
        width: w,
        height: h,
        focal: cam.focal * w as f32 / cam.width as f32,
        c2w: cam.c2w,
    };
    let full = image::Rgb32FImage::from_raw(cam.width, cam.height, view.image.rgb.clone())
        .expect("image size matches its camera");
    let small = image::imageops::resize(&full, w, h, image::imageops::FilterType::Triangle);
    (scaled, small.into_raw())
}

/// Renders `particles` from `view`, saves `[render | ground truth]` and scores it.
fn render_and_score(
    physnerf: &PhysNerf,
    view: &ViewFrame,
    particles: &[[f32; 3]],
    scale: f64,
    png: &std::path::Path,
) -> anyhow::Result<(f64, f64)> {
    let device = physnerf
        .devices()
        .into_iter()
        .next()
        .context("PhysNeRF has no device")?;
    let (cam, gt_rgb) = scaled_view(view, scale);
    let cam = &cam;
    let image = render_image(
        physnerf,
        cam,
        &points_tensor(particles, &device),
        physnerf.config.chunk,
        &mut |_, _| {},
    )?;
    let pred = as_image(cam.width, cam.height, image.best())?;
    let gt = as_image(cam.width, cam.height, &gt_rgb)?;
    let side = side_by_side(&pred, &gt);
    save_png(png, side.width, side.height, &side.rgb)?;
    Ok((psnr(&pred, &gt)?, ssim(&pred, &gt).unwrap_or(f64::NAN)))
}

/// The rollout steps rendered (of a test split of `frames` frames): every `every`-th and the
/// last.
pub fn rendered_steps(frames: usize, every: usize) -> Vec<usize> {
    let steps = frames.saturating_sub(1);
    let every = every.max(1);
    (1..=steps)
        .filter(|t| t % every == 0 || *t == steps)
        .collect()
}

/// Runs the evaluation, writes `eval/` and returns the report.
pub fn run(run: &Run, models: &Grounded) -> anyhow::Result<EvalReport> {
    let scene = &run.scene;
    let cfg = &run.exp.eval;
    let test = scene.frames(Role::Test);
    let train_len = scene.frames(Role::Train).len();
    let gt: Vec<_> = scene.particle_sequence(Role::Test)?;
    check_sequence(&gt, test.start).context("the test split's particles")?;
    let steps = test.len() - 1;
    tracing::info!(steps, "evaluating: rollouts from the first test frame");
    let grounded = rollout_positions(
        run,
        &models.dlf,
        &gt[0].pos,
        &gt[0].vel,
        steps,
        "NeuroFluid",
    )?;
    let baseline = if cfg.baseline {
        let net = run.load_dlf(&run.exp.dlf.weights)?;
        Some(rollout_positions(
            run, &net, &gt[0].pos, &gt[0].vel, steps, "DLF",
        )?)
    } else {
        None
    };
    let mut report = EvalReport::new(
        &run.exp.name,
        &scene.manifest().name,
        &run.stage_dir(super::joint::STAGE).display().to_string(),
        Windows::from_lengths(train_len, test.len()),
    );
    report.frames = (1..=steps)
        .map(|t| FrameDistance {
            t,
            neurofluid: gt_to_pred_distance(&gt[t].pos, &grounded[t]).mean,
            dlf: baseline
                .as_ref()
                .map(|b| gt_to_pred_distance(&gt[t].pos, &b[t]).mean),
        })
        .collect();

    let dir = run.stage_dir(STAGE);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    if cfg.write_ply {
        let format = match cfg.ply_format {
            PlyEncoding::Binary => PlyFormat::BinaryLittleEndian,
            PlyEncoding::Ascii => PlyFormat::Ascii,
        };
        for (t, pos) in grounded.iter().enumerate() {
            let path = dir.join(format!("particles/neurofluid_{t:04}.ply"));
            write_ply(&path, pos, None, format)?;
            if let Some(b) = &baseline {
                write_ply(
                    &dir.join(format!("particles/dlf_{t:04}.ply")),
                    &b[t],
                    None,
                    format,
                )?;
            }
        }
    }
    if cfg.render {
        let physnerf = models.physnerf.valid();
        let frames = rendered_steps(test.len(), cfg.render_every);
        let views = cfg
            .views
            .clone()
            .unwrap_or_else(|| scene.views(Role::Test).to_vec());
        for view in &views {
            let bar = indicatif::ProgressBar::new(frames.len() as u64)
                .with_prefix(format!("render {view}"));
            for &t in &frames {
                let vf = ViewFrame::load(scene, Role::Test, view, test.start + t)?;
                let png = dir.join(format!("renders/{view}/t{t:04}.png"));
                let (psnr, ssim) =
                    render_and_score(&physnerf, &vf, &grounded[t], cfg.image_scale, &png)?;
                report.images.push(ImageScore {
                    view: view.clone(),
                    t,
                    psnr,
                    ssim,
                });
                bar.inc(1);
            }
            bar.finish_and_clear();
        }
    }
    report.write_all(&dir)?;
    Ok(report)
}
