//! The surface threshold from the images alone: the iso-density whose body `{σ > iso}`, seen
//! from each warm-up camera, covers the pixels the fluid covers in that view (the image's
//! alpha).
//!
//! A pixel's ray meets the body exactly when the largest density along the ray is above the
//! iso, so one march per pixel (the largest trilinear sample, every half cell) gives the
//! silhouette of every candidate iso. The candidates run geometrically from a thousandth of the
//! grid's largest density to the largest; the one with the best mean intersection over union
//! with the views' coverage (alpha ≥ 0.5) wins. Unlike an absolute density, this adapts to how
//! a NeRF happens to represent a fluid (glass-like water's NeRF is dense at the refracting
//! surfaces and thin inside; honey's is dense everywhere), and unlike a fraction of the peak it
//! does not depend on one voxel.

use neurofluid_core::camera::Camera;
use neurofluid_core::ray_focus::mask_iou;
use rayon::prelude::*;

use crate::geometry::volume_fill::DensityGrid;

/// Candidate isos tried, from 10⁻³ of the largest density to the largest.
pub const CANDIDATES: usize = 96;

/// A view's camera and the fluid's coverage of each pixel (row-major, as the image).
#[derive(Debug, Clone, Copy)]
pub struct Coverage<'a> {
    /// The camera.
    pub camera: &'a Camera,
    /// Coverage in [0, 1] per pixel (the PNG's alpha).
    pub alpha: &'a [f32],
    /// The view's name, for messages.
    pub name: &'a str,
}

/// The chosen iso and how well its silhouettes match.
#[derive(Debug, Clone, PartialEq)]
pub struct IsoChoice {
    /// The iso-density.
    pub iso: f64,
    /// Its mean intersection over union with the views' coverage.
    pub iou: f64,
    /// Every candidate: (iso, mean IoU), ascending iso.
    pub candidates: Vec<(f64, f64)>,
}

impl DensityGrid {
    /// The trilinear interpolation of the values at `p`; 0 outside the grid.
    pub fn sample(&self, p: [f64; 3]) -> f32 {
        let mut base = [0usize; 3];
        let mut frac = [0f64; 3];
        for a in 0..3 {
            let u = (p[a] - self.origin[a]) / self.cell;
            let last = (self.dims[a] - 1) as f64;
            if !(0.0..=last).contains(&u) {
                return 0.0;
            }
            let i = (u.floor() as usize).min(self.dims[a] - 2);
            base[a] = i;
            frac[a] = u - i as f64;
        }
        let mut v = 0.0f64;
        for corner in 0..8 {
            let mut w = 1.0;
            let mut idx = [0usize; 3];
            for a in 0..3 {
                let up = (corner >> a) & 1 == 1;
                idx[a] = base[a] + usize::from(up);
                w *= if up { frac[a] } else { 1.0 - frac[a] };
            }
            if w > 0.0 {
                v += w * f64::from(self.values[self.index(idx[0], idx[1], idx[2])]);
            }
        }
        v as f32
    }

