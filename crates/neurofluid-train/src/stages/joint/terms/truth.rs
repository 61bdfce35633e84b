//! The truth (`[joint.terms.truth]`): each step's predicted positions held to the true ones of
//! the same frame, in particle radii²: matched by particle index, or (`matching = "nearest"`) by
//! the nearest particle both ways, the symmetric Chamfer distance, which does not care which
//! particle is which (a truth from another simulator need not keep DLF's particle order, and
//! index matching holds a fluid to one arrangement of its particles).
//!
//! A reference, never a method: the images are all NeuroFluid may see. With it, grounding at the
//! same budget and rules is given every particle's truth, a reference for what the images could
//! teach DLF. It needs the scene's true particles of every training frame, the predicted
//! particles (not initial particles from images).

use anyhow::Context;
use burn::prelude::*;
use serde::{Deserialize, Serialize};

use super::anchor::mean_square_distance;
use super::{ParticleTerm, TermContext, TermSettings, Transition, weight_problem};
use neurofluid_core::tensors::points_tensor;

/// `[joint.terms.truth]`: each step's prediction held to the true particles of its frame
/// (a reference given the truth, never a method).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TruthSettings {
    /// w, per particle radius² of mean squared distance to the truth.
    pub weight: f64,
    /// How predicted particles meet true ones: `"index"` (the default) or `"nearest"`.
    #[serde(default)]
    pub matching: TruthMatching,
}

/// How the truth term matches predicted particles to true ones.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TruthMatching {
    /// The i-th predicted particle to the i-th true one.
    #[default]
    Index,
    /// Each particle to the nearest of the other set, both ways, averaged: ½ (mean over the
    /// predicted of the squared distance to the nearest true one + the same from the truth).
    Nearest,
}

impl TermSettings for TruthSettings {
    fn build(&self, ctx: &TermContext) -> anyhow::Result<Option<Box<dyn ParticleTerm>>> {
        if self.weight <= 0.0 {
            return Ok(None);
        }
        let truth = ctx.truth.with_context(|| {
            "joint.terms.truth needs the scene's true particles of every training frame; this \
             scene has none"
        })?;
        let by_index = self.matching == TruthMatching::Index;
        anyhow::ensure!(
            truth.len() as u64 > ctx.transitions && (!by_index || truth[0].len() == ctx.particles),
            "joint.terms.truth needs the true particles of every training frame (matched by \
             index: as many as the predicted ones): the truth has {} frames of {} particles, the joint stage {} \
             transitions from {} particles",
            truth.len(),
            truth.first().map_or(0, Vec::len),
            ctx.transitions,
            ctx.particles
        );
        let device = ctx.pretrained.device();
        Ok(Some(Box::new(Truth {
            frames: truth.iter().map(|p| points_tensor(p, &device)).collect(),
            radius: ctx.radius,
            weight: self.weight,
            matching: self.matching,
        })))
    }

    fn problem(&self) -> Option<(&'static str, String)> {
        weight_problem(self.weight)
    }
}

/// The truth term with every training frame's true particles on the device.
pub struct Truth {
    frames: Vec<Tensor<2>>,
    radius: f32,
    weight: f64,
    matching: TruthMatching,
}

impl ParticleTerm for Truth {
    fn name(&self) -> &'static str {
        "truth"
    }

    fn loss(&self, step: &Transition) -> Tensor<1> {
        let target = self.frames[step.frame].clone();
        let pred = step.after.0.clone();
        let loss = match self.matching {
            TruthMatching::Index => mean_square_distance(pred, target, self.radius),
            TruthMatching::Nearest => chamfer(pred, target, self.radius),
        };
        loss.mul_scalar(self.weight)
    }
}

/// Queries per block of the nearest-point search: a block's squared distances to every point
/// are one `[block, points]` matrix (4 MB at 1,024 × 1,024).
const SEARCH_BLOCK: usize = 1024;

/// The symmetric Chamfer distance of `pred` and `target` (`[n, 3]` and `[m, 3]`) in radii²:
/// ½ (mean over `pred` of the squared distance to its nearest `target` point + the same from
/// `target`), differentiable through `pred` (the matches are found without the graph).
pub fn chamfer(pred: Tensor<2>, target: Tensor<2>, radius: f32) -> Tensor<1> {
    let held = pred.clone().detach();
    let to_target = target
        .clone()
        .select(0, nearest(held.clone(), target.clone()));
    let to_pred = pred.clone().select(0, nearest(target.clone(), held));
    (mean_square_distance(pred, to_target, radius) + mean_square_distance(to_pred, target, radius))
        .mul_scalar(0.5)
}

