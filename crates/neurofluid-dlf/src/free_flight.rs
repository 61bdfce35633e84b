//! Clusters in free flight move as projectiles (`DlfConfig::ballistic_free_flight`).
//!
//! Within one DLF step a particle's correction depends only on the particles its convs reach:
//! its fluid neighbours (and theirs, layer by layer) and the box particles within reach. A
//! cluster, a connected component of the fluid's neighbour graph at the conv's radius, none of
//! whose particles has a box particle within reach, is a closed system for that step: its
//! particles exert forces only on one another, which cancel in sum (Newton's third law), so its
//! centre of mass must move as a projectile under gravity. The published weights break this: a
//! falling clump accelerates at about 6.3 m/s² of 9.81 (`tests/free_fall.rs`), and grounding
//! from images can slow a fall further (a honey's pile held up over the truth).
//!
//! The rule moves each free cluster's centre of mass as a projectile from the state's velocity,
//! read as the instantaneous velocity (the data's, and the one DLF's pre-step assumes: x* = x +
//! dt·v + ½·dt²·g), and leaves the particles' motion relative to it as the network made it: the
//! cluster's mean correction becomes `½·(1 − s)·g·dt²` for the pre-step's gravity scale s, so the
//! centre moves by `dt·v + ½·g·dt²`, and its particles' new velocities gain `½·g·dt` over the
//! step's mean velocity (x_{t+1} − x_t)/dt, which is the projectile's velocity at the step's end
//! (DLF's own rule, the mean velocity, lags it by `½·g·dt` and would let a free clump fall at
//! g/2). Clusters within the walls' reach are left as the network made them. The clusters are
//! constants of the step; gradients flow through the corrections (the rule is linear in them).

use burn::prelude::*;
use neurofluid_core::neighbors::PairList;
use neurofluid_core::rows::{RowIndex, add_rows, gather_rows};
use neurofluid_core::transfer::upload;

use crate::config::DlfConfig;

/// The clusters in free flight of one step.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FreeClusters {
    /// Per particle, its free cluster (`0..sizes.len()`), or `None` where its cluster is within
    /// the walls' reach.
    pub of_particle: Vec<Option<u32>>,
    /// Particles per free cluster.
    pub sizes: Vec<u32>,
}

/// The root of `i` in a union-find forest, halving paths on the way.
fn root(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        let up = parent[parent[i as usize] as usize];
        parent[i as usize] = up;
        i = up;
    }
    i
}

/// The free clusters of `n` fluid particles: `fluid` their neighbour pairs (rows are particles,
/// indices particles), `touching[i]` whether particle i has a box particle within reach. Cluster
/// ids follow the order of each cluster's lowest particle.
pub fn free_clusters(fluid: &PairList, touching: &[bool]) -> FreeClusters {
    let n = touching.len();
    assert_eq!(
        fluid.num_queries(),
        n,
        "one row of pairs per fluid particle"
    );
    let mut parent: Vec<u32> = (0..n as u32).collect();
    for q in 0..n {
        for &j in &fluid.indices[fluid.offsets[q]..fluid.offsets[q + 1]] {
            let (a, b) = (root(&mut parent, q as u32), root(&mut parent, j));
            if a != b {
                parent[a.max(b) as usize] = a.min(b);
            }
        }
    }
    let roots: Vec<u32> = (0..n as u32).map(|i| root(&mut parent, i)).collect();
    let mut held = vec![false; n];
    for (i, &r) in roots.iter().enumerate() {
        held[r as usize] |= touching[i];
    }
    let mut id_of_root = vec![None; n];
    let mut sizes = Vec::new();
    let of_particle = roots
        .iter()
        .map(|&r| {
            if held[r as usize] {
                return None;
            }
            let id = *id_of_root[r as usize].get_or_insert_with(|| {
                sizes.push(0);
                (sizes.len() - 1) as u32
            });
            sizes[id as usize] += 1;
            Some(id)
        })
        .collect();
    FreeClusters { of_particle, sizes }
}

