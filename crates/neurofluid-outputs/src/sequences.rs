//! The evaluation's rollouts as plain position sequences: the true test frames and every
//! model's rollout from the same starting state, what the report measures of them (d per frame
//! both ways, the interpolation sweep's points, particles through the walls, alone, far, the
//! density kept and the energy gained), which of them the renderer draws beside NeuroFluid's and
//! their particle pictures. The trainer rolls the models out and hands the positions here.

use std::path::Path;

use neurofluid_core::camera::Camera;
use neurofluid_core::metrics::{
    FarSplit, SUPPORT_RADII, alone_share, energy_gains, far_split, gt_to_pred_distance,
    mean_density,
};
use neurofluid_core::scene::{Aabb, SceneManifest};

use crate::formats::ply::{PlyError, PlyFormat, write_ply};
use crate::pictures::Picture;
use crate::pictures::viewer::{Recording, TrackInput};
use crate::scoring::particle_row;

use crate::report::{
    ALONE_REACH_RADII, EnergyGain, EvalReport, FAR_REACH_RADII, FarShare, FrameDistance,
    InterpolationPoint, Rollout, Sequence, WindowMean, Windows, count_outside,
};

/// Particle positions per frame or rollout step (step 0 the starting state).
pub type Positions = Vec<Vec<[f32; 3]>>;

/// The true test frames and every model's rollout over them.
pub struct Sequences {
    /// The true particles' positions of the test split.
    pub truth: Positions,
    /// The grounded transition model (NeuroFluid).
    pub grounded: Positions,
    /// The pretrained DLF it started from (`eval.baseline`).
    pub baseline: Option<Positions>,
    /// The pretrained DLF stepped as the paper steps it, where the run's rules differ.
    pub published: Option<Positions>,
    /// DLF† (`eval.supervised_dlf`).
    pub supervised: Option<Positions>,
    /// NeuroFluid's DLF at each fraction of `diagnostics.interpolation_sweep`.
    pub interpolated: Vec<(f64, Positions)>,
}

/// The model name of the renders of the true particles (`diagnostics.render_truth`) in the tables.
pub const RENDERER_ON_TRUTH: &str = "PhysNeRF on the true particles";

/// The model name of the renders of the pretrained DLF's rollout (`diagnostics.render_dlf`).
pub const RENDERER_ON_DLF: &str = "PhysNeRF on DLF's particles";

/// The model name of the renders of DLF†'s rollout (`diagnostics.render_dlf`).
pub const RENDERER_ON_SUPERVISED_DLF: &str = "PhysNeRF on DLF†'s particles";

/// A particle set the renderer draws beside NeuroFluid's: its name in the tables, the prefix of
/// its saved renders and its particles at every rollout step.
pub struct OtherParticles<'a> {
    /// Its name in the tables.
    pub model: &'static str,
    /// The prefix of its saved renders.
    pub prefix: &'static str,
    /// Its particles at every rollout step.
    pub at: Vec<&'a [[f32; 3]]>,
}

impl Sequences {
    /// NeuroFluid's and DLF's (where evaluated) particles of every frame as
    /// `particles/neurofluid_<t>.ply` and `particles/dlf_<t>.ply` in `dir`.
    pub fn write_ply(&self, dir: &Path, format: PlyFormat) -> Result<(), PlyError> {
        for (t, pos) in self.grounded.iter().enumerate() {
            let name = format!("particles/neurofluid_{t:04}.ply");
            write_ply(&dir.join(name), pos, None, format)?;
            if let Some(b) = &self.baseline {
                write_ply(
                    &dir.join(format!("particles/dlf_{t:04}.ply")),
                    &b[t],
                    None,
                    format,
                )?;
            }
        }
        Ok(())
    }

    /// The rollout steps (the test split's frames after the first).
    pub fn steps(&self) -> usize {
        self.truth.len() - 1
    }