/// For each row of `queries` `[n, 3]`, the index of the nearest row of `points` `[m, 3]` (on
/// the device, [`SEARCH_BLOCK`] queries at a time).
fn nearest(queries: Tensor<2>, points: Tensor<2>) -> Tensor<1, Int> {
    let [n, _] = queries.dims();
    let m = points.dims()[0];
    let points_t = points.clone().transpose();
    let p2 = points.powi_scalar(2).sum_dim(1).reshape([1, m]);
    let blocks: Vec<Tensor<1, Int>> = (0..n)
        .step_by(SEARCH_BLOCK)
        .map(|start| {
            let len = SEARCH_BLOCK.min(n - start);
            let q = queries.clone().narrow(0, start, len);
            // |q − p|² without the |q|² each row shares
            let d2 = p2.clone() - q.matmul(points_t.clone()).mul_scalar(2.0);
            d2.argmin(1).reshape([len])
        })
        .collect();
    Tensor::cat(blocks, 0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stages::views::{points_tensor, scalar, tensor_points};

    fn rows(v: &[[f32; 3]]) -> Tensor<2> {
        points_tensor(v, &neurofluid_core::device::cpu().autodiff())
    }

    /// Points spread over a metre cube, a fixed sequence.
    fn cloud(n: usize, seed: u32) -> Vec<[f32; 3]> {
        let mut x = seed.wrapping_mul(2_654_435_761).max(1);
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            (x % 10_000) as f32 / 10_000.0
        };
        (0..n).map(|_| [next(), next(), next()]).collect()
    }

    fn nearest_sq(p: [f32; 3], set: &[[f32; 3]]) -> (f64, usize) {
        set.iter()
            .enumerate()
            .map(|(k, q)| {
                let d: f64 = (0..3).map(|i| f64::from(p[i] - q[i]).powi(2)).sum();
                (d, k)
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .unwrap()
    }

    /// The term is the Chamfer distance computed by brute force, across search blocks and
    /// unequal sets; the same particles in another order are at distance 0.
    #[test]
    fn nearest_matching_is_the_brute_force_chamfer_and_ignores_order() {
        let (pred, target) = (cloud(1500, 3), cloud(700, 11));
        let r = 0.025f32;
        let brute = |a: &[[f32; 3]], b: &[[f32; 3]]| {
            a.iter().map(|&p| nearest_sq(p, b).0).sum::<f64>() / a.len() as f64
        };
        let expected = 0.5 * (brute(&pred, &target) + brute(&target, &pred)) / f64::from(r * r);
        let got = scalar(&chamfer(rows(&pred), rows(&target), r));
        assert!(
            (got - expected).abs() < 1e-4 * expected,
            "{got} vs {expected}"
        );
        let mut shuffled = pred.clone();
        shuffled.reverse();
        shuffled.swap(3, 900);
        let same = scalar(&chamfer(rows(&pred), rows(&shuffled), r));
        assert!(same.abs() < 1e-9, "{same}");
        let by_index = scalar(&mean_square_distance(rows(&pred), rows(&shuffled), r));
        assert!(
            by_index > 1.0,
            "index matching should see the reorder: {by_index}"
        );
    }

    /// The gradient is the definition's by hand: (p − T(p)) / (n r²) from the prediction's own
    /// match plus Σ (p − t) / (m r²) over the true points whose nearest prediction is p.
    #[test]
    fn nearest_matching_gradient_is_the_definitions() {
        let (pred, target) = (cloud(40, 5), cloud(25, 7));
        let r = 0.1f32;
        let x = rows(&pred).require_grad();
        let g = tensor_points(
            &x.grad(&chamfer(x.clone(), rows(&target), r).backward())
                .unwrap(),
        );
        let (n, m, r2) = (pred.len() as f64, target.len() as f64, f64::from(r * r));
        let mut expected = vec![[0.0f64; 3]; pred.len()];
        for (k, &p) in pred.iter().enumerate() {
            let t = target[nearest_sq(p, &target).1];
            for i in 0..3 {
                expected[k][i] += f64::from(p[i] - t[i]) / (n * r2);
            }
        }
        for &t in &target {
            let k = nearest_sq(t, &pred).1;
            for i in 0..3 {
                expected[k][i] += f64::from(pred[k][i] - t[i]) / (m * r2);
            }
        }
        for (k, e) in expected.iter().enumerate() {
            for i in 0..3 {
                let got = f64::from(g[k][i]);
                assert!(
                    (got - e[i]).abs() < 1e-3 * (1.0 + e[i].abs()),
                    "{k} {i}: {got} vs {}",
                    e[i]
                );
            }
        }
    }
}
