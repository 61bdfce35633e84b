//! A density prior for joint training (`joint.density_weight`): every predicted particle keeps
//! the neighbourhood a fluid particle has.
//!
//! The image loss cannot see a particle that strays from the fluid: PhysNeRF's gate gives a
//! sample density only when all K of its neighbour slots are filled within the search radius, so
//! a sparse cloud of particles renders as nothing and gets no gradient, whatever it does to d′
//! (the spray of the test bed, BENCHMARKS.md "Issue 34"). This term sees every particle. With
//! s_i the root-mean-square distance from particle i to its K nearest others (K = the renderer's
//! gate count) and τ the largest s over the known first training state (where every particle is
//! fluid):
//!
//! L = (w / N) Σ_i max(0, s_i − τ)² / τ²
//!
//! The neighbours are held fixed (detached): a stray particle is pulled back towards its nearest
//! particles, the fluid is not pulled out to it. L is dimensionless, so the weight does not
//! depend on the scene's scale.

use burn::prelude::*;
use neurofluid_core::metrics::nearest_others;
use neurofluid_core::tensors::sum_all;

/// The prior's settings, fixed for a run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DensityPrior {
    /// Neighbours per particle (K).
    pub k: usize,
    /// τ: the largest spread of the first training state (world units).
    pub spread: f32,
    /// w.
    pub weight: f64,
}

/// The root-mean-square distance from each point to the neighbours `neighbours[i]` (world
/// units; 0 for a point without neighbours).
pub fn spreads(points: &[[f32; 3]], neighbours: &[Vec<usize>]) -> Vec<f32> {
    points
        .iter()
        .zip(neighbours)
        .map(|(p, nb)| {
            if nb.is_empty() {
                return 0.0;
            }
            let sum: f64 = nb
                .iter()
                .map(|&j| {
                    (0..3)
                        .map(|a| f64::from(points[j][a] - p[a]).powi(2))
                        .sum::<f64>()
                })
                .sum();
            (sum / nb.len() as f64).sqrt() as f32
        })
        .collect()
}

impl DensityPrior {
    /// The prior of weight `weight` over `k` neighbours, its τ taken from `initial` (the true
    /// first training state).
    pub fn new(initial: &[[f32; 3]], k: usize, weight: f64) -> anyhow::Result<Self> {
        anyhow::ensure!(
            initial.len() > k,
            "joint.density_weight needs more than {k} particles in the first training state, \
             found {}",
            initial.len()
        );
        let nb = nearest_others(initial, k)
            .ok_or_else(|| anyhow::anyhow!("the first training state has a non-finite particle"))?;
        let spread = spreads(initial, &nb).into_iter().fold(0.0f32, f32::max);
        anyhow::ensure!(
            spread > 0.0,
            "the first training state's particles coincide: no spread for joint.density_weight"
        );
        Ok(Self { k, spread, weight })
    }

    /// L at the positions `pos` (`[N, 3]`, differentiable through its graph; `points` its host
    /// copy), and how many particles are sparser than τ; `None` for the term when none is (or a
    /// position is not finite: the state check reports that).
    pub fn loss(&self, pos: &Tensor<2>, points: &[[f32; 3]]) -> (Option<Tensor<1>>, usize) {
        let Some(nb) = nearest_others(points, self.k) else {
            return (None, 0);
        };
        let sparse: Vec<usize> = spreads(points, &nb)
            .iter()
            .enumerate()
            .filter(|&(i, &s)| s > self.spread && nb[i].len() == self.k)
            .map(|(i, _)| i)
            .collect();
        if sparse.is_empty() {
            return (None, 0);
        }
        let device = pos.device();
        let m = sparse.len();
        let own = int_tensor(sparse.iter().copied(), &device);
        let others = int_tensor(sparse.iter().flat_map(|&i| nb[i].iter().copied()), &device);
        let x = pos.clone().select(0, own).unsqueeze_dim::<3>(1);
        let around = pos
            .clone()
            .detach()
            .select(0, others)
            .reshape([m, self.k, 3]);
        let spread = (x - around)
            .powi_scalar(2)
            .sum_dim(2)
            .mean_dim(1)
            .sqrt()
            .reshape([m]);
        let tau = f64::from(self.spread);
        let scale = self.weight / (points.len() as f64 * tau * tau);
        let excess = spread.sub_scalar(tau);
        (Some(sum_all(excess.powi_scalar(2)).mul_scalar(scale)), m)
    }
}

