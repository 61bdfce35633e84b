//! The bodies of a fluid: the connected groups of its particles, two particles joined where they
//! are neighbours of a step (within DLF's search radius). A falling clump is one body, a droplet
//! thrown off it another. The dissipation in the body frame
//! (`dlf.dissipation_frame = "body"`, [`crate::rules::DissipationFrame`]) takes its share of each
//! velocity relative to the mean velocity of the particle's body: a body's motion as a whole (a
//! fall, a throw) is kept, its momentum too, and only the motion within it (spreading, spin,
//! splashing) is damped; it is the same in every frame that moves uniformly (Galilean invariant),
//! where the dissipation in the box frame is a drag on every velocity.

use burn::prelude::*;
use neurofluid_core::rows::{RowIndex, add_rows, gather_rows};
use neurofluid_core::transfer::upload;

use crate::geometry::HostGeometry;

/// The body of every particle of a fluid→fluid geometry `g` over the same points: labels
/// `0..bodies`, numbered in the order of each body's first particle.
pub fn body_labels(g: &HostGeometry) -> Vec<u32> {
    let n = g.num_out;
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn root(parent: &mut [u32], mut i: u32) -> u32 {
        while parent[i as usize] != i {
            let up = parent[parent[i as usize] as usize];
            parent[i as usize] = up;
            i = up;
        }
        i
    }
    for (&q, &j) in g.query_of_pair.iter().zip(&g.pairs.indices) {
        let (a, b) = (root(&mut parent, q), root(&mut parent, j));
        if a != b {
            parent[a.max(b) as usize] = a.min(b);
        }
    }
    let mut label = vec![u32::MAX; n];
    let mut labels = Vec::with_capacity(n);
    let mut next = 0;
    for i in 0..n as u32 {
        let r = root(&mut parent, i) as usize;
        if label[r] == u32::MAX {
            label[r] = next;
            next += 1;
        }
        labels.push(label[r]);
    }
    labels
}

/// For every particle, the mean of `vel` `[N, 3]` over its body (`labels` from
/// [`body_labels`]); gradients flow through the velocities.
pub fn body_mean_velocities(vel: Tensor<2>, labels: &[u32]) -> Tensor<2> {
    let device = vel.device();
    let bodies = labels.iter().max().map_or(0, |&m| m as usize + 1);
    let mut sizes = vec![0.0f32; bodies];
    for &b in labels {
        sizes[b as usize] += 1.0;
    }
    let index = RowIndex::new(labels.iter().map(|&b| b as usize), &device);
    let sums = add_rows(Tensor::zeros([bodies, 3], &device), &index, vel);
    let sizes: Tensor<2> = upload(TensorData::new(sizes, [bodies, 1]), &device);
    gather_rows(sums / sizes, &index)
}

/// Each velocity of `vel` relative to its body's mean, `v − v̄_body`: the motion within the
/// bodies, which the dissipation in the body frame takes its share of (`v − c (v − v̄_body)`).
pub fn motion_within_bodies(vel: Tensor<2>, labels: &[u32]) -> Tensor<2> {
    vel.clone() - body_mean_velocities(vel, labels)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::build_host_geometry;
    use neurofluid_core::tensors::{points_tensor, tensor_points};

    const RADIUS: f32 = 0.1125;

    /// Two blocks of particles 0.05 apart, 1 m from each other, and a lone particle.
    fn two_clumps_and_a_drop() -> Vec<[f32; 3]> {
        let mut x = Vec::new();
        for offset in [0.0f32, 1.0] {
            for i in 0..4 {
                for j in 0..3 {
                    x.push([offset + i as f32 * 0.05, j as f32 * 0.05, 0.0]);
                }
            }
        }
        x.push([0.5, 0.5, 0.5]);
        x
    }

    fn labels(x: &[[f32; 3]]) -> Vec<u32> {
        body_labels(&build_host_geometry(x, x, 2.0 * RADIUS, true, None))
    }

    /// Bodies by brute force: flood fill over every pair closer than the search radius.
    fn brute_force_labels(x: &[[f32; 3]]) -> Vec<u32> {
        let n = x.len();
        let mut label = vec![u32::MAX; n];
        let mut next = 0;
        for s in 0..n {
            if label[s] != u32::MAX {
                continue;
            }
            let mut stack = vec![s];
            label[s] = next;
            while let Some(i) = stack.pop() {
                for j in 0..n {
                    let d2: f32 = (0..3).map(|k| (x[i][k] - x[j][k]).powi(2)).sum();
                    if label[j] == u32::MAX && d2 < RADIUS * RADIUS {
                        label[j] = next;
                        stack.push(j);
                    }
                }
            }
            next += 1;
        }
        label
    }

    #[test]
    fn bodies_are_the_connected_groups() {
        let x = two_clumps_and_a_drop();
        let l = labels(&x);
        assert_eq!(l, brute_force_labels(&x));
        assert_eq!(*l.iter().max().unwrap(), 2, "two clumps and a drop");
    }

    #[test]
    fn damping_keeps_each_bodys_motion_and_momentum_and_is_galilean_invariant() {
        let device = neurofluid_core::device::cpu();
        let x = two_clumps_and_a_drop();
        let l = labels(&x);
        let v: Vec<[f32; 3]> = x
            .iter()
            .map(|p| [p[1] * 3.0 - 0.2, (p[0] * 7.0).sin(), p[0] + 0.3])
            .collect();
        let share = 0.3f32;
        // the step's damping: v − c (v − v̄_body)
        let damp = |v: &[[f32; 3]]| {
            let v = points_tensor(v, &device);
            tensor_points(&(v.clone() - motion_within_bodies(v, &l) * share))
        };
        let out = damp(&v);
        // by hand, per body in f64
        for b in 0..3u32 {
            let members: Vec<usize> = (0..x.len()).filter(|&i| l[i] == b).collect();
            let mean = |w: &[[f32; 3]], k: usize| {
                members.iter().map(|&i| w[i][k] as f64).sum::<f64>() / members.len() as f64
            };
            for k in 0..3 {
                let (m_in, m_out) = (mean(&v, k), mean(&out, k));
                assert!((m_in - m_out).abs() < 1e-5, "body {b}'s momentum kept");
                for &i in &members {
                    let want = v[i][k] as f64 - share as f64 * (v[i][k] as f64 - m_in);
                    assert!((out[i][k] as f64 - want).abs() < 1e-5);
                }
            }
        }
        // the lone particle is its own body: nothing within it to damp
        assert_eq!(out[x.len() - 1], v[x.len() - 1]);
        // a uniform motion added to every velocity comes out added
        let u = [0.7f32, -2.0, 0.4];
        let moved: Vec<[f32; 3]> = v
            .iter()
            .map(|w| [w[0] + u[0], w[1] + u[1], w[2] + u[2]])
            .collect();
        for (a, b) in damp(&moved).iter().zip(&out) {
            for k in 0..3 {
                assert!((a[k] - b[k] - u[k]).abs() < 1e-5);
            }
        }
        // a rigid translation is left as it is
        let rigid = vec![u; x.len()];
        for w in damp(&rigid) {
            for k in 0..3 {
                assert!((w[k] - u[k]).abs() < 1e-6);
            }
        }
    }
}
