//! The evaluation's rollouts: from the same starting state (the truth of the first test frame,
//! or the particles from images), the grounded transition model, the DLF it started from and
//! DLF† roll out without feedback; what they are measured by (d per frame both ways, particles
//! through the walls, alone and far).

use anyhow::Context;
use burn::module::Module;
use neurofluid_core::metrics::{FarSplit, alone_share, far_split, gt_to_pred_distance};
use neurofluid_core::scene::{Aabb, Particles, Role};
use neurofluid_dlf::DlfNet;
use neurofluid_dlf::rollout::rollout;

use crate::energy_prior::energy_gains;
use crate::report::{
    ALONE_REACH_RADII, EnergyGain, EvalReport, FAR_REACH_RADII, FarShare, FrameDistance,
    InterpolationPoint, Reverse, Rollout, WindowMean, Windows, count_outside,
};
use crate::rest_density::{SUPPORT_RADII, mean_density};
use crate::stages::initial::starting_particles;
use crate::stages::joint::Grounded;
use crate::stages::run_folder::Run;
use crate::stages::views::check_sequence;

/// Particle positions per rollout step (step 0 the starting state).
pub type Positions = Vec<Vec<[f32; 3]>>;

/// The true test frames and every model's rollout over them.
pub struct Rollouts {
    /// The true particles of the test split.
    pub truth: Vec<Particles>,
    /// The grounded transition model (NeuroFluid).
    pub grounded: Positions,
    /// The pretrained DLF it started from (`eval.baseline`).
    pub baseline: Option<Positions>,
    /// DLF† (`eval.supervised_dlf`).
    pub supervised: Option<Positions>,
    /// NeuroFluid's DLF at each fraction of `eval.interpolation_sweep`.
    pub interpolated: Vec<(f64, Positions)>,
}

impl Rollouts {
    /// Rolls every evaluated model out over the test split of `run`.
    pub fn of(run: &Run, models: &Grounded) -> anyhow::Result<Self> {
        let cfg = &run.exp.eval;
        let (truth, start, steps) = test_start(run)?;
        let pretrained = run.load_dlf(&run.exp.dlf.weights)?;
        let evaluated = evaluated_dlf(&pretrained, &models.dlf, cfg.weight_interpolation)?;
        let grounded = positions(run, &evaluated, &start, steps, "NeuroFluid")?;
        let baseline = if cfg.baseline {
            Some(positions(run, &pretrained, &start, steps, "DLF")?)
        } else {
            None
        };
        let supervised = match &cfg.supervised_dlf {
            Some(path) => {
                let net = run.load_dlf(path).context("eval.supervised_dlf")?;
                Some(positions(run, &net, &start, steps, "DLF†")?)
            }
            None => None,
        };
        let interpolated = cfg
            .interpolation_sweep
            .iter()
            .map(|&f| {
                let net = evaluated_dlf(&pretrained, &models.dlf, f)?;
                let what = format!("NeuroFluid at {f}");
                Ok((f, positions(run, &net, &start, steps, &what)?))
            })
            .collect::<anyhow::Result<_>>()?;
        Ok(Self {
            truth,
            grounded,
            baseline,
            supervised,
            interpolated,
        })
    }

    /// The truth of the test split and one DLF's rollout from its first frame in the grounded
    /// model's place (no baseline, no DLF†): a rule or weights file scored alone (`rollout`).
    pub fn of_one(run: &Run, net: &DlfNet, what: &str) -> anyhow::Result<Self> {
        let (truth, start, steps) = test_start(run)?;
        Ok(Self {
            truth,
            grounded: positions(run, net, &start, steps, what)?,
            baseline: None,
            supervised: None,
            interpolated: Vec::new(),
        })
    }

    /// The rollout steps (the test split's frames after the first).
    pub fn steps(&self) -> usize {
        self.truth.len() - 1
    }

    /// d per rollout step t ≥ 1, truth → prediction and the reverse.
    pub fn frame_distances(&self) -> Vec<FrameDistance> {
        let (baseline, supervised) = (self.baseline.as_ref(), self.supervised.as_ref());
        (1..=self.steps())
            .map(|t| {
                let truth = &self.truth[t].pos;
                let d = |pred: &[[f32; 3]]| gt_to_pred_distance(truth, pred).mean;
                let d_rev = |pred: &[[f32; 3]]| gt_to_pred_distance(pred, truth).mean;
                FrameDistance {
                    t,
                    neurofluid: d(&self.grounded[t]),
                    dlf: baseline.map(|b| d(&b[t])),
                    supervised_dlf: supervised.map(|b| d(&b[t])),
                    reverse: Reverse {
                        neurofluid: Some(d_rev(&self.grounded[t])),
                        dlf: baseline.map(|b| d_rev(&b[t])),
                        supervised_dlf: supervised.map(|b| d_rev(&b[t])),
                    },
                }
            })
            .collect()
    }

