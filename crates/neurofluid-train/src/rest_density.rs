//! A rest-density prior for joint training (`joint.rest_density_weight`): the predicted fluid may
//! not expand past the density it had at the first training state.
//!
//! One view sees a pile's height and outline, not how densely its particles fill it: a grounded
//! DLF can match the training view with fewer particles per volume. On the test bed's honey it
//! did (honey-drop-z, seed 10: 20–24 neighbours within four radii per particle at t = 10–49
//! against the truth's 25–27, the pile as tall as the truth's and a third wider; BENCHMARKS.md,
//! twenty-eighth session), which d′ counts as fluid beside the truth. A viscous fluid does not
//! splash, so its mean density hardly moves (the truth's: 24.8 at t = 0, 25–28 after). With the
//! kernel `W(r) = (1 − r²/h²)³` for `r < h` (h = four particle radii), each particle's density
//! `ρ_i = Σ_{j≠i} W(|x_i − x_j|)` and the fluid's mean `ρ̄ = (1/N) Σ_i ρ_i`:
//!
//! L = w · max(0, 1 − ρ̄ / ρ̄₀)²
//!
//! with ρ̄₀ the first training state's mean (known). Only expansion costs: a fluid pressed denser
//! than its first state (the pretrained DLF's piles) is left to the images. The pairs are those
//! within h of the predicted positions, found on the host; W and its derivative vanish at h, so
//! holding the set fixed gives the exact gradient, through both ends of every pair: the fluid
//! contracts as a whole. L is dimensionless, so the weight does not depend on the scene's scale.

use burn::prelude::*;
use neurofluid_core::neighbors::{PairList, fixed_radius_pairs};
use neurofluid_core::tensors::sum_all;

use crate::density_prior::int_tensor;

/// Kernel support in particle radii.
pub const SUPPORT_RADII: f32 = 4.0;

/// The prior's settings, fixed for a run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RestDensity {
    /// h: the kernel's support (world units).
    pub support: f32,
    /// ρ̄₀: the first training state's mean density.
    pub rest: f64,
    /// w.
    pub weight: f64,
}

/// `W(r)` for the squared distance `r2` and support `h`.
fn kernel(r2: f64, h: f64) -> f64 {
    let q = 1.0 - r2 / (h * h);
    if q > 0.0 { q * q * q } else { 0.0 }
}

/// Σ_i ρ_i over the pairs `pairs` (each counted from both ends) with support `h`.
fn density_sum(pairs: &PairList, h: f32) -> f64 {
    let h = f64::from(h);
    pairs.dist2.iter().map(|&r2| kernel(f64::from(r2), h)).sum()
}

/// ρ̄ of `points` with support `h`, on the host (every pair within h, each counted from both ends).
pub fn mean_density(points: &[[f32; 3]], h: f32) -> f64 {
    if points.is_empty() {
        return 0.0;
    }
    density_sum(&fixed_radius_pairs(points, points, h, true), h) / points.len() as f64
}

impl RestDensity {
    /// The prior of weight `weight` for particles of `radius`, its ρ̄₀ taken from `initial` (the
    /// true first training state).
    pub fn new(initial: &[[f32; 3]], radius: f32, weight: f64) -> anyhow::Result<Self> {
        let support = SUPPORT_RADII * radius;
        let rest = mean_density(initial, support);
        anyhow::ensure!(
            rest.is_finite() && rest > 0.0,
            "joint.rest_density_weight: no two particles of the first training state lie within \
             {SUPPORT_RADII} particle radii of each other (mean density {rest}); the prior needs \
             a fluid, not scattered points"
        );
        Ok(Self {
            support,
            rest,
            weight,
        })
    }

    /// L on the host for `points` (its definition; the tests' reference).
    pub fn host_loss(&self, points: &[[f32; 3]]) -> f64 {
        let deficit = (1.0 - mean_density(points, self.support) / self.rest).max(0.0);
        self.weight * deficit * deficit
    }

