//! DLF's supervised loss (docs/spec/dlf.md §5).

use burn::prelude::*;

/// Exponent γ of the distance in DLF's loss.
pub const LOSS_GAMMA: f32 = 0.5;
/// Neighbour-count scale of the per-particle weight exp(−n/40).
pub const NEIGHBOR_SCALE: f32 = 40.0;
/// Factor on the summed sample losses (DLF multiplies by 128).
pub const LOSS_SCALE: f32 = 128.0;

/// Per-step loss `mean_i exp(−n_i/40) · (sqrt(‖p_i − g_i‖² + 1e-9))^γ` with γ = 0.5.
///
/// `num_fluid_neighbors` are the fluid neighbour counts of that step (at its x*).
pub fn dlf_step_loss(pred: Tensor<2>, target: Tensor<2>, num_fluid_neighbors: &[u32]) -> Tensor<1> {
    let device = pred.device();
    let n = num_fluid_neighbors.len();
    let importance: Vec<f32> = num_fluid_neighbors
        .iter()
        .map(|&c| (-(c as f32) / NEIGHBOR_SCALE).exp())
        .collect();
    let importance = neurofluid_core::transfer::upload::<1, burn::tensor::Float, _>(
        TensorData::new(importance, [n]),
        &device,
    )
    .cast(pred.dtype());
    let diff = pred - target;
    let dist = ((diff.clone() * diff).sum_dim(1).squeeze_dim::<1>(1) + 1e-9).sqrt();
    neurofluid_core::tensors::mean_all(importance * dist.powf_scalar(LOSS_GAMMA))
}

/// DLF's two-step sample loss `128 · (0.5·L1 + 0.5·L2)`.
pub fn two_step_loss(l1: Tensor<1>, l2: Tensor<1>) -> Tensor<1> {
    (l1 * 0.5 + l2 * 0.5) * LOSS_SCALE
}
