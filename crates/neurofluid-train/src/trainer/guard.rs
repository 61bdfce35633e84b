//! The divergence guard every stage shares: what counts as a step gone wrong (the gradient norms
//! it reads: [`neurofluid_core::gradients`]).
//!
//! The [`Driver`](super::Driver) asks the [`Guard`] after every step, before anything is logged
//! or checkpointed. A step is bad when its loss or a gradient norm is not finite, when the loss
//! or a group's gradient norm explodes (grows [`EXPLOSION_FACTOR`]-fold over the session's first,
//! or over [`EXPLOSION_FLOOR`]), when the trainer's own state check fails (e.g. particles far
//! outside the box), or when a parameter group received no gradient for
//! [`NO_GRADIENT_PATIENCE`] updates in a row (a loss that depends on none of its parameters:
//! nothing can be learned). The loss of a step is computed before its update, so a checkpoint is
//! trusted only once a healthy update followed it; the driver rolls back one that did not.

use super::StepStats;

/// A loss (or gradient norm) this many times the session's first counts as exploding.
pub const EXPLOSION_FACTOR: f64 = 1e4;

/// Updates in a row without any gradient for a group after which the run stops (a shorter
/// session stops at its end when a group received no gradient in any update).
pub const NO_GRADIENT_PATIENCE: u64 = 10;

/// Losses and gradient norms below this count as this for the explosion test (a loss near
/// zero at the start of a fine-tuning must not make ordinary noise an explosion).
pub const EXPLOSION_FLOOR: f64 = 1e-3;

/// What the guard remembers of the session: the first loss and gradient norms, and the updates
/// in a row without a gradient, per group.
#[derive(Debug, Default)]
pub struct Guard {
    first_loss: Option<f64>,
    first_norm: Vec<(&'static str, f64)>,
    without_gradient: Vec<(&'static str, u64)>,
    updates: u64,
}

fn entry<'a, T: Copy>(
    list: &'a mut Vec<(&'static str, T)>,
    group: &'static str,
    init: T,
) -> &'a mut T {
    match list.iter().position(|(g, _)| *g == group) {
        Some(i) => &mut list[i].1,
        None => {
            list.push((group, init));
            &mut list.last_mut().expect("just pushed").1
        }
    }
}

fn no_gradient(group: &str, count: u64) -> String {
    let why = match group {
        "physnerf" => {
            ". For PhysNeRF this means no ray sample was given any density: no sample has \
             physnerf.k neighbours within physnerf.search_radius inside [scene.near, scene.far], \
             or the network starts with σ ≤ 0 everywhere (ReLU density; `physnerf.density = \
             \"softplus\"` cannot start dead)"
        }
        "nerf" => {
            ". For a NeRF this means its ReLU density is 0 on every sample: it collapsed to the \
             white background, or started that way (more `nerf.precrop_iters`, a lower \
             `nerf.optim.lr` or another seed)"
        }
        _ => "",
    };
    format!(
        "{group} received no gradient in {count} updates in a row: the loss depends on none of \
         its parameters{why}"
    )
}

impl Guard {
    /// A guard with nothing seen.
    pub fn new() -> Self {
        Self::default()
    }

    /// Checks one step's statistics; returns what went wrong. Explosions and missing gradients
    /// are judged on updates (a step inside a multi-step window only adds to the window's loss).
    pub fn check(&mut self, stats: &StepStats) -> Option<String> {
        if !stats.loss.is_finite() {
            return Some(format!("the loss is {}", stats.loss));
        }
        for (group, norm) in &stats.grad_norms {
            if !norm.is_finite() {
                return Some(format!("the gradient norm of {group} is {norm}"));
            }
        }
        if !stats.updated {
            return None;
        }
        self.updates += 1;
        let first = *self.first_loss.get_or_insert(stats.loss);
        if stats.loss > EXPLOSION_FACTOR * first.max(EXPLOSION_FLOOR) {
            return Some(format!(
                "the loss exploded to {:.4e} (the session's first loss was {first:.4e})",
                stats.loss
            ));
        }
        for &(group, norm) in &stats.grad_norms {
            if norm > 0.0 {
                let first = *entry(&mut self.first_norm, group, norm);
                if norm > EXPLOSION_FACTOR * first.max(EXPLOSION_FLOOR) {
                    return Some(format!(
                        "the gradient norm of {group} exploded to {norm:.4e} (its first in the \
                         session was {first:.4e})"
                    ));
                }
            }
            let count = entry(&mut self.without_gradient, group, 0);
            *count = if norm == 0.0 { *count + 1 } else { 0 };
            if *count >= NO_GRADIENT_PATIENCE {
                return Some(no_gradient(group, *count));
            }
        }
        None
    }

    /// At the end of a session: a group that received no gradient in any of its updates.
    pub fn at_end(&self) -> Option<String> {
        self.without_gradient
            .iter()
            .find(|(_, count)| self.updates > 0 && *count == self.updates)
            .map(|(group, count)| no_gradient(group, *count))
    }
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
        assert!(g.check(&stats(f64::NAN, &[])).unwrap().contains("NaN"));
        let msg = g.check(&stats(1.0, &[("dlf", f64::INFINITY)])).unwrap();
        assert!(msg.contains("dlf") && msg.contains("inf"), "{msg}");
    }

    #[test]
    fn an_exploding_loss_or_gradient_is_caught_relative_to_the_first() {
        let mut g = Guard::new();
        assert!(g.check(&stats(2.0, &[("dlf", 0.5)])).is_none());
        assert!(g.check(&stats(2.0e4 - 1.0, &[("dlf", 0.5)])).is_none());
        assert!(g.check(&stats(2.0e4 + 1.0, &[("dlf", 0.5)])).is_some());
        let mut g = Guard::new();
        assert!(g.check(&stats(1.0, &[("dlf", 0.5)])).is_none());
        let msg = g.check(&stats(1.0, &[("dlf", 5.1e3)])).unwrap();
        assert!(msg.contains("gradient norm of dlf exploded"), "{msg}");
        // a first loss near zero is measured against the floor
        let mut g = Guard::new();
        assert!(g.check(&stats(1e-9, &[])).is_none());
        assert!(g.check(&stats(1e-2, &[])).is_none());
        assert!(g.check(&stats(11.0, &[])).is_some());
        // a step inside a window is only checked for finiteness
        let mut window = stats(1e30, &[]);
        window.updated = false;
        assert!(Guard::new().check(&window).is_none());
    }

    #[test]
    fn a_group_without_gradient_stops_after_the_patience() {
        let mut g = Guard::new();
        for _ in 0..NO_GRADIENT_PATIENCE - 1 {
            assert!(g.check(&stats(1.0, &[("physnerf", 0.0)])).is_none());
        }
        // a gradient resets the count
        assert!(g.check(&stats(1.0, &[("physnerf", 0.5)])).is_none());
        for _ in 0..NO_GRADIENT_PATIENCE - 1 {
            assert!(g.check(&stats(1.0, &[("physnerf", 0.0)])).is_none());
        }
        assert!(g.at_end().is_none());
        let msg = g.check(&stats(1.0, &[("physnerf", 0.0)])).unwrap();
        assert!(msg.contains("physnerf received no gradient"), "{msg}");
        // a session shorter than the patience is judged at its end
        let mut g = Guard::new();
        assert!(g.check(&stats(1.0, &[("dlf", 0.0)])).is_none());
        assert!(g.check(&stats(1.0, &[("dlf", 0.0)])).is_none());
        assert!(
            g.at_end()
                .unwrap()
                .contains("dlf received no gradient in 2")
        );
    }
}
