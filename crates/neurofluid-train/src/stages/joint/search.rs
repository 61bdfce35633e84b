//! `[joint.physics.search]`: before the fit, the fitted scalars are set to the point of a grid
//! whose rollout best matches the joint stage's views (the training view, then
//! `joint.extra_views`; the mean over them). At each point DLF (as the stage starts it, the
//! rules' other values) is rolled out from the first training frame over every training frame and
//! scored by the grid's objective: the warm-up renderer's image loss (the mean coarse + fine MSE
//! of a view's images rendered from that rollout at `joint.rays` pixels a frame, drawn from the
//! seed's search stream, the same pixels at every point), or the silhouette (the mean Jaccard
//! distance between the pixels where a view shows fluid and those the rollout's particles
//! cover). Where the scene has the true particles, the same objective scores them too: how near
//! the best point comes to the images' own particles. A coarse search finds the basin that Adam
//! from the rules' values may not reach (docs/notebook/2026-12-06-image-landscape.md).

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

/// Every point of `grid` (the scalars not searched at `dlf`'s rules' values) with its score, and
/// the same objective on the true particles of the training frames where the scene has them (how
/// near the images' own particles come by that score, beside the grid's best). `physnerf`
/// renders only for the image objective.
pub fn search(
    physnerf: &PhysNerf,
    dlf: &DlfNet,
    data: &JointData,
    grid: &ScalarGrid,
    rays: usize,
    seed: u64,
) -> anyhow::Result<(Vec<Tried>, Option<f64>)> {
    let start = neurofluid_dlf::physics::values_of(&dlf.config.rules);
    let objective = Objective::new(physnerf, data, grid.objective, rays, seed);
    let tried = grid
        .points(start)
        .into_iter()
        .map(|point| {
            let mut config = dlf.config;
            config.rules = neurofluid_dlf::physics::rules_with(config.rules, point);
            let rollout = training_rollout(&dlf.clone().with_config(config), data);
            let loss = objective.score(&rollout.pos)?;
            tracing::debug!(?point, loss, "searched");
            Ok(Tried { point, loss })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let truth = data
        .truth
        .as_ref()
        .map(|truth| objective.score(truth))
        .transpose()?;
    Ok((tried, truth))
}

/// A search's objective: the mean over the joint stage's views (`data.views`: the training view,
/// then `joint.extra_views`) and over every training frame after the first.
struct Objective<'a> {
    physnerf: &'a PhysNerf,
    data: &'a JointData,
    kind: SearchObjective,
    frames: Vec<usize>,
    /// Per view, per frame of `frames`: where its image shows fluid (the silhouette's only).
    fluid: Vec<Vec<Vec<bool>>>,
    rays: usize,
    seed: u64,
}

impl<'a> Objective<'a> {
    fn new(
        physnerf: &'a PhysNerf,
        data: &'a JointData,
        kind: SearchObjective,
        rays: usize,
        seed: u64,
    ) -> Self {
        let frames: Vec<usize> = (1..=data.transitions() as usize).collect();
        let fluid = match kind {
            SearchObjective::Image => Vec::new(),
            SearchObjective::Silhouette => data
                .views
                .iter()
                .map(|view| {
                    frames
                        .iter()
                        .map(|&t| image_foreground(&view[t].image))
                        .collect()
                })
                .collect(),
        };
        Self {
            physnerf,
            data,
            kind,
            frames,
            fluid,
            rays,
            seed,
        }
    }

    /// The objective on `particles[t]` (t counted from the first training frame).
    fn score(&self, particles: &[Vec<[f32; 3]>]) -> anyhow::Result<f64> {
        let views = &self.data.views;
        let mut total = 0.0;
        for (v, view) in views.iter().enumerate() {
            total += match self.kind {
                SearchObjective::Image => {
                    let frames = &self.frames;
                    let (seed, rays) = (self.seed, self.rays);
                    image_mse(self.physnerf, view, particles, frames, rays, seed, STAGE)?.0
                }
                SearchObjective::Silhouette => {
                    let covered = self.frames.iter().map(|&t| {
                        let camera = &view[t].camera;
                        let mut mask = vec![false; camera.num_pixels()];
                        mark_particles(&mut mask, camera, &particles[t], self.data.radius);
                        mask
                    });
                    silhouette_distance(covered, &self.fluid[v])
                }
            };
        }
        Ok(total / views.len().max(1) as f64)
    }
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

/// The metrics rows' stage of the truth's score ([`search`]'s second value): one row, step 0.
pub const TRUTH_STAGE: &str = "joint-search-truth";

/// The metrics row of the truth's score.
pub fn truth_row(loss: f64) -> MetricsRow {
    MetricsRow::new(TRUTH_STAGE, 0, loss, 0.0)
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
