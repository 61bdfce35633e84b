//! One parameter group's optimiser: Adam with its learning rate, ε and a schedule that is a pure
//! function of the step, so a resumed run is exact.
//!
//! A schedule reads one number: the updates its group has taken before this one (0 for the
//! group's first update), which is PyTorch's `last_epoch` when the scheduler is stepped once after
//! every optimiser step. Each [`Group`] counts its own: in the joint stage with `bptt_steps` = 4,
//! DLF is updated once per window, so its milestones count windows, not iterations.
//!
//! Each group has its defaults written once, in its [`OptimDefaults`] marker; a table that sets
//! only some keys (`[joint.dlf_optim] lr = 1e-4`) keeps the group's other defaults.

use std::fmt::Debug;
use std::marker::PhantomData;

use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use serde::{Deserialize, Serialize};

/// The factor a learning rate is multiplied by at a given step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Schedule {
    /// factor(s) = 1.
    Constant,
    /// factor(s) = 0.1^(s / decay_steps): NeuroFluid's warm-up (`utils/lr_schedulers.py`).
    Exponential {
        /// Steps per ×0.1.
        decay_steps: u64,
    },
    /// factor(s) = gamma^#{m : s > m}: NeuroFluid's joint LambdaLR (1 while s ≤ m₁, then
    /// ×gamma for every milestone passed).
    MultiStep {
        /// Increasing milestones.
        milestones: Vec<u64>,
        /// Factor per milestone passed.
        gamma: f64,
    },
    /// factor(s) = factors[k] for the last k with s > boundaries[k], else 1: DLF's piecewise
    /// LambdaLR (`factor = v_k if step > boundary_k`).
    Piecewise {
        /// Increasing boundaries.
        boundaries: Vec<u64>,
        /// Factor after each boundary (same length as `boundaries`).
        factors: Vec<f64>,
    },
}

impl Schedule {
    /// DLF's training schedule (spec dlf.md §5) for a run of `iterations` steps: factor 1, then
    /// 0.5/0.25/0.125/0.0625/0.03125 after 25k/30k/35k/40k/45k of 50k steps, the boundaries
    /// scaled in proportion for other run lengths.
    pub fn dlf(iterations: u64) -> Self {
        let scale = iterations as f64 / 50_000.0;
        Schedule::Piecewise {
            boundaries: [25_000.0, 30_000.0, 35_000.0, 40_000.0, 45_000.0]
                .iter()
                .map(|b: &f64| (b * scale).floor() as u64)
                .collect(),
            factors: vec![0.5, 0.25, 0.125, 0.0625, 0.03125],
        }
    }

    /// [`Schedule::dlf`] over the updates taken: DLF's reference steps its scheduler before each
    /// update, so an update's factor is `dlf`'s at one more than the updates taken before it;
    /// here every boundary is one lower (one at 0, in a run of a single step, stays at 0).
    pub fn dlf_per_update(iterations: u64) -> Self {
        match Self::dlf(iterations) {
            Schedule::Piecewise {
                boundaries,
                factors,
            } => Schedule::Piecewise {
                boundaries: boundaries.iter().map(|b| b.saturating_sub(1)).collect(),
                factors,
            },
            _ => unreachable!("DLF's schedule is piecewise"),
        }
    }

    /// The multiplicative factor at `step` (lr / lr0).
    pub fn factor_at(&self, step: u64) -> f64 {
        match self {
            Schedule::Constant => 1.0,
            Schedule::Exponential { decay_steps } => {
                0.1f64.powf(step as f64 / (*decay_steps).max(1) as f64)
            }
            Schedule::MultiStep { milestones, gamma } => {
                let passed = milestones.iter().filter(|&&m| step > m).count();
                gamma.powi(passed as i32)
            }
            Schedule::Piecewise {
                boundaries,
                factors,
            } => boundaries
                .iter()
                .zip(factors)
                .rev()
                .find(|&(&b, _)| step > b)
                .map_or(1.0, |(_, &f)| f),
        }
    }

    /// Why the schedule cannot be used (`None` when it can).
    pub fn problem(&self) -> Option<&'static str> {
        let increasing = |v: &[u64]| v.windows(2).all(|w| w[0] < w[1]);
        match self {
            Schedule::Constant => None,
            Schedule::Exponential { decay_steps } => {
                (*decay_steps == 0).then_some("decay_steps: expected at least 1")
            }
            Schedule::MultiStep { milestones, gamma } => {
                if !increasing(milestones) {
                    Some("milestones: expected strictly increasing steps")
                } else if !(gamma.is_finite() && *gamma > 0.0 && *gamma <= 1.0) {
                    Some("gamma: expected a factor in (0, 1]")
                } else {
                    None
                }
            }
            Schedule::Piecewise {
                boundaries,
                factors,
            } => {
                if !increasing(boundaries) {
                    Some("boundaries: expected strictly increasing steps")
                } else if boundaries.len() != factors.len() {
                    Some("factors: expected one factor per boundary")
                } else if factors.iter().any(|f| !(f.is_finite() && *f > 0.0)) {
                    Some("factors: expected positive factors")
                } else {
                    None
                }
            }
        }
    }
}

