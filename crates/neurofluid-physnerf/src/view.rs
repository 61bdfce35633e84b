//! Whole-view rendering in ray chunks (bounded memory) and PNG output.

use std::path::Path;

use burn::prelude::*;
use neurofluid_core::camera::Camera;

use crate::error::{PhysNerfError, Result};
use crate::renderer::{PhysNerf, RayBatch, RenderOutput};

/// A rendered view: row-major RGB in [0, 1] (white background).
#[derive(Debug, Clone, PartialEq)]
pub struct RenderedImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `[H·W·3]` colours of the coarse pass.
    pub coarse: Vec<f32>,
    /// `[H·W·3]` colours of the fine pass (empty without a fine pass).
    pub fine: Vec<f32>,
}

impl RenderedImage {
    /// The fine colours when present, else the coarse ones.
    pub fn best(&self) -> &[f32] {
        if self.fine.is_empty() {
            &self.coarse
        } else {
            &self.fine
        }
    }
}

/// Renders every pixel of `camera` through `particles [N, 3]`, `chunk` rays at a time, without
/// gradients (the model and particles are taken off any autodiff device). Only the MLP inputs of
/// one chunk are alive at a time. `progress(done, total)` is called after every chunk.
pub fn render_image(
    model: &PhysNerf,
    camera: &Camera,
    particles: &Tensor<2>,
    chunk: usize,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<RenderedImage> {
    let model = model.valid();
    let particles = particles.clone().without_autodiff();
    render_image_with(camera, chunk, progress, &mut |rays| {
        model.render_rays(&particles, rays, None)
    })
}

/// Renders every pixel of `camera`, `chunk` rays at a time, with `render` (which renders one
/// chunk of rays, deterministically and without gradients).
pub fn render_image_with(
    camera: &Camera,
    chunk: usize,
    progress: &mut dyn FnMut(usize, usize),
    render: &mut dyn FnMut(&RayBatch) -> Result<RenderOutput>,
) -> Result<RenderedImage> {
    if chunk == 0 {
        return Err(PhysNerfError::Invalid(
            "ray chunk must be at least 1".into(),
        ));
    }
    let rays = RayBatch::from(&camera.all_rays());
    let n = rays.len();
    let mut coarse = Vec::with_capacity(n * 3);
    let mut fine = Vec::new();
    let mut start = 0;
    while start < n {
        let end = (start + chunk).min(n);
        let out = render(&rays.slice(start, end))?;
        let read = |t: Tensor<2>| {
            neurofluid_core::transfer::read_vec::<f32, 2, burn::tensor::Float>(t)
                .map_err(|e| PhysNerfError::Readback(format!("{e:?}")))
        };
        coarse.extend(read(out.coarse.rgb_map)?);
        if let Some(f) = out.fine {
            fine.extend(read(f.rgb_map)?);
        }
        start = end;
        progress(start, n);
    }
    Ok(RenderedImage {
        width: camera.width,
        height: camera.height,
        coarse,
        fine,
    })
}

/// Writes row-major RGB in [0, 1] as an 8-bit PNG, atomically. `rgb` must hold `width·height·3`
/// values; they are clamped and rounded.
pub fn save_png(path: impl AsRef<Path>, width: u32, height: u32, rgb: &[f32]) -> Result<()> {
    let path = path.as_ref();
    let err = |message: String| PhysNerfError::Image {
        path: path.to_path_buf(),
        message,
    };
    if rgb.len() != width as usize * height as usize * 3 {
        return Err(err(format!(
            "{} values for a {width}×{height} RGB image",
            rgb.len()
        )));
    }
    let bytes: Vec<u8> = rgb
        .iter()
        .map(|&v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    let mut png = Vec::new();
    image::write_buffer_with_format(
        &mut std::io::Cursor::new(&mut png),
        &bytes,
        width,
        height,
        image::ExtendedColorType::Rgb8,
        image::ImageFormat::Png,
    )
    .map_err(|e| err(e.to_string()))?;
    neurofluid_core::atomic::write_bytes(path, &png).map_err(|e| PhysNerfError::io(path, e))
}

impl RenderedImage {
    /// Coarse and fine renders side by side (`[2W wide]`), or the coarse one alone.
    pub fn side_by_side(&self) -> (u32, u32, Vec<f32>) {
        if self.fine.is_empty() {
            return (self.width, self.height, self.coarse.clone());
        }
        let w = self.width as usize;
        let mut out = Vec::with_capacity(self.coarse.len() * 2);
        for (c, f) in self.coarse.chunks(w * 3).zip(self.fine.chunks(w * 3)) {
            out.extend_from_slice(c);
            out.extend_from_slice(f);
        }
        (self.width * 2, self.height, out)
    }
}

impl PhysNerf {
    /// Renders every pixel of `camera` in chunks of `chunk` rays; see [`render_image`].
    pub fn render_image(
        &self,
        camera: &Camera,
        particles: &Tensor<2>,
        chunk: usize,
    ) -> Result<RenderedImage> {
        render_image(self, camera, particles, chunk, &mut |_, _| {})
    }
}
