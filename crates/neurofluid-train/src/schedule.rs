//! Learning-rate schedules as pure functions of the step, so a resumed run is exact.
//!
//! `step` is the number of optimiser steps already taken (0 for the first iteration), which is
//! PyTorch's `last_epoch` when the scheduler is stepped once after every optimiser step.

use serde::{Deserialize, Serialize};

/// A learning-rate schedule.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum LrSchedule {
    /// lr(s) = lr0.
    Constant {
        /// The learning rate.
        lr0: f64,
    },
    /// lr(s) = lr0 · 0.1^(s / decay_steps): NeuroFluid's warm-up (`utils/lr_schedulers.py`).
    Exponential {
        /// Initial learning rate.
        lr0: f64,
        /// Steps per ×0.1.
        decay_steps: u64,
    },
    /// lr(s) = lr0 · gamma^#{m : s > m}: NeuroFluid's joint LambdaLR (factor 1 while s ≤ m₁,
    /// then ×gamma for every milestone passed).
    MultiStep {
        /// Initial learning rate.
        lr0: f64,
        /// Increasing milestones.
        milestones: Vec<u64>,
        /// Factor per milestone passed.
        gamma: f64,
    },
    /// lr(s) = lr0 · factors[k] for the last k with s > boundaries[k], else lr0: DLF's
    /// piecewise LambdaLR (`factor = v_k if step > boundary_k`).
    Piecewise {
        /// Initial learning rate.
        lr0: f64,
        /// Increasing boundaries.
        boundaries: Vec<u64>,
        /// Factor after each boundary (same length as `boundaries`).
        factors: Vec<f64>,
    },
}

impl LrSchedule {
    /// DLF's training schedule (spec dlf.md §5): lr0 = 1e-3, factor 1 up to 25k, then 0.5 (>25k),
    /// 0.25 (>30k), 0.125 (>35k), 0.0625 (>40k), 0.03125 (>45k).
    pub fn dlf(lr0: f64) -> Self {
        LrSchedule::Piecewise {
            lr0,
            boundaries: vec![25_000, 30_000, 35_000, 40_000, 45_000],
            factors: vec![0.5, 0.25, 0.125, 0.0625, 0.03125],
        }
    }

    /// The multiplicative factor at `step` (lr / lr0).
    pub fn factor_at(&self, step: u64) -> f64 {
        match self {
            LrSchedule::Constant { .. } => 1.0,
            LrSchedule::Exponential { decay_steps, .. } => {
                0.1f64.powf(step as f64 / (*decay_steps).max(1) as f64)
            }
            LrSchedule::MultiStep {
                milestones, gamma, ..
            } => {
                let passed = milestones.iter().filter(|&&m| step > m).count();
                gamma.powi(passed as i32)
            }
            LrSchedule::Piecewise {
                boundaries,
                factors,
                ..
            } => boundaries
                .iter()
                .zip(factors)
                .rev()
                .find(|&(&b, _)| step > b)
                .map_or(1.0, |(_, &f)| f),
        }
    }

    /// The initial learning rate.
    pub fn lr0(&self) -> f64 {
        match self {
            LrSchedule::Constant { lr0 }
            | LrSchedule::Exponential { lr0, .. }
            | LrSchedule::MultiStep { lr0, .. }
            | LrSchedule::Piecewise { lr0, .. } => *lr0,
        }
    }

    /// The learning rate for the optimiser step taken at `step` (0-based).
    pub fn lr_at(&self, step: u64) -> f64 {
        self.lr0() * self.factor_at(step)
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
        let s = LrSchedule::Exponential {
            lr0: 5e-4,
            decay_steps: 10_000,
        };
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
        let s = LrSchedule::MultiStep {
            lr0: 3e-4,
            milestones: vec![10_000, 75_000, 150_000],
            gamma: 0.5,
        };
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
        let s = LrSchedule::MultiStep {
            lr0: 1e-5,
            milestones: vec![10_000, 30_000, 50_000, 100_000, 300_000],
            gamma: 0.5,
        };
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
            assert_eq!(s.factor_at(step), f, "step {step}");
            assert!(close(s.lr_at(step), 1e-5 * f));
        }
    }

    #[test]
    fn dlf_piecewise_at_every_boundary() {
        let s = LrSchedule::dlf(1e-3);
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
        assert!(close(s.lr_at(45_001), 3.125e-5));
    }

    #[test]
    fn schedules_serialise() {
        let s = LrSchedule::dlf(1e-3);
        let json = serde_json::to_string(&s).unwrap();
        assert!(json.contains("\"kind\":\"piecewise\""));
        let back: LrSchedule = serde_json::from_str(&json).unwrap();
        assert_eq!(back, s);
        assert_eq!(LrSchedule::Constant { lr0: 0.1 }.lr_at(123_456), 0.1);
    }
}