/// The defaults of one parameter group (a marker type per group).
pub trait OptimDefaults: Debug + Clone + PartialEq + Default {
    /// Initial learning rate.
    const LR: f64;
    /// Adam's ε.
    const EPSILON: f64;
    /// The schedule.
    fn schedule() -> Schedule;
}

/// Adam with a learning-rate schedule: one parameter group. `G` gives the group's defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields, bound = "")]
pub struct OptimConfig<G: OptimDefaults> {
    /// Initial learning rate.
    pub lr: f64,
    /// Adam's ε (PyTorch's 1e-8 in NeuroFluid).
    pub epsilon: f64,
    /// How the learning rate changes with the step.
    pub schedule: Schedule,
    #[serde(skip)]
    group: PhantomData<G>,
}

impl<G: OptimDefaults> Default for OptimConfig<G> {
    fn default() -> Self {
        Self {
            lr: G::LR,
            epsilon: G::EPSILON,
            schedule: G::schedule(),
            group: PhantomData,
        }
    }
}

impl<G: OptimDefaults> OptimConfig<G> {
    /// The learning rate of the update taken after `updates` earlier ones.
    pub fn lr_at(&self, updates: u64) -> f64 {
        self.lr * self.schedule.factor_at(updates)
    }

    /// The group in training: a fresh Adam that has taken no update.
    pub fn group(&self) -> Group<G> {
        Group {
            cfg: self.clone(),
            adam: self.adam(),
            updates: 0,
        }
    }

    /// A fresh Adam with this ε.
    pub fn adam(&self) -> ModuleOptimizer {
        AdamConfig::new().with_epsilon(self.epsilon as f32).init()
    }

    /// Why the settings cannot be used, as `(key under the group, what was expected)`.
    pub fn problem(&self) -> Option<(&'static str, &'static str)> {
        if !(self.lr.is_finite() && self.lr >= 0.0) {
            return Some(("lr", "expected a learning rate ≥ 0"));
        }
        if !(self.epsilon.is_finite() && self.epsilon > 0.0) {
            return Some(("epsilon", "expected a positive ε"));
        }
        self.schedule.problem().map(|p| ("schedule", p))
    }
}

/// One parameter group in training: its settings, its Adam and the number of updates it has
/// taken, which its schedule reads.
pub struct Group<G: OptimDefaults> {
    cfg: OptimConfig<G>,
    adam: ModuleOptimizer,
    updates: u64,
}

impl<G: OptimDefaults> Group<G> {
    /// The learning rate of the next update.
    pub fn lr(&self) -> f64 {
        self.cfg.lr_at(self.updates)
    }

    /// The updates taken.
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// Updates `module` with `grads` at [`Group::lr`] and counts the update.
    pub fn step<M: Module>(&mut self, module: M, grads: GradientsParams) -> M {
        let lr = self.lr();
        self.updates += 1;
        self.adam.step(lr, module, grads)
    }

    /// The Adam (its moments, to save).
    pub fn adam(&self) -> &ModuleOptimizer {
        &self.adam
    }

    /// A fresh Adam of the group's settings (to load saved moments into).
    pub fn fresh_adam(&self) -> ModuleOptimizer {
        self.cfg.adam()
    }

    /// Puts back a saved Adam and update count.
    pub fn restore(&mut self, adam: ModuleOptimizer, updates: u64) {
        self.adam = adam;
        self.updates = updates;
    }
}

/// The renderer warm-up: 5e-4, ×0.1 every 10k steps (spec §4.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WarmupGroup;
impl OptimDefaults for WarmupGroup {
    const LR: f64 = 5e-4;
    const EPSILON: f64 = 1e-8;
    fn schedule() -> Schedule {
        Schedule::Exponential {
            decay_steps: 10_000,
        }
    }
}

/// A NeRF baseline or the NeRF of the initial particles: the original NeRF's 5e-4, ×0.1 every
/// 250k steps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct NerfGroup;
impl OptimDefaults for NerfGroup {
    const LR: f64 = 5e-4;
    const EPSILON: f64 = 1e-8;
    fn schedule() -> Schedule {
        Schedule::Exponential {
            decay_steps: 250_000,
        }
    }
}

/// PhysNeRF in the joint stage: 3e-4, halved after 10k, 75k, 150k (spec §4.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct JointPhysNerfGroup;
impl OptimDefaults for JointPhysNerfGroup {
    const LR: f64 = 3e-4;
    const EPSILON: f64 = 1e-8;
    fn schedule() -> Schedule {
        Schedule::MultiStep {
            milestones: vec![10_000, 75_000, 150_000],
            gamma: 0.5,
        }
    }
}

