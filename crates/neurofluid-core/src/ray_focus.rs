//! Where a ray can carry information about the particles: the pixels where the target image
//! shows fluid, and those the predicted particles cover once projected into the camera. Joint
//! training can draw a share of its rays from them (its `joint.foreground_rays`): with uniform
//! rays, most land on the white background, where truth and prediction agree and the image loss
//! says nothing about where the particles should go; rays where the truth has fluid and the
//! prediction has none, or the other way round, are the ones that can pull particles.

use crate::camera::Camera;
use crate::sampler::{Rng, SampleError};
use crate::scene::Image;

/// A pixel shows fluid when its coverage exceeds this, or, in an image without coverage, when a
/// channel is this far below the white background.
const FOREGROUND_LEVEL: f32 = 0.02;

/// The pixels (row-major indices) where `image` shows something in front of the white
/// background: coverage above 2 % where the image has an alpha channel, else a colour at
/// least 2 % off white.
pub fn image_foreground(image: &Image) -> Vec<bool> {
    let has_alpha = image.alpha.iter().any(|&a| a < 1.0);
    (0..image.width as usize * image.height as usize)
        .map(|p| {
            if has_alpha {
                image.alpha[p] > FOREGROUND_LEVEL
            } else {
                image.rgb[3 * p..3 * p + 3]
                    .iter()
                    .any(|&c| 1.0 - c > FOREGROUND_LEVEL)
            }
        })
        .collect()
}

/// Marks in `mask` (row-major, the camera's size) every pixel within the projected radius of a
/// particle of `radius` at each of `points`, plus one pixel (a particle smaller than a pixel
/// still marks the pixels around it).
pub fn mark_particles(mask: &mut [bool], camera: &Camera, points: &[[f32; 3]], radius: f32) {
    let (w, h) = (camera.width as i64, camera.height as i64);
    for &p in points {
        let Some((col, row, depth)) = camera.project(p) else {
            continue;
        };
        if !(col.is_finite() && row.is_finite()) {
            continue;
        }
        let r = (camera.fx.max(camera.fy) * radius / depth).max(0.0) + 1.0;
        let (c0, c1) = ((col - r).floor() as i64, (col + r).ceil() as i64);
        let (r0, r1) = ((row - r).floor() as i64, (row + r).ceil() as i64);
        if c1 < 0 || r1 < 0 || c0 >= w || r0 >= h {
            continue;
        }
        for y in r0.max(0)..=r1.min(h - 1) {
            for x in c0.max(0)..=c1.min(w - 1) {
                let (dx, dy) = (x as f32 - col, y as f32 - row);
                if dx * dx + dy * dy <= r * r {
                    mask[(y * w + x) as usize] = true;
                }
            }
        }
    }
}

/// The intersection over union of two masks of the same pixels (1 when both are empty).
pub fn mask_iou(a: &[bool], b: &[bool]) -> f64 {
    debug_assert_eq!(a.len(), b.len());
    let (mut inter, mut union) = (0usize, 0usize);
    for (&x, &y) in a.iter().zip(b) {
        inter += usize::from(x && y);
        union += usize::from(x || y);
    }
    if union == 0 {
        1.0
    } else {
        inter as f64 / union as f64
    }
}

