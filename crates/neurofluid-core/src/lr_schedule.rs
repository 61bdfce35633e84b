//! Learning-rate schedules that are pure functions of the step: the factor a group's initial
//! learning rate is multiplied by after a given number of updates, so a resumed run is exact.
//! The forms are PyTorch's schedulers as NeuroFluid and DLF use them (exponential decay,
//! `MultiStepLR`, a piecewise `LambdaLR`); the step is PyTorch's `last_epoch` when the scheduler
//! is stepped once after every optimiser step.

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_kind_gives_its_factor() {
        assert_eq!(Schedule::Constant.factor_at(123_456), 1.0);
        let exponential = Schedule::Exponential { decay_steps: 100 };
        assert_eq!(exponential.factor_at(0), 1.0);
        assert!((exponential.factor_at(200) - 0.01).abs() < 1e-15);
        assert!((exponential.factor_at(50) - 0.1f64.sqrt()).abs() < 1e-15);
        let multi = Schedule::MultiStep {
            milestones: vec![10, 20],
            gamma: 0.5,
        };
        let at =
            |s: &Schedule, steps: &[u64]| steps.iter().map(|&n| s.factor_at(n)).collect::<Vec<_>>();
        assert_eq!(
            at(&multi, &[0, 10, 11, 20, 21, 1000]),
            [1.0, 1.0, 0.5, 0.5, 0.25, 0.25]
        );
        let piecewise = Schedule::Piecewise {
            boundaries: vec![5, 8],
            factors: vec![0.5, 0.1],
        };
        assert_eq!(at(&piecewise, &[0, 5, 6, 8, 9]), [1.0, 1.0, 0.5, 0.5, 0.1]);
    }

    #[test]
    fn unusable_schedules_are_named() {
        assert!(
            Schedule::Exponential { decay_steps: 0 }
                .problem()
                .unwrap()
                .contains("decay_steps")
        );
        let unordered = Schedule::MultiStep {
            milestones: vec![3, 2],
            gamma: 0.5,
        };
        assert!(unordered.problem().unwrap().contains("milestones"));
        let short = Schedule::Piecewise {
            boundaries: vec![1, 2],
            factors: vec![0.5],
        };
        assert!(short.problem().unwrap().contains("one factor per boundary"));
        assert!(Schedule::Constant.problem().is_none());
    }

    #[test]
    fn schedules_serialise() {
        let s = Schedule::Piecewise {
            boundaries: vec![25, 30],
            factors: vec![0.5, 0.25],
        };
        let json = serde_json::to_string(&s).unwrap();
        assert!(json.contains("\"kind\":\"piecewise\""));
        let back: Schedule = serde_json::from_str(&json).unwrap();
        assert_eq!(back, s);
    }
}