/// The particle indices `ids` on `device` (the priors' gathers).
pub(crate) fn int_tensor(ids: impl IntoIterator<Item = usize>, device: &Device) -> Tensor<1, Int> {
    let v: Vec<i64> = ids.into_iter().map(|i| i as i64).collect();
    let n = v.len();
    neurofluid_core::transfer::upload(TensorData::new(v, [n]), device)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stages::views::{points_tensor, scalar, tensor_points};

    /// A 6 × 6 × 6 lattice of spacing 0.05 (a block of fluid at rest).
    fn block() -> Vec<[f32; 3]> {
        let mut p = Vec::new();
        for i in 0..6 {
            for j in 0..6 {
                for k in 0..6 {
                    p.push([i as f32 * 0.05, j as f32 * 0.05, k as f32 * 0.05]);
                }
            }
        }
        p
    }

    /// L computed on the host from the definition, every particle's neighbours searched anew.
    fn host_loss(prior: &DensityPrior, points: &[[f32; 3]]) -> f64 {
        let nb = nearest_others(points, prior.k).unwrap();
        let tau = f64::from(prior.spread);
        spreads(points, &nb)
            .iter()
            .map(|&s| (f64::from(s) - tau).max(0.0).powi(2))
            .sum::<f64>()
            * prior.weight
            / (points.len() as f64 * tau * tau)
    }

    #[test]
    fn a_fluid_at_rest_costs_nothing() {
        let device = neurofluid_core::device::cpu().autodiff();
        let prior = DensityPrior::new(&block(), 20, 1.0).unwrap();
        // a corner of the block: its 20 nearest reach 2 spacings along the edges
        assert!(
            prior.spread > 0.05 && prior.spread < 0.15,
            "{}",
            prior.spread
        );
        let (term, sparse) = prior.loss(&points_tensor(&block(), &device), &block());
        assert!(term.is_none());
        assert_eq!(sparse, 0);
    }

    #[test]
    fn a_stray_particle_is_pulled_back_as_finite_differences_say() {
        let device = neurofluid_core::device::cpu().autodiff();
        let prior = DensityPrior::new(&block(), 20, 2.0).unwrap();
        let mut points = block();
        let stray = points.len();
        // off the lattice's symmetry planes, so that no two neighbours tie
        points.push([0.6, 0.137, 0.083]);
        let pos = points_tensor(&points, &device).require_grad();
        let (term, sparse) = prior.loss(&pos, &points);
        assert_eq!(sparse, 1);
        let term = term.unwrap();
        let value = scalar(&term);
        assert!((value - host_loss(&prior, &points)).abs() < 1e-6 * value.max(1e-3));
        let grads = term.backward();
        let g = tensor_points(&pos.grad(&grads).unwrap());
        // the block's particles are not pulled out (the neighbours are held fixed)
        assert!(g[..stray].iter().flatten().all(|&v| v == 0.0));
        // the stray particle's gradient: central differences of the host loss (only its own
        // spread moves: the block's stay below τ)
        let h = 1e-3f32;
        for a in 0..3 {
            let mut up = points.clone();
            up[stray][a] += h;
            let mut down = points.clone();
            down[stray][a] -= h;
            let fd = (host_loss(&prior, &up) - host_loss(&prior, &down)) / (2.0 * f64::from(h));
            let got = f64::from(g[stray][a]);
            // f32 positions and spreads: central differences good to about 0.5 %
            assert!(
                (got - fd).abs() < 1e-2 * fd.abs().max(1e-3),
                "axis {a}: {got} vs {fd}"
            );
        }
        // it points away from the block: descent brings the particle back
        assert!(g[stray][0] > 0.0);
    }

    #[test]
    fn descent_brings_the_stray_particle_into_the_fluid() {
        let device = neurofluid_core::device::cpu().autodiff();
        let prior = DensityPrior::new(&block(), 20, 1.0).unwrap();
        let mut points = block();
        points.push([0.9, 0.9, 0.9]);
        let stray = points.len() - 1;
        for _ in 0..200 {
            let pos = points_tensor(&points, &device).require_grad();
            let (Some(term), _) = prior.loss(&pos, &points) else {
                break;
            };
            let g = tensor_points(&pos.grad(&term.backward()).unwrap());
            // a step of 0.02 m along the descent direction
            let norm = g[stray].iter().map(|v| v * v).sum::<f32>().sqrt();
            for a in 0..3 {
                points[stray][a] -= 0.02 * g[stray][a] / norm;
            }
        }
        let (term, sparse) = prior.loss(&points_tensor(&points, &device), &points);
        assert!(term.is_none() && sparse == 0, "{:?}", points[stray]);
        assert!(
            points[stray].iter().all(|&v| v < 0.45),
            "{:?}",
            points[stray]
        );
    }

    #[test]
    fn too_few_particles_are_refused() {
        let err = DensityPrior::new(&block()[..10], 20, 1.0).unwrap_err();
        assert!(err.to_string().contains("joint.density_weight"), "{err}");
    }
}