    /// Fills `report`'s measures of the rollouts over a scene of `manifest`: d per frame, the
    /// interpolation sweep's points (NeuroFluid at `fraction`), the energy gained (one frame
    /// every `dt` seconds under `gravity`), the particles through the walls, alone, the density
    /// kept and where the far particles lie.
    pub fn measure(
        &self,
        report: &mut EvalReport,
        manifest: &SceneManifest,
        fraction: f64,
        dt: f32,
        gravity: [f32; 3],
    ) {
        let radius = manifest.particle_radius;
        report.frames = self.frame_distances();
        report.interpolation = self.interpolation_points(report, fraction);
        report.energy = self.energy_gains(&report.windows, dt, gravity);
        report.escaped = self.escaped(&manifest.box_interior, radius);
        report.alone = self.alone_shares(&report.windows, radius);
        report.density = self.density_ratios(&report.windows, radius);
        let mut up = [0.0; 3];
        up[manifest.up_axis.index()] = 1.0;
        report.far = self.far_shares(&report.windows, radius, up);
    }

    /// The particle sets the renderer draws beside NeuroFluid's: the truth (`render_truth`),
    /// then the rollouts of DLF and DLF† where evaluated (`render_dlf`).
    pub fn others(&self, render_truth: bool, render_dlf: bool) -> Vec<OtherParticles<'_>> {
        let mut others = Vec::new();
        if render_truth {
            others.push(OtherParticles {
                model: RENDERER_ON_TRUTH,
                prefix: "true_particles_",
                at: self.truth.iter().map(Vec::as_slice).collect(),
            });
        }
        if render_dlf {
            let sets = [
                (RENDERER_ON_DLF, "dlf_particles_", &self.baseline),
                (
                    RENDERER_ON_SUPERVISED_DLF,
                    "dlf_supervised_particles_",
                    &self.supervised,
                ),
            ];
            for (model, prefix, positions) in sets {
                if let Some(positions) = positions {
                    let at = positions.iter().map(Vec::as_slice).collect();
                    others.push(OtherParticles { model, prefix, at });
                }
            }
        }
        others
    }

    /// The viewer's recording of the truth, DLF's rollout where evaluated and NeuroFluid's, with
    /// particles of `radius`.
    pub fn recording(&self, title: &str, radius: f32) -> anyhow::Result<Recording> {
        let mut sets: Vec<TrackInput<'_>> = vec![("truth", "#3a6fc4", &self.truth)];
        if let Some(b) = &self.baseline {
            sets.push(("DLF", "#d9822b", b));
        }
        sets.push(("NeuroFluid", "#2e9e5b", &self.grounded));
        Recording::new(title, radius, &sets)
    }

    /// The particles of step `t` seen from `camera` ([`particle_row`]): the truth, DLF's where
    /// evaluated and NeuroFluid's.
    pub fn particle_picture(&self, camera: &Camera, radius: f32, t: usize) -> Picture {
        let mut predictions: Vec<(&str, &[[f32; 3]])> = Vec::new();
        if let Some(b) = &self.baseline {
            predictions.push(("DLF", &b[t]));
        }
        predictions.push(("NeuroFluid", &self.grounded[t]));
        particle_row(camera, radius, t, &self.truth[t], &predictions)
    }

    /// d per rollout step t ≥ 1, truth → prediction and the reverse, of every rollout by label.
    pub fn frame_distances(&self) -> Vec<FrameDistance> {
        (1..=self.steps())
            .map(|t| {
                let truth = &self.truth[t];
                let mut f = FrameDistance::new(t);
                for (model, frames) in self.rollouts() {
                    f.d.set(model, gt_to_pred_distance(truth, &frames[t]).mean);
                    f.reverse
                        .set(model, gt_to_pred_distance(&frames[t], truth).mean);
                }
                f
            })
            .collect()
    }

    /// d and d′ averaged over both windows at each fraction of `diagnostics.interpolation_sweep`, with
    /// the pretrained DLF (fraction 0) and NeuroFluid (`fraction`) read from `report`'s rows,
    /// by fraction (a fraction evaluated twice once). Empty without a sweep.
    fn interpolation_points(&self, report: &EvalReport, fraction: f64) -> Vec<InterpolationPoint> {
        if self.interpolated.is_empty() {
            return Vec::new();
        }
        // a window's steps are those of the report's frames (NaN where it has none)
        let windows = [report.windows.grounding, report.windows.prediction].map(|(a, b)| {
            let steps = report.frames.iter().map(|f| f.t);
            steps.filter(|t| (a..=b).contains(t)).collect::<Vec<_>>()
        });
        let swept = |f: f64, frames: &[Vec<[f32; 3]>]| {
            let [grounding, prediction] = windows.clone().map(|steps| {
                let (mut d, mut d_rev) = (0.0, 0.0);
                for &t in &steps {
                    d += gt_to_pred_distance(&self.truth[t], &frames[t]).mean;
                    d_rev += gt_to_pred_distance(&frames[t], &self.truth[t]).mean;
                }
                let n = steps.len() as f64;
                [d / n, d_rev / n]
            });
            InterpolationPoint {
                fraction: f,
                grounding,
                prediction,
            }
        };
        let evaluated = |f: f64, model: Rollout| {
            let (d, d_rev) = (report.distance_row(model)?, report.reverse_row(model)?);
            let or_nan = |v: Option<f64>| v.unwrap_or(f64::NAN);
            Some(InterpolationPoint {
                fraction: f,
                grounding: [or_nan(d.grounding_mean), or_nan(d_rev.grounding_mean)],
                prediction: [or_nan(d.prediction_mean), or_nan(d_rev.prediction_mean)],
            })
        };
        let mut points: Vec<InterpolationPoint> = self
            .interpolated
            .iter()
            .map(|(f, frames)| swept(*f, frames))
            .chain(evaluated(0.0, Rollout::Dlf))
            .chain(evaluated(fraction, Rollout::NeuroFluid))
            .collect();
        points.sort_by(|a, b| a.fraction.total_cmp(&b.fraction));
        points.dedup_by(|a, b| a.fraction == b.fraction);
        points
    }

    /// `per` of the truth and of every rollout.
    fn per_sequence<R>(&self, per: impl Fn(Sequence, &Positions) -> R) -> Vec<R> {
        std::iter::once(per(Sequence::Truth, &self.truth))
            .chain(
                self.per_rollout(|label, frames| per(Sequence::Rollout(label.to_string()), frames)),
            )
            .collect()
    }

    /// `per` of every rollout (DLF, DLF†, NeuroFluid, those evaluated), with its table label.
    fn per_rollout<R>(&self, per: impl Fn(&str, &Positions) -> R) -> Vec<R> {
        self.rollouts()
            .into_iter()
            .map(|(model, frames)| per(model.label(), frames))
            .collect()
    }

    /// Every rollout evaluated (DLF, DLF under the paper's step, DLF†, NeuroFluid), in table
    /// order.
    fn rollouts(&self) -> Vec<(Rollout, &Positions)> {
        [
            self.baseline.as_ref().map(|b| (Rollout::Dlf, b)),
            self.published.as_ref().map(|b| (Rollout::PublishedDlf, b)),
            self.supervised
                .as_ref()
                .map(|b| (Rollout::SupervisedDlf, b)),
            Some((Rollout::NeuroFluid, &self.grounded)),
        ]
        .into_iter()
        .flatten()
        .collect()
    }

    /// The share of particles alone ([`alone_share`]: no other within
    /// [`ALONE_REACH_RADII`] particle radii of `radius`) of the truth and of every rollout, the
    /// mean over each of `windows`' frames (a frame with a non-finite particle counts as all
    /// alone).
    fn alone_shares(&self, windows: &Windows, radius: f32) -> Vec<WindowMean> {
        let reach = ALONE_REACH_RADII * f64::from(radius);
        self.per_sequence(|model, frames| {
            window_mean(model, frames, windows, |p| {
                alone_share(p, reach).unwrap_or(1.0)
            })
        })
    }

    /// The mean kernel density ([`mean_density`], support [`SUPPORT_RADII`] radii of `radius`)
    /// of the truth and of every rollout relative to the truth's at the first test frame, the
    /// mean over each of `windows`' frames: a fluid that keeps its density stays near 1. None
    /// (no table) when no two true particles of that frame are within the support.
    fn density_ratios(&self, windows: &Windows, radius: f32) -> Vec<WindowMean> {
        let support = SUPPORT_RADII * radius;
        let rest = mean_density(&self.truth[0], support);
        if rest.is_nan() || rest <= 0.0 {
            return Vec::new();
        }
        self.per_sequence(|model, frames| {
            window_mean(model, frames, windows, |p| mean_density(p, support) / rest)
        })
    }

    /// The energy gained over `windows` by the truth and by every rollout, one frame every
    /// `dt` seconds under `gravity`.
    fn energy_gains(&self, windows: &Windows, dt: f32, gravity: [f32; 3]) -> Vec<EnergyGain> {
        self.per_sequence(|model, frames| {
            let gains = energy_gains(frames, dt, gravity);
            let over = |gains: &[f64], (a, b): (usize, usize)| -> f64 {
                gains.iter().take(b + 1).skip(a).sum()
            };
            EnergyGain {
                model,
                grounding: over(&gains.fluid, windows.grounding),
                prediction: over(&gains.fluid, windows.prediction),
                grounding_per_particle: over(&gains.particle, windows.grounding),
                prediction_per_particle: over(&gains.particle, windows.prediction),
            }
        })
    }

    /// Per rollout, the most particles more than `radius` outside `interior` at any step.
    pub fn escaped(&self, interior: &Aabb, radius: f32) -> Vec<(String, usize)> {
        self.per_rollout(|label, frames| {
            let most = frames[1..]
                .iter()
                .map(|p| count_outside(p, interior, radius))
                .max()
                .unwrap_or(0);
            (label.to_string(), most)
        })
    }

    /// Per rollout, where its far particles lie ([`far_split`]: more than [`FAR_REACH_RADII`]
    /// particle radii of `radius` from every true particle, beside, above or within the truth;
    /// `up` the scene's vertical), the mean over each of `windows`' frames (a frame with a
    /// non-finite particle counts as all far, beside).
    fn far_shares(&self, windows: &Windows, radius: f32, up: [f32; 3]) -> Vec<FarShare> {
        let reach = FAR_REACH_RADII * f64::from(radius);
        self.per_rollout(|model, frames| {
            let mean = |(a, b): (usize, usize)| -> FarSplit {
                let splits: Vec<FarSplit> = frames
                    .iter()
                    .zip(&self.truth)
                    .take(b + 1)
                    .skip(a)
                    .map(|(p, t)| {
                        far_split(p, t, up, reach).unwrap_or(FarSplit {
                            beside: 1.0,
                            ..FarSplit::default()
                        })
                    })
                    .collect();
                let n = splits.len().max(1) as f64;
                FarSplit {
                    beside: splits.iter().map(|s| s.beside).sum::<f64>() / n,
                    above: splits.iter().map(|s| s.above).sum::<f64>() / n,
                    within: splits.iter().map(|s| s.within).sum::<f64>() / n,
                }
            };
            FarShare {
                model: model.to_string(),
                grounding: mean(windows.grounding),
                prediction: mean(windows.prediction),
            }
        })
    }
}

