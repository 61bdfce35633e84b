//! Scoring a render or a particle set against the truth, shared by the evaluation, the
//! novel-view baselines and the initial particles: images as the metrics see them, views at the
//! evaluated scale, the frames scored and pictured, and the particle pictures that show d.

use anyhow::Context;
use neurofluid_core::camera::Camera;
use neurofluid_core::metrics::{
    Lpips, RgbImage, error_share_on, gt_to_pred_distance, nearest_distances, psnr, ssim,
};

use neurofluid_core::scene::Image;

use crate::pictures::{Picture, TRUTH_COLOUR, particle_view, row_of, viridis};
use crate::report::ImageScore;

/// An image of the renderer's fine output as [`RgbImage`] (8-bit quantised, as saved PNGs are).
pub fn as_image(width: u32, height: u32, rgb: &[f32]) -> anyhow::Result<RgbImage> {
    Ok(RgbImage::new(width as usize, height as usize, rgb.to_vec())?.quantised())
}

/// A view's truth at the evaluated scale: the camera, the image as the metrics see it and its
/// coverage (the alpha, one value per pixel).
pub struct ScaledTruth {
    /// The camera at the evaluated size.
    pub camera: Camera,
    /// The ground truth composited on white, 8-bit quantised.
    pub image: RgbImage,
    /// Where the truth shows fluid: its alpha.
    pub coverage: Vec<f32>,
}

/// The truth of a view, seen by `cam` as `image`, at `scale` × its resolution (the image and its
/// alpha resampled with a triangle filter; unchanged at scale 1).
pub fn scaled_truth(cam: Camera, image: &Image, scale: f64) -> anyhow::Result<ScaledTruth> {
    let (camera, rgb, coverage) = if (scale - 1.0).abs() < 1e-12 {
        (cam, image.rgb.clone(), image.alpha.clone())
    } else {
        let w = ((cam.width as f64 * scale).round() as u32).max(1);
        let h = ((cam.height as f64 * scale).round() as u32).max(1);
        let (from, to) = ((cam.width, cam.height), (w, h));
        (
            cam.resized(w, h),
            resized::<image::Rgb<f32>>(image.rgb.clone(), from, to)?,
            resized::<image::Luma<f32>>(image.alpha.clone(), from, to)?,
        )
    };
    Ok(ScaledTruth {
        image: as_image(camera.width, camera.height, &rgb)?,
        camera,
        coverage,
    })
}

/// `data`, an image of `from` pixels of `P`, resampled to `to` with a triangle filter.
fn resized<P>(data: Vec<f32>, from: (u32, u32), to: (u32, u32)) -> anyhow::Result<Vec<f32>>
where
    P: image::Pixel<Subpixel = f32> + 'static,
{
    let full = image::ImageBuffer::<P, Vec<f32>>::from_raw(from.0, from.1, data)
        .context("an image of its camera's size")?;
    let filter = image::imageops::FilterType::Triangle;
    Ok(image::imageops::resize(&full, to.0, to.1, filter).into_raw())
}

/// PSNR, SSIM and LPIPS of a render against the truth (LPIPS absent for images too small for
/// AlexNet) and the share of its error on the truth's fluid (absent where the truth's alpha
/// covers every pixel, as for images without alpha: there is no "around it").
pub fn score(
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
        error_on_fluid: if truth.coverage.iter().all(|a| *a >= 0.5) {
            None
        } else {
            error_share_on(pred, image, &truth.coverage)?
        },
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

/// The frames the particle pictures show: the first predicted one, the last of the grounding
/// window and the last of the prediction window.
pub fn picture_frames(train_frames: usize, steps: usize) -> Vec<usize> {
    let mut t = vec![1, train_frames.saturating_sub(1), steps];
    t.retain(|&t| (1..=steps).contains(&t));
    t.dedup();
    t
}

/// The particle sets at frame `t` seen from `camera`: truth, then each prediction coloured by
/// its particles' distances to the nearest true particle (0 → 4 particle radii, viridis), with
/// its d in the label.
pub fn particle_row(
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
pub fn at_least_wide(camera: &Camera, width: u32) -> Camera {
    let k = (width as f32 / camera.width as f32).max(1.0);
    camera.resized(
        (camera.width as f32 * k).round() as u32,
        (camera.height as f32 * k).round() as u32,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// At half the resolution the alpha is resampled as the image is: a covered square stays
    /// where the image's coloured square is.
    #[test]
    fn the_truth_and_its_alpha_are_scaled_together() {
        let (w, h) = (8u32, 6u32);
        let inside = |x: u32, y: u32| (2..6).contains(&x) && (2..4).contains(&y);
        let mut rgb = Vec::new();
        let mut alpha = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let a = if inside(x, y) { 1.0 } else { 0.0 };
                rgb.extend([1.0 - 0.5 * a, 1.0 - 0.5 * a, 1.0]);
                alpha.push(a);
            }
        }
        let camera = Camera::look_at(w, h, 0.8, [0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0]);
        let image = Image {
            width: w,
            height: h,
            rgb,
            alpha,
        };
        let truth = scaled_truth(camera, &image, 0.5).unwrap();
        assert_eq!((truth.camera.width, truth.camera.height), (4, 3));
        assert_eq!(truth.coverage.len(), 12);
        for (p, a) in truth.coverage.iter().enumerate() {
            let red = truth.image.data[3 * p];
            assert_eq!(*a >= 0.5, red < 0.75, "pixel {p}: alpha {a}, red {red}");
        }
        assert!(truth.coverage.iter().any(|a| *a >= 0.5));
        assert!(truth.coverage.iter().any(|a| *a < 0.5));
    }
}
