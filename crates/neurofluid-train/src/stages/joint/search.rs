//! `[joint.physics.search]`: before the fit, the fitted scalars are set to the point of a grid
//! whose rollout best matches the training view. At each point DLF (as the stage starts it, the
//! rules' other values) is rolled out from the first training frame over every training frame and
//! scored by the grid's objective: the warm-up renderer's image loss (the mean coarse + fine MSE
//! of the training view's images rendered from that rollout at `joint.rays` pixels a frame, drawn
//! from the seed's search stream, the same pixels at every point), or the silhouette (the mean
//! Jaccard distance between the pixels where the training view shows fluid and those the
//! rollout's particles cover). A coarse search finds the basin that Adam from the rules' values
//! may not reach (docs/notebook/2026-12-06-image-landscape.md).

use neurofluid_core::ray_focus::{image_foreground, mark_particles, mask_iou};
use neurofluid_dlf::DlfNet;
use neurofluid_outputs::metrics_log::MetricsRow;
use neurofluid_physnerf::PhysNerf;

use super::data::{JointData, training_rollout};
use super::diagnostics::image_mse;
use super::physics::COLUMNS;
use crate::config::{ScalarGrid, SearchObjective};

/// The metrics rows' stage: one row per point tried, its step the point's index.
pub const STAGE: &str = "joint-search";

/// A point of the grid and its score.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tried {
    /// Gravity scale, viscosity, dissipation.
    pub point: [f64; 3],
    /// The objective's value (lower is better).
    pub loss: f64,
}

/// Every point of `grid` (the scalars not searched at `dlf`'s rules' values) with its score
/// (`physnerf` renders only for the image objective).
pub fn search(
    physnerf: &PhysNerf,
    dlf: &DlfNet,
    data: &JointData,
    grid: &ScalarGrid,
    rays: usize,
    seed: u64,
) -> anyhow::Result<Vec<Tried>> {
    let start = neurofluid_dlf::physics::values_of(&dlf.config.rules);
    let frames: Vec<usize> = (1..=data.transitions() as usize).collect();
    let fluid: Vec<Vec<bool>> = match grid.objective {
        SearchObjective::Image => Vec::new(),
        SearchObjective::Silhouette => frames
            .iter()
            .map(|&t| image_foreground(&data.target(t).image))
            .collect(),
    };
    grid.points(start)
        .into_iter()
        .map(|point| {
            let mut config = dlf.config;
            config.rules = neurofluid_dlf::physics::rules_with(config.rules, point);
            let rollout = training_rollout(&dlf.clone().with_config(config), data);
            let loss = match grid.objective {
                SearchObjective::Image => {
                    image_mse(physnerf, data, &rollout.pos, &frames, rays, seed, STAGE)?.0
                }
                SearchObjective::Silhouette => {
                    let covered = frames.iter().map(|&t| {
                        let camera = &data.target(t).camera;
                        let mut mask = vec![false; camera.num_pixels()];
                        mark_particles(&mut mask, camera, &rollout.pos[t], data.radius);
                        mask
                    });
                    silhouette_distance(covered, &fluid)
                }
            };
            tracing::debug!(?point, loss, "searched");
            Ok(Tried { point, loss })
        })
        .collect()
}

/// The mean over frames of the Jaccard distance 1 − IoU between each frame's `covered` pixels and
/// its `fluid` pixels.
fn silhouette_distance(covered: impl Iterator<Item = Vec<bool>>, fluid: &[Vec<bool>]) -> f64 {
    let total: f64 = covered.zip(fluid).map(|(c, f)| 1.0 - mask_iou(&c, f)).sum();
    total / fluid.len().max(1) as f64
}

/// The point of least finite loss (the first of equals); `None` when no loss is finite.
pub fn best(tried: &[Tried]) -> Option<Tried> {
    tried
        .iter()
        .filter(|t| t.loss.is_finite())
        .fold(None, |best: Option<Tried>, t| match best {
            Some(b) if b.loss <= t.loss => Some(b),
            _ => Some(*t),
        })
}

/// The metrics row of the `k`-th point tried.
pub fn row(k: usize, tried: &Tried) -> MetricsRow {
    let mut row = MetricsRow::new(STAGE, k as u64, tried.loss, 0.0);
    for (name, v) in COLUMNS.into_iter().zip(tried.point) {
        row.set(name, v);
    }
    row
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::PhysicalScalar;

    /// The grid is the product of the lists (the first scalar outermost), a scalar without
    /// values at its start; more points than the bound are refused.
    #[test]
    fn the_grid_is_the_product_of_its_lists() {
        let grid = ScalarGrid {
            gravity_scale: vec![1.0, 2.0],
            viscosity: vec![],
            dissipation: vec![0.0, 0.1, 0.2],
            ..ScalarGrid::default()
        };
        let mut want = Vec::new();
        for g in [1.0, 2.0] {
            for d in [0.0, 0.1, 0.2] {
                want.push([g, 0.3, d]);
            }
        }
        assert_eq!(grid.points([1.7, 0.3, 0.05]), want);
        let fit = [PhysicalScalar::GravityScale, PhysicalScalar::Dissipation];
        assert_eq!(grid.problem(&fit), None);
        let wide = ScalarGrid {
            gravity_scale: vec![1.0; 21],
            dissipation: vec![0.0; 20],
            ..ScalarGrid::default()
        };
        let (field, msg) = wide.problem(&fit).unwrap();
        assert_eq!(field, "gravity_scale");
        assert!(msg.contains("420 points"), "{msg}");
    }

    /// The mean of the frames' 1 − IoU: a frame matched exactly (0) and one half covered (½).
    #[test]
    fn the_silhouette_distance_is_the_frames_mean_jaccard_distance() {
        let fluid = vec![vec![true, true, false], vec![true, true, false]];
        let covered = vec![vec![true, true, false], vec![true, false, false]];
        assert_eq!(silhouette_distance(covered.into_iter(), &fluid), 0.25);
    }

    #[test]
    fn the_best_point_is_the_least_finite_loss_and_the_first_of_equals() {
        let t = |g: f64, loss: f64| Tried {
            point: [g, 0.0, 0.0],
            loss,
        };
        let tried = [t(1.0, 0.3), t(2.0, f64::NAN), t(3.0, 0.1), t(4.0, 0.1)];
        assert_eq!(best(&tried), Some(t(3.0, 0.1)));
        assert_eq!(best(&[t(1.0, f64::INFINITY), t(2.0, f64::NAN)]), None);
    }
}