    /// d and d′ averaged over both windows at each fraction of `eval.interpolation_sweep`, with
    /// the pretrained DLF (fraction 0) and NeuroFluid (`fraction`) read from `report`'s rows,
    /// by fraction (a fraction evaluated twice once). Empty without a sweep.
    pub fn interpolation_points(
        &self,
        report: &EvalReport,
        fraction: f64,
    ) -> Vec<InterpolationPoint> {
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
                    d += gt_to_pred_distance(&self.truth[t].pos, &frames[t]).mean;
                    d_rev += gt_to_pred_distance(&frames[t], &self.truth[t].pos).mean;
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

    /// `per` of the truth and of every rollout, with its label (`truth` or the table's).
    fn per_sequence<R>(&self, per: impl Fn(&str, &Positions) -> R) -> Vec<R> {
        let truth: Positions = self.truth.iter().map(|p| p.pos.clone()).collect();
        std::iter::once(per("truth", &truth))
            .chain(self.per_rollout(per))
            .collect()
    }

    /// `per` of every rollout (DLF, DLF†, NeuroFluid, those evaluated), with its table label.
    fn per_rollout<R>(&self, per: impl Fn(&str, &Positions) -> R) -> Vec<R> {
        [
            self.baseline.as_ref().map(|b| (Rollout::Dlf, b)),
            self.supervised
                .as_ref()
                .map(|b| (Rollout::SupervisedDlf, b)),
            Some((Rollout::NeuroFluid, &self.grounded)),
        ]
        .into_iter()
        .flatten()
        .map(|(model, frames)| per(model.label(), frames))
        .collect()
    }

    /// The share of particles alone ([`alone_share`]: no other within
    /// [`ALONE_REACH_RADII`] particle radii of `radius`) of the truth and of every rollout, the
    /// mean over each of `windows`' frames (a frame with a non-finite particle counts as all
    /// alone).
    pub fn alone_shares(&self, windows: &Windows, radius: f32) -> Vec<WindowMean> {
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
    pub fn density_ratios(&self, windows: &Windows, radius: f32) -> Vec<WindowMean> {
        let support = SUPPORT_RADII * radius;
        let rest = mean_density(&self.truth[0].pos, support);
        if rest.is_nan() || rest <= 0.0 {
            return Vec::new();
        }
        self.per_sequence(|model, frames| {
            window_mean(model, frames, windows, |p| mean_density(p, support) / rest)
        })
    }

    /// The energy gained over `windows` by the truth and by every rollout, one frame every
    /// `dt` seconds under `gravity`.
    pub fn energy_gains(&self, windows: &Windows, dt: f32, gravity: [f32; 3]) -> Vec<EnergyGain> {
        self.per_sequence(|model, frames| {
            let gains = energy_gains(frames, dt, gravity);
            let over = |gains: &[f64], (a, b): (usize, usize)| -> f64 {
                gains.iter().take(b + 1).skip(a).sum()
            };
            EnergyGain {
                model: model.to_string(),
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
    pub fn far_shares(&self, windows: &Windows, radius: f32, up: [f32; 3]) -> Vec<FarShare> {
        let reach = FAR_REACH_RADII * f64::from(radius);
        self.per_rollout(|model, frames| {
            let mean = |(a, b): (usize, usize)| -> FarSplit {
                let splits: Vec<FarSplit> = frames
                    .iter()
                    .zip(&self.truth)
                    .take(b + 1)
                    .skip(a)
                    .map(|(p, t)| {
                        far_split(p, &t.pos, up, reach).unwrap_or(FarSplit {
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

/// NeuroFluid's DLF as evaluated (`eval.weight_interpolation`): `pretrained` plus `fraction` of
/// the change from it to `grounded`.
pub fn evaluated_dlf(
    pretrained: &DlfNet,
    grounded: &DlfNet,
    fraction: f64,
) -> anyhow::Result<DlfNet> {
    if fraction == 1.0 {
        return Ok(grounded.clone());
    }
    tracing::info!(
        fraction,
        "NeuroFluid's DLF: the pretrained weights plus this fraction of grounding's change"
    );
    neurofluid_core::params::interpolate(pretrained, grounded.clone(), fraction)
        .context("eval.weight_interpolation: the grounded DLF against dlf.weights")
}

/// The test split's true particles, the state every rollout starts from (the truth of its first
/// frame, or the particles from images) and the number of steps.
fn test_start(run: &Run) -> anyhow::Result<(Vec<Particles>, Particles, usize)> {
    let test = run.scene.frames(Role::Test);
    let truth: Vec<_> = run.scene.particle_sequence(Role::Test)?;
    check_sequence(&truth, test.start).context("the test split's particles")?;
    let start = starting_particles(run, Role::Test, test.start, "first test frame")?;
    tracing::info!(steps = test.len() - 1, "rollouts from the first test frame");
    Ok((truth, start, test.len() - 1))
}

/// `net`'s rollout of `steps` steps from `start` against the scene's boundary.
fn positions(
    run: &Run,
    net: &DlfNet,
    start: &Particles,
    steps: usize,
    what: &str,
) -> anyhow::Result<Positions> {
    let net = net.valid();
    let b = run.scene.boundary()?;
    let boundary = net.boundary(&b.points, &b.normals, &net.device());
    let bar = indicatif::ProgressBar::new(steps as u64).with_prefix(what.to_string());
    let out = rollout(&net, &start.pos, &start.vel, &boundary, steps, |_| {
        bar.inc(1)
    });
    bar.finish_and_clear();
    Ok(out.pos)
}

/// `model`'s `per_frame` statistic, the mean over each of `windows`' own frames.
fn window_mean(
    model: &str,
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
        model: model.to_string(),
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
    fn over_still_block(grounded: Positions, baseline: Positions) -> Rollouts {
        Rollouts {
            truth: (0..60)
                .map(|_| Particles {
                    pos: block(),
                    vel: vec![[0.0; 3]; 64],
                })
                .collect(),
            grounded,
            baseline: Some(baseline),
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
        let labels: Vec<&str> = ratios.iter().map(|s| s.model.as_str()).collect();
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
        let labels: Vec<&str> = shares.iter().map(|s| s.model.as_str()).collect();
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