/// `count` distinct pixels of a `width`×`height` image: `round(fraction · count)` of them (at
/// most as many as there are) from the pixels `mask` marks, the rest uniformly from all the
/// others. With `fraction = 0` exactly [`Rng::sample_pixels`] over the whole image.
pub fn sample_focused(
    rng: &mut Rng,
    count: usize,
    width: u32,
    height: u32,
    mask: &[bool],
    fraction: f64,
) -> Result<Vec<u32>, SampleError> {
    if fraction <= 0.0 {
        return rng.sample_pixels(count, width, height, None);
    }
    let total = width as usize * height as usize;
    if count > total {
        return Err(SampleError::TooMany {
            count,
            population: total,
        });
    }
    let focus: Vec<u32> = (0..total as u32).filter(|&p| mask[p as usize]).collect();
    let k = ((fraction * count as f64).round() as usize).min(focus.len());
    let mut out: Vec<u32> = rng
        .sample_indices(k, focus.len())?
        .into_iter()
        .map(|i| focus[i])
        .collect();
    // the rest from the pixels not drawn yet, uniformly
    let mut taken = vec![false; total];
    for &p in &out {
        taken[p as usize] = true;
    }
    let rest: Vec<u32> = (0..total as u32).filter(|&p| !taken[p as usize]).collect();
    out.extend(
        rng.sample_indices(count - k, rest.len())?
            .into_iter()
            .map(|i| rest[i]),
    );
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(size: u32) -> Camera {
        // at (0, 0, 4) looking down −z
        let c2w = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 4.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        Camera::from_angle_x(size, size, 0.7, c2w)
    }

    #[test]
    fn foreground_follows_coverage_or_colour() {
        let mut img = Image {
            width: 4,
            height: 1,
            rgb: vec![1.0; 12],
            alpha: vec![1.0; 4],
        };
        img.rgb[3] = 0.9; // pixel 1 off white
        assert_eq!(image_foreground(&img), [false, true, false, false]);
        img.alpha = vec![0.0, 0.0, 0.5, 0.01];
        assert_eq!(image_foreground(&img), [false, false, true, false]);
    }

    #[test]
    fn particles_mark_their_projected_discs() {
        let cam = camera(41);
        let mut mask = vec![false; 41 * 41];
        // on the optical axis: the centre pixel; radius 0.1 at depth 4
        mark_particles(&mut mask, &cam, &[[0.0, 0.0, 0.0]], 0.1);
        let (cx, cy) = (cam.cx, cam.cy);
        let r = cam.fx * 0.1 / 4.0 + 1.0;
        for y in 0..41 {
            for x in 0..41 {
                let inside = (x as f32 - cx).powi(2) + (y as f32 - cy).powi(2) <= r * r;
                assert_eq!(mask[y * 41 + x], inside, "({x}, {y})");
            }
        }
        // behind the camera or outside the image: nothing
        let mut other = vec![false; 41 * 41];
        mark_particles(&mut other, &cam, &[[0.0, 0.0, 5.0], [50.0, 0.0, 0.0]], 0.1);
        assert!(other.iter().all(|m| !m));
    }

    /// Against a count of the pixels by kind: 2 in both, 3 in one only.
    #[test]
    fn the_iou_counts_shared_pixels_over_covered_ones() {
        let a = [true, true, true, false, true, false, false];
        let b = [true, false, true, true, false, false, false];
        assert_eq!(mask_iou(&a, &b), 2.0 / 5.0);
        assert_eq!(mask_iou(&a, &a), 1.0);
        assert_eq!(mask_iou(&[false; 3], &[false; 3]), 1.0);
        assert_eq!(mask_iou(&[true, false], &[false, true]), 0.0);
    }

    #[test]
    fn a_share_of_the_rays_comes_from_the_mask() {
        let (w, h) = (50u32, 40u32);
        let mask: Vec<bool> = (0..w * h).map(|p| p % w < 5).collect(); // 200 of 2000
        let mut rng = Rng::new(7);
        let px = sample_focused(&mut rng, 100, w, h, &mask, 0.6).unwrap();
        assert_eq!(px.len(), 100);
        let mut sorted = px.clone();
        sorted.sort_unstable();
        sorted.dedup();
        assert_eq!(sorted.len(), 100, "distinct pixels");
        let inside = px.iter().filter(|&&p| mask[p as usize]).count();
        // 60 from the mask, and of the 40 uniform ones about 10 % land in it too
        assert!((60..=75).contains(&inside), "{inside}");
        assert!(px[..60].iter().all(|&p| mask[p as usize]));
        // a mask smaller than the share: all of it, the rest uniform
        let tiny: Vec<bool> = (0..w * h).map(|p| p < 3).collect();
        let px = sample_focused(&mut rng, 100, w, h, &tiny, 0.6).unwrap();
        assert!((0..3).all(|p| px.contains(&p)));
        assert_eq!(px.len(), 100);
        // fraction 0 is the uniform draw, draw for draw
        let (mut a, mut b) = (Rng::new(9), Rng::new(9));
        assert_eq!(
            sample_focused(&mut a, 64, w, h, &mask, 0.0).unwrap(),
            b.sample_pixels(64, w, h, None).unwrap()
        );
        assert!(sample_focused(&mut rng, 2001, w, h, &mask, 0.5).is_err());
    }
}
