//! Scoring a render or a particle set against the truth, shared by the evaluation, the
//! novel-view baselines and the initial particles: images as the metrics see them, views at the
//! evaluated scale, the frames scored, and the particle pictures that show d.

use anyhow::Context;
use neurofluid_core::camera::Camera;
use neurofluid_core::metrics::{
    Lpips, RgbImage, error_share_on, gt_to_pred_distance, nearest_distances, psnr, ssim,
};

use super::views::ViewFrame;
use crate::pictures::{TRUTH_COLOUR, particle_view, row_of, viridis};
use crate::report::ImageScore;
use crate::trainer::Picture;

/// An image of the renderer's fine output as [`RgbImage`] (8-bit quantised, as saved PNGs are).
pub(crate) fn as_image(width: u32, height: u32, rgb: &[f32]) -> anyhow::Result<RgbImage> {
    Ok(RgbImage::new(width as usize, height as usize, rgb.to_vec())?.quantised())
}

/// A view's truth at the evaluated scale: the camera, the image as the metrics see it and its
/// coverage (the alpha, one value per pixel).
pub(crate) struct ScaledTruth {
    /// The camera at the evaluated size.
    pub camera: Camera,
    /// The ground truth composited on white, 8-bit quantised.
    pub image: RgbImage,
    /// Where the truth shows fluid: its alpha.
    pub coverage: Vec<f32>,
}

/// The truth of a view at `scale` × its resolution (the image and its alpha resampled with a
/// triangle filter; unchanged at scale 1).
pub(crate) fn scaled_truth(view: &ViewFrame, scale: f64) -> anyhow::Result<ScaledTruth> {
    let cam = view.camera;
    let (camera, rgb, coverage) = if (scale - 1.0).abs() < 1e-12 {
        (cam, view.image.rgb.clone(), view.image.alpha.clone())
    } else {
        let w = ((cam.width as f64 * scale).round() as u32).max(1);
        let h = ((cam.height as f64 * scale).round() as u32).max(1);
        let resize = |data: Vec<f32>, channels: usize| -> anyhow::Result<Vec<f32>> {
            let luma = |d| {
                image::ImageBuffer::<image::Luma<f32>, Vec<f32>>::from_raw(cam.width, cam.height, d)
            };
            let filter = image::imageops::FilterType::Triangle;
            Ok(if channels == 3 {
                let full = image::Rgb32FImage::from_raw(cam.width, cam.height, data)
                    .context("an image of its camera's size")?;
                image::imageops::resize(&full, w, h, filter).into_raw()
            } else {
                let full = luma(data).context("an alpha of its camera's size")?;
                image::imageops::resize(&full, w, h, filter).into_raw()
            })
        };
        (
            cam.resized(w, h),
            resize(view.image.rgb.clone(), 3)?,
            resize(view.image.alpha.clone(), 1)?,
        )
    };
    Ok(ScaledTruth {
        image: as_image(camera.width, camera.height, &rgb)?,
        camera,
        coverage,
    })
}

/// PSNR, SSIM and LPIPS of a render against the truth (LPIPS absent for images too small for
/// AlexNet) and the share of its error on the truth's fluid.
pub(crate) fn score(
    view: &str,
    t: usize,
    pred: &RgbImage,
    truth: &ScaledTruth,
    lpips: &Lpips,
) -> anyhow::Result<ImageScore> {
    let image = &truth.image;
    Ok(ImageScore {
        view: view.into(),
        t,
        psnr: psnr(pred, image)?,
        ssim: ssim(pred, image).unwrap_or(f64::NAN),
        lpips: lpips.distance(pred, image).ok(),
        error_on_fluid: error_share_on(pred, image, &truth.coverage)?,
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