/// The rule on one step under `cfg` (model frame): `correction [N, 3]` (metres) with each free
/// cluster's mean the projectile's, and the closure that turns the step's mean velocities
/// `[N, 3]` into the new state's (the projectile's velocity at the step's end for the free
/// clusters' particles).
pub fn projectile_step(
    correction: Tensor<2>,
    clusters: &FreeClusters,
    cfg: DlfConfig,
) -> (Tensor<2>, impl FnOnce(Tensor<2>) -> Tensor<2> + '_) {
    let g = cfg.model_gravity();
    let (dt, s) = (cfg.dt, cfg.gravity_scale);
    let mean = g.map(|g| 0.5 * (1.0 - s) * g * dt * dt);
    let lift = g.map(|g| 0.5 * g * dt);
    let correction = ballistic(correction, clusters, mean);
    let velocity = move |v: Tensor<2>| lift_rows(v, clusters, lift);
    (correction, velocity)
}

/// `v [N, 3]` with `lift` added to the rows of every free cluster's particles.
fn lift_rows(v: Tensor<2>, clusters: &FreeClusters, lift: [f32; 3]) -> Tensor<2> {
    if clusters.sizes.is_empty() {
        return v;
    }
    let n = clusters.of_particle.len();
    let member: Vec<f32> = clusters
        .of_particle
        .iter()
        .map(|k| if k.is_some() { 1.0 } else { 0.0 })
        .collect();
    let (device, dtype) = (v.device(), v.dtype());
    let member: Tensor<2> = upload(TensorData::new(member, [n, 1]), (&device, dtype));
    let lift: Tensor<2> = upload(TensorData::new(lift.to_vec(), [1, 3]), (&device, dtype));
    v + member * lift
}

/// `correction [N, 3]` with each free cluster's mean replaced by `mean` (model frame, metres);
/// the rows of particles in no free cluster as they are.
pub fn ballistic(correction: Tensor<2>, clusters: &FreeClusters, mean: [f32; 3]) -> Tensor<2> {
    let c = clusters.sizes.len();
    if c == 0 {
        return correction;
    }
    let (device, dtype) = (correction.device(), correction.dtype());
    // each particle's free cluster; the particles of none share one row more, left out
    let of_row = RowIndex::new(
        clusters
            .of_particle
            .iter()
            .map(|k| k.map_or(c, |k| k as usize)),
        &device,
    );
    let sums = add_rows(
        Tensor::zeros([c + 1, 3], (&device, dtype)),
        &of_row,
        correction.clone(),
    )
    .slice([0..c, 0..3]);
    let sizes: Vec<f32> = clusters.sizes.iter().map(|&s| s as f32).collect();
    let sizes: Tensor<2> = upload(TensorData::new(sizes, [c, 1]), (&device, dtype));
    let target: Tensor<2> = upload(TensorData::new(mean.to_vec(), [1, 3]), (&device, dtype));
    // per cluster, what its rows gain; a zero row for the particles of no free cluster
    let shift = Tensor::cat(
        vec![
            target.expand([c, 3]) - sums / sizes,
            Tensor::zeros([1, 3], (&device, dtype)),
        ],
        0,
    );
    correction + gather_rows(shift, &of_row)
}

#[cfg(test)]
mod tests {
    use super::*;
    use neurofluid_core::neighbors::NeighborGrid;
    use rand::{Rng, SeedableRng};

    /// Components by breadth-first search over every pair of points within `r` (O(N²)).
    fn brute_components(p: &[[f32; 3]], r: f32) -> Vec<usize> {
        let n = p.len();
        let near = |a: usize, b: usize| {
            let d: f32 = (0..3).map(|k| (p[a][k] - p[b][k]).powi(2)).sum();
            a != b && d <= r * r
        };
        let mut comp = vec![usize::MAX; n];
        let mut next = 0;
        for s in 0..n {
            if comp[s] != usize::MAX {
                continue;
            }
            comp[s] = next;
            let mut queue = vec![s];
            while let Some(a) = queue.pop() {
                for (b, c) in comp.iter_mut().enumerate() {
                    if *c == usize::MAX && near(a, b) {
                        *c = next;
                        queue.push(b);
                    }
                }
            }
            next += 1;
        }
        comp
    }

