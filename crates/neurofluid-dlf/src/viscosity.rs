//! XSPH viscosity (Monaghan's velocity smoothing): after DLF's step, each particle's velocity
//! moves part of the way toward its neighbours', `v_i' = v_i + Σ_j a_ij (v_j − v_i)`. DLF's
//! published weights learned water; a viscous fluid (honey) keeps neighbouring particles moving
//! together, which this adds as a rule of the rollout (`StepRules::viscosity`).
//!
//! The pair coefficients are `a_ij = s · w_ij / max(S_i, S_j)`, with `w = (1 − r²/R²)³` (the
//! window of DLF's conv over the pairs it already found, self excluded), `S_i` the sum of
//! particle i's weights and `s` the strength in [0, 1]. The pairs are symmetric, so the step
//! keeps the momentum; each row sums to at most `s`, so every new velocity is a convex
//! combination of the old ones, and the kinetic energy cannot grow in sum; a uniform motion is
//! left as it is. (No-slip walls, the box's particles among the neighbours at rest, were screened
//! and retired: docs/notebook/benchmarks-history.md, "Issue 34: viscosity for honey".) The weights are constants of the step (positions get no gradient
//! from them); gradients flow through the velocities.

use burn::prelude::*;
use neurofluid_core::rows::{RowIndex, add_rows, gather_rows};
use neurofluid_core::transfer::upload;

use crate::geometry::HostGeometry;
use crate::mapping::window_poly6;

/// The window weight of every pair of `g` for the search radius `radius`.
fn pair_weights(g: &HostGeometry, radius: f32) -> Vec<f32> {
    let r2 = radius * radius;
    g.pairs
        .dist2
        .iter()
        .map(|&d2| window_poly6(d2 / r2))
        .collect()
}

/// The sum of the weights of each query's pairs.
fn row_sums(g: &HostGeometry, w: &[f32]) -> Vec<f32> {
    g.pairs
        .offsets
        .windows(2)
        .map(|o| w[o[0]..o[1]].iter().sum())
        .collect()
}

/// The coefficients `a_ij` of one step for every pair of `fluid` (query-major, as the geometry
/// holds them).
pub fn coefficients(fluid: &HostGeometry, radius: f32, strength: f32) -> Vec<f32> {
    let w = pair_weights(fluid, radius);
    let sums = row_sums(fluid, &w);
    w.iter()
        .zip(&fluid.query_of_pair)
        .zip(&fluid.pairs.indices)
        .map(|((&w, &q), &j)| {
            let norm = sums[q as usize].max(sums[j as usize]);
            if norm > 0.0 { strength * w / norm } else { 0.0 }
        })
        .collect()
}