    /// The largest [`DensityGrid::sample`] along the ray `origin + t·dir` (`dir` of unit
    /// length) inside the grid, sampled every half cell; 0 when the ray misses the grid.
    pub fn ray_max(&self, origin: [f64; 3], dir: [f64; 3]) -> f32 {
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for a in 0..3 {
            let lo = self.origin[a];
            let hi = lo + (self.dims[a] - 1) as f64 * self.cell;
            if dir[a].abs() < 1e-12 {
                if origin[a] < lo || origin[a] > hi {
                    return 0.0;
                }
                continue;
            }
            let (ta, tb) = ((lo - origin[a]) / dir[a], (hi - origin[a]) / dir[a]);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
        if t0 > t1 {
            return 0.0;
        }
        let step = 0.5 * self.cell;
        let steps = ((t1 - t0) / step).ceil() as usize;
        (0..=steps)
            .map(|s| {
                let t = (t0 + s as f64 * step).min(t1);
                self.sample(std::array::from_fn(|a| origin[a] + t * dir[a]))
            })
            .fold(0.0f32, f32::max)
    }
}

/// The largest density along every pixel's ray of `camera`, row-major.
fn ray_maxima(grid: &DensityGrid, camera: &Camera) -> Vec<f32> {
    let origin = camera.origin().map(f64::from);
    let width = camera.width;
    (0..camera.num_pixels())
        .into_par_iter()
        .map(|p| {
            let (row, col) = (p as u32 / width, p as u32 % width);
            grid.ray_max(origin, camera.ray_dir(row, col).map(f64::from))
        })
        .collect()
}

/// Intersection over union of `{maxima > iso}` with `mask`.
fn iou(maxima: &[f32], mask: &[bool], iso: f64) -> f64 {
    let hits: Vec<bool> = maxima.iter().map(|&m| f64::from(m) > iso).collect();
    mask_iou(&hits, mask)
}

/// The iso whose silhouettes best match the views' coverage (module docs).
///
/// # Errors
/// When the grid's density is nowhere positive, a view's coverage does not match its camera's
/// size, or no view has both fluid and background in its alpha (images without an alpha
/// channel read as covered everywhere: the rule needs the fluid's coverage).
pub fn silhouette_iso(grid: &DensityGrid, views: &[Coverage<'_>]) -> anyhow::Result<IsoChoice> {
    let max = f64::from(grid.values.iter().copied().fold(0.0f32, f32::max));
    anyhow::ensure!(
        max > 0.0,
        "the NeRF's density is zero everywhere in the box: no surface to place"
    );
    let used: Vec<_> = usable_views(views)?
        .into_iter()
        .map(|(v, mask)| (ray_maxima(grid, v.camera), mask))
        .collect();
    let candidates: Vec<(f64, f64)> = (0..CANDIDATES)
        .map(|k| {
            let iso = max * 1e-3f64.powf(1.0 - k as f64 / (CANDIDATES - 1) as f64);
            let mean =
                used.iter().map(|(m, mask)| iou(m, mask, iso)).sum::<f64>() / used.len() as f64;
            (iso, mean)
        })
        .collect();
    // the best mean IoU; among equals, the lowest iso (the fullest body)
    let (iso, iou) = candidates
        .iter()
        .copied()
        .fold((0.0, f64::NEG_INFINITY), |best, c| {
            if c.1 > best.1 { c } else { best }
        });
    Ok(IsoChoice {
        iso,
        iou,
        candidates,
    })
}

/// The views whose alpha shows both fluid and background, with their coverage masks (alpha ≥
/// ½); an error when a view's size does not match its camera's, or when none has both: the
/// silhouette rule then has nothing to match (known from the images alone, before any fit).
pub fn usable_views<'a, 'b>(
    views: &'b [Coverage<'a>],
) -> anyhow::Result<Vec<(&'b Coverage<'a>, Vec<bool>)>> {
    let mut used = Vec::new();
    for v in views {
        anyhow::ensure!(
            v.alpha.len() == v.camera.num_pixels(),
            "view {}: {} coverage values for a {}×{} camera",
            v.name,
            v.alpha.len(),
            v.camera.width,
            v.camera.height
        );
        let mask: Vec<bool> = v.alpha.iter().map(|&a| a >= 0.5).collect();
        let covered = mask.iter().filter(|&&m| m).count();
        if covered == 0 || covered == mask.len() {
            tracing::warn!(
                view = v.name,
                covered,
                "the view's alpha shows no fluid or no background: not used for the silhouette \
                 threshold"
            );
            continue;
        }
        used.push((v, mask));
    }
    anyhow::ensure!(
        !used.is_empty(),
        "initial.threshold = \"silhouette\" needs warm-up images whose alpha channel shows the \
         fluid's coverage (some pixels covered, some not); none of the {} views has one (images \
         without alpha read as covered everywhere): use \"half_max\" or \"opacity\"",
        views.len()
    );
    Ok(used)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sphere of radius `r` at `c` whose density falls from 20 to 0 over a shell of width
    /// ~`w`, 10 exactly on the sphere.
    fn soft_sphere(c: [f64; 3], r: f64, w: f64, cell: f64) -> DensityGrid {
        let n = 41;
        let origin = c.map(|x| x - 20.0 * cell);
        let mut grid = DensityGrid::new(origin, cell, [n; 3], vec![0.0; n * n * n]).unwrap();
        let values = grid
            .points()
            .iter()
            .map(|p| {
                let d = (0..3).map(|a| (p[a] - c[a]).powi(2)).sum::<f64>().sqrt();
                (20.0 / (1.0 + ((d - r) / w).exp())) as f32
            })
            .collect();
        grid.values = values;
        grid
    }

    /// A camera at `eye` looking at `c`, and the pixels whose rays pass within `r` of `c`.
    fn view_of_sphere(eye: [f32; 3], c: [f64; 3], r: f64) -> (Camera, Vec<f32>) {
        let target = c.map(|x| x as f32);
        let camera = Camera::look_at(64, 64, 0.7, eye, target, [0.0, 0.0, 1.0]);
        let o = eye.map(f64::from);
        let alpha = (0..camera.num_pixels())
            .map(|p| {
                let d = camera.ray_dir(p as u32 / 64, p as u32 % 64).map(f64::from);
                let v: [f64; 3] = std::array::from_fn(|a| c[a] - o[a]);
                let along: f64 = (0..3).map(|a| v[a] * d[a]).sum();
                let miss2 = (0..3).map(|a| (v[a] - along * d[a]).powi(2)).sum::<f64>();
                if miss2.sqrt() <= r { 1.0 } else { 0.0 }
            })
            .collect();
        (camera, alpha)
    }

    #[test]
    fn trilinear_samples_reproduce_a_linear_field_and_vanish_outside() {
        let mut grid = DensityGrid::new([0.0; 3], 0.5, [3, 4, 5], vec![0.0; 60]).unwrap();
        grid.values = grid
            .points()
            .iter()
            .map(|p| (1.0 + 2.0 * p[0] - p[1] + 0.5 * p[2]) as f32)
            .collect();
        let p = [0.3, 1.2, 1.7];
        let exact = 1.0 + 2.0 * p[0] - p[1] + 0.5 * p[2];
        assert!((f64::from(grid.sample(p)) - exact).abs() < 1e-6);
        assert_eq!(grid.sample([-0.1, 1.0, 1.0]), 0.0);
        assert_eq!(grid.sample([0.5, 1.0, 2.01]), 0.0);
    }

    #[test]
    fn the_largest_density_along_a_ray_is_the_spheres_profile_at_its_closest_approach() {
        let c = [0.0, 0.0, 0.0];
        let grid = soft_sphere(c, 0.2, 0.02, 0.02);
        // through the centre: the peak; 0.3 from the centre: the profile there
        let through = grid.ray_max([-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]);
        assert!(through > 19.0, "{through}");
        let off = grid.ray_max([-1.0, 0.3, 0.0], [1.0, 0.0, 0.0]);
        let profile = 20.0 / (1.0 + ((0.3f64 - 0.2) / 0.02).exp());
        assert!(
            (f64::from(off) - profile).abs() < 0.05,
            "{off} vs {profile}"
        );
        assert_eq!(grid.ray_max([-1.0, 5.0, 0.0], [1.0, 0.0, 0.0]), 0.0);
    }

    #[test]
    fn the_chosen_iso_puts_the_surface_on_the_true_sphere() {
        // the sphere's radius at density iso is r + w·ln(20/iso − 1): the choice must land
        // within half a grid cell of the true radius, whatever scale the density has
        let (c, r, w, cell) = ([0.1, -0.2, 0.3], 0.25, 0.03, 0.02);
        for scale in [0.05f32, 1.0, 40.0] {
            let mut grid = soft_sphere(c, r, w, cell);
            grid.values.iter_mut().for_each(|v| *v *= scale);
            let eyes = [
                [2.0, 0.3, 0.8],
                [-1.5, 1.5, 0.5],
                [0.2, -2.0, 1.5],
                [1.0, 1.0, -1.0],
            ];
            let views: Vec<(Camera, Vec<f32>)> =
                eyes.iter().map(|&e| view_of_sphere(e, c, r)).collect();
            let names = ["a", "b", "c", "d"];
            let cov: Vec<Coverage> = views
                .iter()
                .zip(names)
                .map(|((camera, alpha), name)| Coverage {
                    camera,
                    alpha,
                    name,
                })
                .collect();
            let choice = silhouette_iso(&grid, &cov).unwrap();
            let unit = choice.iso / f64::from(scale);
            let radius = r + w * (20.0 / unit - 1.0).ln();
            assert!(
                (radius - r).abs() < 0.5 * cell,
                "scale {scale}: iso {} (radius {radius:.3} against {r}), IoU {:.3}",
                choice.iso,
                choice.iou
            );
            assert!(choice.iou > 0.9, "IoU {}", choice.iou);
        }
    }

    #[test]
    fn images_without_coverage_are_refused_with_the_alternatives() {
        let grid = soft_sphere([0.0; 3], 0.2, 0.02, 0.02);
        let (camera, _) = view_of_sphere([2.0, 0.0, 0.0], [0.0; 3], 0.2);
        let opaque = vec![1.0f32; camera.num_pixels()];
        let cov = [Coverage {
            camera: &camera,
            alpha: &opaque,
            name: "view_1",
        }];
        let e = format!("{:#}", silhouette_iso(&grid, &cov).unwrap_err());
        assert!(e.contains("alpha") && e.contains("half_max"), "{e}");
    }
}
