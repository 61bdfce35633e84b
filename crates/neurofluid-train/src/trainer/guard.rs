//! The divergence guard every stage shares: what counts as a step gone wrong, and the checks on
//! parameters and gradients it needs.
//!
//! The [`Driver`](super::Driver) asks the [`Guard`] after every step, before anything is logged
//! or checkpointed, so the last good checkpoint is never replaced by a bad state. A step is bad
//! when its loss or a gradient norm is not finite, when the loss explodes (grows by
//! [`EXPLOSION_FACTOR`] over the first loss of the session), when the trainer's own state check
//! fails (e.g. particles far outside the box), or when a parameter group received no gradient at
//! all for [`NO_GRADIENT_PATIENCE`] updates in a row (a loss that depends on none of its
//! parameters: nothing can be learned).

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::prelude::*;

use super::StepStats;

/// A loss this many times the first loss of the session counts as exploding.
pub const EXPLOSION_FACTOR: f64 = 1e4;

/// Updates in a row without any gradient for a group after which the run stops (fewer when the
/// stage has fewer updates).
pub const NO_GRADIENT_PATIENCE: u64 = 10;

/// The global L2 norm of the gradients `grads` holds for `module`'s parameters (0 when it holds
/// none: the loss did not depend on the module).
pub fn grad_norm<M: Module>(grads: &GradientsParams, module: &M) -> f64 {
    struct SumSquares<'a> {
        grads: &'a GradientsParams,
        sum: f64,
    }
    impl ModuleVisitor for SumSquares<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            if let Some(g) = self.grads.get::<D>(param.id) {
                let s: f64 = g.powi_scalar(2).sum().into_scalar::<f64>();
                self.sum += s;
            }
        }
    }
    let mut v = SumSquares { grads, sum: 0.0 };
    module.visit(&mut v);
    v.sum.sqrt()
}

/// What the guard remembers of the session: the first loss and the updates in a row without a
/// gradient, per group.
#[derive(Debug, Default)]
pub struct Guard {
    first_loss: Option<f64>,
    without_gradient: Vec<(&'static str, u64)>,
}

impl Guard {
    /// A guard with nothing seen.
    pub fn new() -> Self {
        Self::default()
    }

    /// Checks one step's statistics; `updates_left_in_stage` bounds the no-gradient patience.
    /// Returns what went wrong.
    pub fn check(&mut self, stats: &StepStats, updates_in_stage: u64) -> Option<String> {
        if !stats.loss.is_finite() {
            return Some(format!("the loss is {}", stats.loss));
        }
        for (group, norm) in &stats.grad_norms {
            if !norm.is_finite() {
                return Some(format!("the gradient norm of {group} is {norm}"));
            }
        }
        if stats.updated {
            let first = *self.first_loss.get_or_insert(stats.loss);
            if first > 0.0 && stats.loss > EXPLOSION_FACTOR * first {
                return Some(format!(
                    "the loss exploded to {:.4e} (the session's first loss was {first:.4e})",
                    stats.loss
                ));
            }
            let patience = NO_GRADIENT_PATIENCE.min(updates_in_stage.max(1));
            for (group, norm) in &stats.grad_norms {
                let count = match self.without_gradient.iter_mut().find(|(g, _)| g == group) {
                    Some((_, c)) => c,
                    None => {
                        self.without_gradient.push((group, 0));
                        &mut self.without_gradient.last_mut().expect("just pushed").1
                    }
                };
                *count = if *norm == 0.0 { *count + 1 } else { 0 };
                if *count >= patience {
                    return Some(format!(
                        "{group} received no gradient in {count} updates in a row: the loss \
                         depends on none of its parameters. For PhysNeRF this means no ray sample \
                         was given any density: no sample has physnerf.k neighbours within \
                         physnerf.search_radius inside [scene.near, scene.far], or the network \
                         starts with σ ≤ 0 everywhere (ReLU density; `physnerf.density = \
                         \"softplus\"` cannot start dead)"
                    ));
                }
            }
        }
        None
    }
}

/// The loss's gradients, or none when the loss depends on no parameter (every sample was
/// masked out): such a step has nothing to update.
pub fn backward(loss: Tensor<1>) -> Option<burn::tensor::Gradients> {
    loss.is_tracked().then(|| loss.backward())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stats(loss: f64, norms: &[(&'static str, f64)]) -> StepStats {
        StepStats {
            loss,
            grad_norms: norms.to_vec(),
            updated: true,
            ..StepStats::default()
        }
    }

    #[test]
    fn non_finite_loss_and_gradients_are_caught() {
        let mut g = Guard::new();
        assert!(g.check(&stats(f64::NAN, &[]), 100).unwrap().contains("NaN"));
        let msg = g
            .check(&stats(1.0, &[("dlf", f64::INFINITY)]), 100)
            .unwrap();
        assert!(msg.contains("dlf") && msg.contains("inf"), "{msg}");
    }

    #[test]
    fn an_exploding_loss_is_caught_relative_to_the_first() {
        let mut g = Guard::new();
        assert!(g.check(&stats(2.0, &[]), 100).is_none());
        assert!(g.check(&stats(2.0e4 - 1.0, &[]), 100).is_none());
        assert!(g.check(&stats(2.0e4 + 1.0, &[]), 100).is_some());
    }

    #[test]
    fn a_group_without_gradient_stops_after_the_patience() {
        let mut g = Guard::new();
        for _ in 0..NO_GRADIENT_PATIENCE - 1 {
            assert!(g.check(&stats(1.0, &[("physnerf", 0.0)]), 100).is_none());
        }
        // a gradient resets the count
        assert!(g.check(&stats(1.0, &[("physnerf", 0.5)]), 100).is_none());
        for _ in 0..NO_GRADIENT_PATIENCE - 1 {
            assert!(g.check(&stats(1.0, &[("physnerf", 0.0)]), 100).is_none());
        }
        let msg = g.check(&stats(1.0, &[("physnerf", 0.0)]), 100).unwrap();
        assert!(msg.contains("physnerf received no gradient"), "{msg}");
        // a short stage stops after all its updates
        let mut g = Guard::new();
        assert!(g.check(&stats(1.0, &[("dlf", 0.0)]), 2).is_none());
        assert!(g.check(&stats(1.0, &[("dlf", 0.0)]), 2).is_some());
    }

    #[test]
    fn gradient_norm_of_a_module() {
        use burn::nn::LinearConfig;
        let device = neurofluid_core::device::cpu().autodiff();
        let layer = LinearConfig::new(2, 1).init(&device);
        let x = Tensor::<2>::from_data([[3.0f32, 4.0]], &device);
        let loss = layer.forward(x).sum();
        let grads = GradientsParams::from_grads(loss.backward(), &layer);
        // d/dw = x, d/db = 1: |(3, 4, 1)| = √26
        assert!((grad_norm(&grads, &layer) - 26f64.sqrt()).abs() < 1e-6);
        assert_eq!(grad_norm(&GradientsParams::new(), &layer), 0.0);
        let untracked = Tensor::<1>::from_data([1.0f32], &device);
        assert!(backward(untracked).is_none());
    }
}