/// `model`'s `per_frame` statistic, the mean over each of `windows`' own frames.
fn window_mean(
    model: Sequence,
    frames: &Positions,
    windows: &Windows,
    per_frame: impl Fn(&[[f32; 3]]) -> f64,
) -> WindowMean {
    let mean = |(a, b): (usize, usize)| -> f64 {
        let values: Vec<f64> = frames
            .iter()
            .take(b + 1)
            .skip(a)
            .map(|p| per_frame(p))
            .collect();
        values.iter().sum::<f64>() / values.len().max(1) as f64
    };
    WindowMean {
        model,
        grounding: mean(windows.grounding),
        prediction: mean(windows.prediction),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A block packed two radii apart (r = 0.025).
    fn block() -> Vec<[f32; 3]> {
        (0..64)
            .map(|i| {
                [
                    (i % 4) as f32 * 0.05,
                    (i / 4 % 4) as f32 * 0.05,
                    (i / 16) as f32 * 0.05,
                ]
            })
            .collect()
    }

    /// Sixty frames of a block at rest, NeuroFluid's `grounded` and DLF's `baseline` rollouts.
    fn over_still_block(grounded: Positions, baseline: Positions) -> Sequences {
        Sequences {
            truth: vec![block(); 60],
            grounded,
            baseline: Some(baseline),
            published: None,
            supervised: None,
            interpolated: Vec::new(),
        }
    }

    /// The truth keeps its first frame's density; a rollout spread thinner from t = 50 is below
    /// it in the prediction window only, and one pressed tighter is above it in both, each by
    /// the ratio of the host sums.
    #[test]
    fn density_ratios_compare_every_sequence_with_the_first_true_frame() {
        let scaled =
            |s: f32| -> Vec<[f32; 3]> { block().iter().map(|p| p.map(|c| c * s)).collect() };
        let grounded: Positions = (0..60)
            .map(|t| if t >= 50 { scaled(1.2) } else { block() })
            .collect();
        let rollouts = over_still_block(grounded, vec![scaled(0.9); 60]);
        let ratios = rollouts.density_ratios(&Windows::paper(), 0.025);
        let labels: Vec<String> = ratios.iter().map(|s| s.model.to_string()).collect();
        assert_eq!(labels, ["truth", "DLF", "NeuroFluid"]);
        let h = SUPPORT_RADII * 0.025;
        let rest = mean_density(&block(), h);
        assert_eq!((ratios[0].grounding, ratios[0].prediction), (1.0, 1.0));
        let pressed = mean_density(&scaled(0.9), h) / rest;
        assert!(pressed > 1.0, "{pressed}");
        assert!(
            (ratios[1].grounding - pressed).abs() < 1e-12,
            "{:?}",
            ratios[1]
        );
        assert!(
            (ratios[1].prediction - pressed).abs() < 1e-12,
            "{:?}",
            ratios[1]
        );
        let thinner = mean_density(&scaled(1.2), h) / rest;
        assert!(thinner < 0.9, "{thinner}");
        assert_eq!(ratios[2].grounding, 1.0);
        // a truth whose particles lie farther apart than the support has no density to compare
        assert!(rollouts.density_ratios(&Windows::paper(), 0.001).is_empty());
        assert!(
            (ratios[2].prediction - thinner).abs() < 1e-12,
            "{:?}",
            ratios[2]
        );
    }

    /// Each window's share is the mean over its own frames only: a stray that NeuroFluid throws
    /// in the last five frames counts half in the prediction window and not in the grounding one.
    #[test]
    fn alone_shares_average_each_window_over_its_frames() {
        let grounded: Positions = (0..60)
            .map(|t| {
                let mut p = block();
                p.push(if t >= 55 {
                    [2.0, 2.0, 2.0]
                } else {
                    [0.2, 0.0, 0.0]
                });
                p
            })
            .collect();
        let mut diverged = grounded.clone();
        diverged[10][0] = [f32::NAN; 3];
        let rollouts = over_still_block(grounded, diverged);
        let shares = rollouts.alone_shares(&Windows::paper(), 0.025);
        let labels: Vec<String> = shares.iter().map(|s| s.model.to_string()).collect();
        assert_eq!(labels, ["truth", "DLF", "NeuroFluid"]);
        assert_eq!((shares[0].grounding, shares[0].prediction), (0.0, 0.0));
        let nf = &shares[2];
        assert_eq!(nf.grounding, 0.0);
        assert!((nf.prediction - 0.5 / 65.0).abs() < 1e-12, "{nf:?}");
        // the frame with a non-finite particle counts as all alone: 1/49 of the window
        assert!(
            (shares[1].grounding - 1.0 / 49.0).abs() < 1e-12,
            "{:?}",
            shares[1]
        );
    }

    /// Each rollout's far particles are placed and averaged over each window's own frames; the
    /// truth has no row (it is what "far" is measured from).
    #[test]
    fn far_shares_place_each_rollout_s_far_particles_per_window() {
        // z up: one of 65 particles held 1 m over the block until t = 49, then 1 m beside it
        let grounded: Positions = (0..60)
            .map(|t| {
                let mut p = block();
                p.push(if t >= 50 {
                    [1.2, 0.0, 0.0]
                } else {
                    [0.1, 0.1, 1.2]
                });
                p
            })
            .collect();
        let mut diverged = block();
        diverged[3] = [f32::NAN; 3];
        let rollouts = over_still_block(grounded, vec![diverged; 60]);
        let far = rollouts.far_shares(&Windows::paper(), 0.025, [0.0, 0.0, 1.0]);
        let labels: Vec<&str> = far.iter().map(|s| s.model.as_str()).collect();
        assert_eq!(labels, ["DLF", "NeuroFluid"]);
        let one = 1.0 / 65.0;
        let nf = &far[1];
        assert_eq!(
            (nf.grounding.beside, nf.grounding.within),
            (0.0, 0.0),
            "{nf:?}"
        );
        assert!((nf.grounding.above - one).abs() < 1e-12, "{nf:?}");
        assert!((nf.prediction.beside - one).abs() < 1e-12, "{nf:?}");
        assert_eq!(nf.prediction.above, 0.0);
        // every frame of the diverged rollout counts as all far, beside
        assert_eq!(far[0].grounding.beside, 1.0);
        assert_eq!(far[0].prediction.total(), 1.0);
    }
}
