//! One parameter group's optimiser: Adam with its learning rate, ε and a schedule that is a pure
//! function of the step ([`neurofluid_core::lr_schedule`]), so a resumed run is exact.
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
use neurofluid_core::lr_schedule::Schedule;
use serde::{Deserialize, Serialize};

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

/// The physical scalars the joint stage fits (`[joint.physics]`): 1e-2, constant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct JointPhysicsGroup;
impl OptimDefaults for JointPhysicsGroup {
    const LR: f64 = 1e-2;
    const EPSILON: f64 = 1e-8;
    fn schedule() -> Schedule {
        Schedule::Constant
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