    /// L at the positions `pos` (`[N, 3]`, differentiable through its graph; `points` its host
    /// copy) and ρ̄/ρ̄₀ there; `None` for the term when the fluid is not below its rest density.
    pub fn loss(&self, pos: &Tensor<2>, points: &[[f32; 3]]) -> (Option<Tensor<1>>, f64) {
        let pairs = fixed_radius_pairs(points, points, self.support, true);
        let h = f64::from(self.support);
        let n = points.len().max(1) as f64;
        let ratio = density_sum(&pairs, self.support) / n / self.rest;
        if ratio >= 1.0 || pairs.num_pairs() == 0 {
            return (None, ratio);
        }
        let device = pos.device();
        let index = |ids: &[u32]| int_tensor(ids.iter().map(|&i| i as usize), &device);
        let own = index(&pairs.query_of_pair());
        let other = index(&pairs.indices);
        let d = pos.clone().select(0, own) - pos.clone().select(0, other);
        let q = d
            .powi_scalar(2)
            .sum_dim(1)
            .mul_scalar(-1.0 / (h * h))
            .add_scalar(1.0)
            .clamp_min(0.0);
        let density = sum_all(q.powi_scalar(3)).mul_scalar(1.0 / (n * self.rest));
        let deficit = density.neg().add_scalar(1.0);
        (Some(deficit.powi_scalar(2).mul_scalar(self.weight)), ratio)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stages::views::{points_tensor, scalar, tensor_points};

    const RADIUS: f32 = 0.025;

    /// A 6 × 6 × 6 lattice of spacing two radii (a block of fluid at rest), off the origin and
    /// jittered deterministically so that no pair sits exactly on the support.
    fn block(scale: f32) -> Vec<[f32; 3]> {
        let mut p = Vec::new();
        for i in 0..6 {
            for j in 0..6 {
                for k in 0..6 {
                    let jitter = ((i * 37 + j * 17 + k * 7) % 11) as f32 * 1e-4;
                    p.push([
                        0.3 + scale * (i as f32 * 0.05 + jitter),
                        0.2 + scale * (j as f32 * 0.05 - jitter),
                        0.1 + scale * (k as f32 * 0.05 + 0.5 * jitter),
                    ]);
                }
            }
        }
        p
    }

    /// ρ̄ by brute force over all pairs.
    fn brute_mean_density(points: &[[f32; 3]], h: f32) -> f64 {
        let mut sum = 0.0;
        for (i, a) in points.iter().enumerate() {
            for (j, b) in points.iter().enumerate() {
                if i != j {
                    let r2: f32 = (0..3).map(|k| (a[k] - b[k]) * (a[k] - b[k])).sum();
                    if r2 <= h * h {
                        sum += kernel(f64::from(r2), f64::from(h));
                    }
                }
            }
        }
        sum / points.len() as f64
    }

    #[test]
    fn the_mean_density_is_the_brute_force_sum() {
        for scale in [0.8, 1.0, 1.3] {
            let points = block(scale);
            let h = SUPPORT_RADII * RADIUS;
            let (grid, brute) = (mean_density(&points, h), brute_mean_density(&points, h));
            assert!((grid - brute).abs() < 1e-9 * brute, "{grid} vs {brute}");
            assert!(brute > 0.0);
        }
    }

    #[test]
    fn a_fluid_at_or_above_its_rest_density_costs_nothing() {
        let device = neurofluid_core::device::cpu().autodiff();
        let prior = RestDensity::new(&block(1.0), RADIUS, 1.0).unwrap();
        for scale in [1.0, 0.9] {
            let points = block(scale);
            let (term, ratio) = prior.loss(&points_tensor(&points, &device), &points);
            assert!(term.is_none(), "scale {scale}");
            assert!(ratio >= 1.0 - 1e-12, "scale {scale}: {ratio}");
            assert_eq!(prior.host_loss(&points), 0.0);
        }
    }

    #[test]
    fn an_expanded_fluid_is_pulled_together_as_finite_differences_say() {
        let device = neurofluid_core::device::cpu().autodiff();
        let prior = RestDensity::new(&block(1.0), RADIUS, 3.0).unwrap();
        let points = block(1.15);
        let pos = points_tensor(&points, &device).require_grad();
        let (term, ratio) = prior.loss(&pos, &points);
        assert!(ratio < 0.9, "{ratio}");
        let term = term.expect("an expanded fluid costs");
        let value = scalar(&term);
        let host = prior.host_loss(&points);
        assert!((value - host).abs() < 1e-5 * host, "{value} vs {host}");
        let g = tensor_points(&pos.grad(&term.backward()).unwrap());
        // central differences of the host definition (its pairs searched anew at each point)
        let h = 1e-3f32;
        for &i in &[0usize, 43, 107, 215] {
            for a in 0..3 {
                let mut up = points.clone();
                up[i][a] += h;
                let mut down = points.clone();
                down[i][a] -= h;
                let fd = (prior.host_loss(&up) - prior.host_loss(&down)) / (2.0 * f64::from(h));
                let got = f64::from(g[i][a]);
                assert!(
                    (got - fd).abs() < 2e-2 * fd.abs().max(1e-4),
                    "particle {i} axis {a}: {got} vs {fd}"
                );
            }
        }
        // a corner particle is pulled towards the block's centre
        let centre: [f32; 3] =
            std::array::from_fn(|k| points.iter().map(|p| p[k]).sum::<f32>() / 216.0);
        let inward: f32 = (0..3).map(|k| -g[0][k] * (centre[k] - points[0][k])).sum();
        assert!(inward > 0.0, "{:?}", g[0]);
    }

    #[test]
    fn scattered_points_are_refused_with_the_key() {
        let points = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
        let err = RestDensity::new(&points, RADIUS, 1.0).unwrap_err();
        assert!(
            format!("{err}").contains("joint.rest_density_weight"),
            "{err}"
        );
    }
}
