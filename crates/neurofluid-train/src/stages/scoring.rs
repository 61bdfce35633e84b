//! Scoring a render or a particle set against the truth, shared by the evaluation, the
//! novel-view baselines and the initial particles: images as the metrics see them, views at the
//! evaluated scale, the frames scored, and the particle pictures that show d.

use neurofluid_core::camera::Camera;
use neurofluid_core::metrics::{
    Lpips, RgbImage, gt_to_pred_distance, nearest_distances, psnr, ssim,
};

use super::views::ViewFrame;
use crate::pictures::{TRUTH_COLOUR, particle_view, row_of, viridis};
use crate::report::ImageScore;
use crate::trainer::Picture;

/// An image of the renderer's fine output as [`RgbImage`] (8-bit quantised, as saved PNGs are).
pub(crate) fn as_image(width: u32, height: u32, rgb: &[f32]) -> anyhow::Result<RgbImage> {
    Ok(RgbImage::new(width as usize, height as usize, rgb.to_vec())?.quantised())
}

/// The camera and ground-truth colours of a view at `scale` × its resolution (the ground truth
/// resampled with a triangle filter; unchanged at scale 1).
pub(crate) fn scaled_view(view: &ViewFrame, scale: f64) -> (Camera, Vec<f32>) {
    let cam = view.camera;
    if (scale - 1.0).abs() < 1e-12 {
        return (cam, view.image.rgb.clone());
    }
    let w = ((cam.width as f64 * scale).round() as u32).max(1);
    let h = ((cam.height as f64 * scale).round() as u32).max(1);
    let scaled = cam.resized(w, h);
    let full = image::Rgb32FImage::from_raw(cam.width, cam.height, view.image.rgb.clone())
        .expect("image size matches its camera");
    let small = image::imageops::resize(&full, w, h, image::imageops::FilterType::Triangle);
    (scaled, small.into_raw())
}

/// PSNR, SSIM and LPIPS of a render against the truth (LPIPS absent for images too small for
/// AlexNet).
pub(crate) fn score(
    view: &str,
    t: usize,
    pred: &RgbImage,
    truth: &RgbImage,
    lpips: &Lpips,
) -> anyhow::Result<ImageScore> {
    Ok(ImageScore {
        view: view.into(),
        t,
        psnr: psnr(pred, truth)?,
        ssim: ssim(pred, truth).unwrap_or(f64::NAN),
        lpips: lpips.distance(pred, truth).ok(),
    })
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

/// The particle sets at frame `t` seen from `camera`: truth, then each prediction coloured by
/// its particles' distances to the nearest true particle (0 → 4 particle radii, viridis), with
/// its d in the label.
pub(crate) fn particle_row(
    camera: &Camera,
    radius: f32,
    t: usize,
    truth: &[[f32; 3]],
    predictions: &[(&str, &[[f32; 3]])],
) -> Picture {
    let mut pictures = vec![(
        format!("truth t={t}"),
        particle_view(camera, truth, radius, |_| TRUTH_COLOUR),
    )];
    for (name, pred) in predictions {
        let d = nearest_distances(pred, truth);
        let colour =
            |i: usize| viridis(d.as_ref().map_or(f64::NAN, |d| d[i]) / (4.0 * radius as f64));
        let mean = gt_to_pred_distance(truth, pred).mean;
        pictures.push((
            format!("{name} d={mean:.1}"),
            particle_view(camera, pred, radius, colour),
        ));
    }
    let labelled: Vec<(&str, &Picture)> = pictures.iter().map(|(l, p)| (l.as_str(), p)).collect();
    row_of(&labelled)
}

/// `camera` enlarged (same view) to at least `width` pixels wide.
pub(crate) fn at_least_wide(camera: &Camera, width: u32) -> Camera {
    let k = (width as f32 / camera.width as f32).max(1.0);
    camera.resized(
        (camera.width as f32 * k).round() as u32,
        (camera.height as f32 * k).round() as u32,
    )
}