/// `vel` `[N, 3]` smoothed over the pairs of `fluid` (a fluid→fluid geometry over the same N
/// points, symmetric, self excluded) with strength `strength` ([module docs](self)).
pub fn smooth_velocities(
    vel: Tensor<2>,
    fluid: &HostGeometry,
    radius: f32,
    strength: f32,
) -> Tensor<2> {
    let device = vel.device();
    if strength == 0.0 {
        return vel;
    }
    let a = coefficients(fluid, radius, strength);
    let n = vel.dims()[0];
    let queries = &fluid.query_of_pair;
    let mut pulled_away = vec![0.0f32; n];
    for (&q, &a) in queries.iter().zip(&a) {
        pulled_away[q as usize] += a;
    }
    let pulled_away: Tensor<2> = upload(TensorData::new(pulled_away, [n, 1]), &device);
    let kept = vel.clone() - vel.clone() * pulled_away;
    let p = fluid.num_pairs();
    if p == 0 {
        return kept;
    }
    let a: Tensor<2> = upload(TensorData::new(a, [p, 1]), &device);
    let inputs = RowIndex::new(fluid.pairs.indices.iter().map(|&j| j as usize), &device);
    let outputs = RowIndex::new(queries.iter().map(|&q| q as usize), &device);
    let pulled = gather_rows(vel, &inputs) * a;
    add_rows(kept, &outputs, pulled)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::build_host_geometry;
    use neurofluid_core::tensors::{points_tensor, tensor_points};

    const RADIUS: f32 = 0.1125;

    /// A jittered block of particles 0.05 apart, and velocities that vary over it.
    fn cloud() -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
        let mut x = Vec::new();
        let mut v = Vec::new();
        let mut k = 0u32;
        for i in 0..6 {
            for j in 0..5 {
                for l in 0..4 {
                    k = k.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                    let jitter = (k >> 8) as f32 / (1u32 << 24) as f32 * 0.01;
                    let p = [
                        i as f32 * 0.05 + jitter,
                        j as f32 * 0.05,
                        l as f32 * 0.05 - jitter,
                    ];
                    x.push(p);
                    v.push([p[1] * 3.0 - 0.2, (p[0] * 7.0).sin(), jitter * 50.0]);
                }
            }
        }
        (x, v)
    }

    /// The geometry of a conv over `inputs` at `outputs` with search radius [`RADIUS`].
    fn geometry(inputs: &[[f32; 3]], outputs: &[[f32; 3]]) -> HostGeometry {
        build_host_geometry(inputs, outputs, 2.0 * RADIUS, true, None)
    }

    fn pairs(x: &[[f32; 3]]) -> HostGeometry {
        geometry(x, x)
    }

    fn smooth(x: &[[f32; 3]], v: &[[f32; 3]], s: f32) -> Vec<[f32; 3]> {
        let device = neurofluid_core::device::cpu();
        tensor_points(&smooth_velocities(
            points_tensor(v, &device),
            &pairs(x),
            RADIUS,
            s,
        ))
    }

    /// The formula over every pair of points, by brute force in f64.
    fn brute_force(x: &[[f32; 3]], v: &[[f32; 3]], s: f64) -> Vec<[f64; 3]> {
        let n = x.len();
        let r2 = f64::from(RADIUS).powi(2);
        let w = |i: usize, j: usize| {
            let d2: f64 = (0..3).map(|c| f64::from(x[i][c] - x[j][c]).powi(2)).sum();
            if i == j || d2 > r2 {
                0.0
            } else {
                (1.0 - d2 / r2).powi(3)
            }
        };
        let sums: Vec<f64> = (0..n).map(|i| (0..n).map(|j| w(i, j)).sum()).collect();
        (0..n)
            .map(|i| {
                std::array::from_fn(|c| {
                    let pull: f64 = (0..n)
                        .map(|j| {
                            let a = s * w(i, j) / sums[i].max(sums[j]).max(f64::MIN_POSITIVE);
                            a * f64::from(v[j][c] - v[i][c])
                        })
                        .sum();
                    f64::from(v[i][c]) + pull
                })
            })
            .collect()
    }

    #[test]
    fn matches_the_formula_over_all_pairs() {
        let (x, v) = cloud();
        let got = smooth(&x, &v, 0.6);
        let want = brute_force(&x, &v, 0.6);
        for (g, w) in got.iter().zip(&want) {
            for c in 0..3 {
                assert!((f64::from(g[c]) - w[c]).abs() < 1e-5, "{g:?} vs {w:?}");
            }
        }
    }

    #[test]
    fn keeps_momentum_and_a_uniform_motion_and_loses_kinetic_energy() {
        let (x, v) = cloud();
        let sum = |v: &[[f32; 3]], c: usize| v.iter().map(|p| f64::from(p[c])).sum::<f64>();
        let energy = |v: &[[f32; 3]]| {
            v.iter()
                .map(|p| p.iter().map(|&c| f64::from(c).powi(2)).sum::<f64>())
                .sum::<f64>()
        };
        for s in [0.3, 1.0] {
            let out = smooth(&x, &v, s);
            for c in 0..3 {
                assert!(
                    (sum(&out, c) - sum(&v, c)).abs() < 1e-4,
                    "momentum, axis {c}"
                );
            }
            assert!(
                energy(&out) < energy(&v),
                "kinetic energy grew at strength {s}"
            );
        }
        let uniform = vec![[0.4, -1.3, 0.2]; x.len()];
        for (o, u) in smooth(&x, &uniform, 1.0).iter().zip(&uniform) {
            for c in 0..3 {
                assert!((o[c] - u[c]).abs() < 1e-6);
            }
        }
        assert_eq!(smooth(&x, &v, 0.0), v, "strength 0 is the identity");
    }

    #[test]
    fn each_row_pulls_at_most_the_strength() {
        let (x, _) = cloud();
        let list = pairs(&x);
        let a = coefficients(&list, RADIUS, 0.8);
        for o in list.pairs.offsets.windows(2) {
            let row: f32 = a[o[0]..o[1]].iter().sum();
            assert!(row <= 0.8 + 1e-6, "{row}");
        }
    }
}