/// DLF in the joint stage: 1e-5, halved after 10k, 30k, 50k, 100k, 300k (spec §4.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct JointDlfGroup;
impl OptimDefaults for JointDlfGroup {
    const LR: f64 = 1e-5;
    const EPSILON: f64 = 1e-8;
    fn schedule() -> Schedule {
        Schedule::MultiStep {
            milestones: vec![10_000, 30_000, 50_000, 100_000, 300_000],
            gamma: 0.5,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-12 * b.abs().max(1e-30)
    }

    #[test]
    fn exponential_is_tenfold_per_decay_period() {
        let s = OptimConfig::<WarmupGroup>::default();
        assert_eq!(s.lr_at(0), 5e-4);
        assert!(close(s.lr_at(10_000), 5e-5));
        assert!(close(s.lr_at(40_000), 5e-8));
        assert!(close(s.lr_at(100_000), 5e-14));
        // half a period: ×1/√10
        assert!(close(s.lr_at(5_000), 5e-4 / 10f64.sqrt()));
        assert!(close(s.lr_at(1), 5e-4 * 0.1f64.powf(1e-4)));
        // strictly decreasing
        assert!((1..200).all(|k| s.lr_at(k) < s.lr_at(k - 1)));
    }

    #[test]
    fn neurofluid_renderer_multistep_at_every_milestone() {
        let s = OptimConfig::<JointPhysNerfGroup>::default();
        let hand = [
            (0, 3e-4),
            (9_999, 3e-4),
            (10_000, 3e-4), // factor 1.0 for s ≤ 10k (spec §4.2)
            (10_001, 1.5e-4),
            (75_000, 1.5e-4),
            (75_001, 0.75e-4),
            (150_000, 0.75e-4),
            (150_001, 0.375e-4),
            (1_000_000, 0.375e-4),
        ];
        for (step, lr) in hand {
            assert!(close(s.lr_at(step), lr), "step {step}: {}", s.lr_at(step));
        }
    }

    #[test]
    fn neurofluid_transition_multistep_at_every_milestone() {
        let s = OptimConfig::<JointDlfGroup>::default();
        let factors = [
            (10_000, 1.0),
            (10_001, 0.5),
            (30_000, 0.5),
            (30_001, 0.25),
            (50_000, 0.25),
            (50_001, 0.125),
            (100_000, 0.125),
            (100_001, 0.0625),
            (300_000, 0.0625),
            (300_001, 0.03125),
            (980_000, 0.03125),
        ];
        for (step, f) in factors {
            assert_eq!(s.schedule.factor_at(step), f, "step {step}");
            assert!(close(s.lr_at(step), 1e-5 * f));
        }
    }

    #[test]
    fn dlf_piecewise_at_every_boundary() {
        let s = Schedule::dlf(50_000);
        let factors = [
            (0, 1.0),
            (25_000, 1.0),
            (25_001, 0.5),
            (30_000, 0.5),
            (30_001, 0.25),
            (35_001, 0.125),
            (40_000, 0.125),
            (40_001, 0.0625),
            (45_000, 0.0625),
            (45_001, 0.03125),
            (50_000, 0.03125),
        ];
        for (step, f) in factors {
            assert_eq!(s.factor_at(step), f, "step {step}");
        }
        assert!(close(1e-3 * s.factor_at(45_001), 3.125e-5));
        // other run lengths scale the boundaries (DLF's `dlf_lr_factor`)
        let short = Schedule::dlf(100);
        assert_eq!(short.factor_at(50), 1.0);
        assert_eq!(short.factor_at(51), 0.5);
        assert_eq!(short.factor_at(91), 0.03125);
    }

    #[test]
    fn dlf_per_update_is_dlf_one_update_later() {
        // the supervised trainer's rates before groups counted updates: `lr_at(step + 1)`
        for iterations in [2, 3, 7, 100, 1234, 50_000] {
            let (reference, per_update) = (
                Schedule::dlf(iterations),
                Schedule::dlf_per_update(iterations),
            );
            for n in 0..iterations {
                assert_eq!(
                    per_update.factor_at(n),
                    reference.factor_at(n + 1),
                    "{iterations} iterations, update {n}"
                );
            }
        }
    }

    #[test]
    fn schedules_serialise() {
        let s = Schedule::dlf(50_000);
        let json = serde_json::to_string(&s).unwrap();
        assert!(json.contains("\"kind\":\"piecewise\""));
        let back: Schedule = serde_json::from_str(&json).unwrap();
        assert_eq!(back, s);
        assert_eq!(Schedule::Constant.factor_at(123_456), 1.0);
    }

    #[test]
    fn a_partial_table_keeps_the_groups_other_defaults() {
        let c: OptimConfig<JointDlfGroup> = toml::from_str("lr = 1e-4").unwrap();
        assert_eq!(c.lr, 1e-4);
        assert_eq!(c.schedule, JointDlfGroup::schedule());
        assert_eq!(c.epsilon, 1e-8);
        assert!(toml::from_str::<OptimConfig<WarmupGroup>>("lr0 = 1").is_err());
        let bad: OptimConfig<WarmupGroup> =
            toml::from_str("[schedule]\nkind = \"multi_step\"\nmilestones = [3, 2]\ngamma = 0.5")
                .unwrap();
        assert_eq!(bad.problem().unwrap().0, "schedule");
    }
}