    #[test]
    fn free_clusters_are_the_components_out_of_the_walls_reach() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        // sparse points: many small components, lone particles among them
        let p: Vec<[f32; 3]> = (0..600)
            .map(|_| [rng.random::<f32>(), rng.random(), rng.random()])
            .collect();
        let r = 0.07;
        let pairs = NeighborGrid::new(&p, r).pairs(&p, r, true);
        // "walls": particles with x < 0.1 touch
        let touching: Vec<bool> = p.iter().map(|q| q[0] < 0.1).collect();
        let found = free_clusters(&pairs, &touching);
        let comp = brute_components(&p, r);
        let held: Vec<bool> = (0..p.len())
            .map(|i| (0..p.len()).any(|j| comp[j] == comp[i] && touching[j]))
            .collect();
        let mut sizes = std::collections::HashMap::new();
        for i in 0..p.len() {
            assert_eq!(found.of_particle[i].is_none(), held[i], "particle {i}");
            for j in 0..p.len() {
                if !held[i] && !held[j] {
                    assert_eq!(
                        found.of_particle[i] == found.of_particle[j],
                        comp[i] == comp[j],
                        "particles {i}, {j}"
                    );
                }
            }
            if let Some(k) = found.of_particle[i] {
                *sizes.entry(k).or_insert(0u32) += 1;
            }
        }
        assert!(found.sizes.len() > 20, "a case with many free clusters");
        assert!(found.of_particle.iter().any(|k| k.is_none()));
        for (k, &s) in found.sizes.iter().enumerate() {
            assert_eq!(sizes[&(k as u32)], s, "cluster {k}'s size");
        }
    }

    #[test]
    fn ballistic_sets_each_free_cluster_mean_and_keeps_the_rest() {
        let device = Device::flex().autodiff();
        let clusters = FreeClusters {
            of_particle: vec![Some(0), None, Some(1), Some(0), Some(0), None],
            sizes: vec![3, 1],
        };
        let values: Vec<f32> = (0..18).map(|i| (i as f32 * 0.37).sin()).collect();
        let c: Tensor<2> =
            upload::<2, burn::tensor::Float, _>(TensorData::new(values.clone(), [6, 3]), &device)
                .require_grad();
        let mean = [0.1, -0.2, 0.3];
        let out = ballistic(c.clone(), &clusters, mean);
        let got: Vec<f32> = out.clone().into_data().try_to_vec::<f32>().unwrap();
        let row = |v: &[f32], i: usize| [v[3 * i], v[3 * i + 1], v[3 * i + 2]];
        for k in 0..3 {
            let m: f32 = [0, 3, 4].iter().map(|&i| got[3 * i + k]).sum::<f32>() / 3.0;
            assert!((m - mean[k]).abs() < 1e-6, "cluster 0's mean, axis {k}");
            assert!((got[3 * 2 + k] - mean[k]).abs() < 1e-6, "a lone particle");
            // differences within the cluster kept
            let d = row(&got, 0)[k] - row(&got, 3)[k];
            assert!((d - (row(&values, 0)[k] - row(&values, 3)[k])).abs() < 1e-6);
        }
        for i in [1, 5] {
            assert_eq!(row(&got, i), row(&values, i), "row {i} held by the walls");
        }
        // the gradient of Σ w·out: w minus its cluster mean for members, w for the rest
        let w: Vec<f32> = (0..18).map(|i| (i as f32 * 0.91).cos()).collect();
        let wt: Tensor<2> =
            upload::<2, burn::tensor::Float, _>(TensorData::new(w.clone(), [6, 3]), &device);
        let grads = (out * wt).sum().backward();
        let g: Vec<f32> = c
            .grad(&grads)
            .unwrap()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        for k in 0..3 {
            let wm: f32 = [0, 3, 4].iter().map(|&i| w[3 * i + k]).sum::<f32>() / 3.0;
            for i in [0, 3, 4] {
                assert!((g[3 * i + k] - (w[3 * i + k] - wm)).abs() < 1e-6);
            }
            assert!(g[3 * 2 + k].abs() < 1e-6, "a lone particle's mean is fixed");
            for i in [1, 5] {
                assert_eq!(g[3 * i + k], w[3 * i + k]);
            }
        }
    }
}
