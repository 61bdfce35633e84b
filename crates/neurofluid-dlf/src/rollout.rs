//! Inference rollouts of the DLF model and the statistics the reference harness reports.

use crate::net::{Boundary, DlfNet, points_tensor, tensor_points};

/// A rollout: the state after every step.
#[derive(Debug, Clone, Default)]
pub struct Rollout {
    /// Positions, one entry per state (index 0 = the input).
    pub pos: Vec<Vec<[f32; 3]>>,
    /// Velocities, one entry per state.
    pub vel: Vec<Vec<[f32; 3]>>,
}

/// Runs `steps` network steps from (`pos`, `vel`), calling `on_step(step)` after each.
///
/// Uses the network's device; gradients are not tracked (the network should be a
/// non-autodiff module, e.g. `net.valid()`).
pub fn rollout(
    net: &DlfNet,
    pos: &[[f32; 3]],
    vel: &[[f32; 3]],
    boundary: &Boundary,
    steps: usize,
    mut on_step: impl FnMut(usize),
) -> Rollout {
    let device = net.device();
    let mut out = Rollout {
        pos: vec![pos.to_vec()],
        vel: vec![vel.to_vec()],
    };
    let mut p = points_tensor(pos, &device);
    let mut v = points_tensor(vel, &device);
    for step in 1..=steps {
        let o = net.step(p, v, boundary);
        out.pos.push(tensor_points(&o.pos));
        out.vel.push(tensor_points(&o.vel));
        p = o.pos;
        v = o.vel;
        on_step(step);
    }
    out
}

/// Mean of coordinate `axis` over the points (the "mean height" with the up axis).
pub fn mean_coordinate(points: &[[f32; 3]], axis: usize) -> f32 {
    if points.is_empty() {
        return f32::NAN;
    }
    (points.iter().map(|p| p[axis] as f64).sum::<f64>() / points.len() as f64) as f32
}

/// Number of points with any coordinate outside the box [lo, hi].
pub fn count_outside(points: &[[f32; 3]], lo: [f32; 3], hi: [f32; 3]) -> usize {
    points
        .iter()
        .filter(|p| (0..3).any(|k| p[k] < lo[k] || p[k] > hi[k]))
        .count()
}
