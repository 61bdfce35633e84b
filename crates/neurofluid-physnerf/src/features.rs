//! Per-sample particle features (spec §2.4) as differentiable tensor ops.
//!
//! The gradient path is: particle positions `[N, 3]` → `select(idx)` (indices are constants)
//! → w_i, p_c, σ_p, v_d, d_c → encodings → MLP. Empty slots gather an extra row of zeros, a
//! fake particle at the world origin (pytorch3d pads with (0,0,0), spec §8.3): it enters w,
//! p_c and σ_p exactly as in the reference; only the occupancy gate hides it.

use burn::prelude::*;
use burn::tensor::TensorData;

use neurofluid_core::rows::{RowIndex, gather_rows};

use crate::real::Real;

/// Added to Σw in p_c and to n in the mean and variance of v_d.
pub const W_EPS: f64 = 1e-12;

/// Features of Q samples with K neighbour slots each.
#[derive(Debug, Clone)]
pub struct LocalFeatures {
    /// `[Q, K]` kernel weights `w_i = max(0, 1 − (|p_i − x|/r)³)` over all slots.
    pub w: Tensor<2>,
    /// `[Q, 3]` fictitious centre `p_c = Σ w_i p_i / (Σ w_i + 1e-12)`.
    pub pc: Tensor<2>,
    /// `[Q, 1]` density `σ_p = Σ w_i`.
    pub sigma_p: Tensor<2>,
    /// `[Q, 3]` per-axis variance of the valid offsets `l_i = p_i − x`.
    pub vd: Tensor<2>,
    /// `[Q, 3]` unit direction from the camera centre to p_c (norm floored at 1e-12).
    pub dc: Tensor<2>,
}

/// Builds a `[rows, cols]` float tensor of dtype T from host values.
pub fn host_tensor<T: Real>(values: Vec<T>, shape: [usize; 2], device: &Device) -> Tensor<2> {
    neurofluid_core::transfer::upload(TensorData::new(values, shape), (device, T::DTYPE))
}

/// Flattens `[[T; 3]]` rows into a `[n, 3]` tensor.
pub fn rows_tensor<T: Real>(rows: &[[T; 3]], device: &Device) -> Tensor<2> {
    let flat: Vec<T> = rows.iter().flatten().copied().collect();
    host_tensor(flat, [rows.len(), 3], device)
}

/// Gathers the neighbour coordinates `[Q, K, 3]` from `particles [N, 3]`; index −1 reads a
/// row of zeros appended after the last particle.
pub fn gather_neighbors(particles: &Tensor<2>, idx: &[i32], k: usize) -> Tensor<3> {
    let [n, _] = particles.dims();
    let device = particles.device();
    let zero_row = Tensor::<2>::zeros([1, 3], (&device, particles.dtype()));
    let padded = Tensor::cat(vec![particles.clone(), zero_row], 0);
    let ids = RowIndex::new(
        idx.iter().map(|&i| if i < 0 { n } else { i as usize }),
        &device,
    );
    gather_rows(padded, &ids).reshape([idx.len() / k, k, 3])
}

/// Computes the features of samples `x [Q, 3]` from their gathered neighbours.
///
/// `valid [Q, K]` is 1 where the slot's squared distance is ≠ 0 (a constant), `origin [Q, 3]`
/// the camera centre of each sample's ray, `radius` the ball-query radius r_s.
pub fn local_features(
    x: Tensor<2>,
    nbr: Tensor<3>,
    valid: Tensor<2>,
    origin: Tensor<2>,
    radius: f64,
) -> LocalFeatures {
    let [q, k, _] = nbr.dims();
    let offs = nbr.clone() - x.reshape([q, 1, 3]); // l_i = p_i − x
    let dist = (offs.clone() * offs.clone())
        .sum_dim(2)
        .sqrt()
        .reshape([q, k]);
    // divide by a tensor, not `div_scalar`: Burn 0.22's autodiff rounds the scalar of
    // `div_scalar` to f32 in the backward pass (a 2.6e-8 relative error of 1/0.225 in F64 runs)
    let r = dist.full_like(radius);
    let w = (dist / r)
        .powi_scalar(3)
        .neg()
        .add_scalar(1.0)
        .clamp_min(0.0);
    let wsum = w.clone().sum_dim(1); // [Q, 1]
    let pc = (w.clone().reshape([q, k, 1]) * nbr)
        .sum_dim(1)
        .reshape([q, 3])
        / wsum.clone().add_scalar(W_EPS);
    let valid3 = valid.clone().reshape([q, k, 1]);
    let n = valid.sum_dim(1).add_scalar(W_EPS); // [Q, 1]
    let lbar = (valid3.clone() * offs.clone()).sum_dim(1).reshape([q, 3]) / n.clone();
    let dev = offs - lbar.reshape([q, 1, 3]);
    let vd = (valid3 * dev.clone() * dev).sum_dim(1).reshape([q, 3]) / n;
    let v = pc.clone() - origin;
    let norm = (v.clone() * v.clone()).sum_dim(1).sqrt().clamp_min(1e-12);
    let dc = v / norm;
    LocalFeatures {
        w,
        pc,
        sigma_p: wsum,
        vd,
        dc,
    }
}

/// The constant `[Q, K]` validity tensor (`dist2 ≠ 0`) of a ball-query result.
pub fn valid_tensor<T: Real>(dist2: &[T], k: usize, device: &Device) -> Tensor<2> {
    let v: Vec<T> = dist2
        .iter()
        .map(|&d| if d != T::zero() { T::one() } else { T::zero() })
        .collect();
    host_tensor(v, [dist2.len() / k, k], device)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::DType;

    /// dσ_p/dp for one neighbour is −3·|l|·l/r³ (l = p − x); exact in F64 (guards against
    /// scalar ops whose backward rounds the scalar to f32).
    #[test]
    fn density_gradient_is_exact_in_f64() {
        let dev = Device::flex().autodiff();
        let p = [0.05f64, -0.07, 0.11];
        let x = [0.0f64, 0.01, 0.02];
        let r = 0.225;
        let particles = host_tensor(p.to_vec(), [1, 3], &dev).require_grad();
        let xt = host_tensor(x.to_vec(), [1, 3], &dev);
        let nbr = gather_neighbors(&particles, &[0], 1);
        let f = local_features(
            xt,
            nbr,
            host_tensor(vec![1.0f64], [1, 1], &dev),
            host_tensor(vec![0.0f64; 3], [1, 3], &dev),
            r,
        );
        let grads = f.sigma_p.sum().backward();
        let g: Vec<f64> = particles
            .grad(&grads)
            .unwrap()
            .try_into_vec_as::<f64>()
            .unwrap();
        let l: Vec<f64> = (0..3).map(|a| p[a] - x[a]).collect();
        let d = l.iter().map(|v| v * v).sum::<f64>().sqrt();
        for a in 0..3 {
            let want = -3.0 * d * l[a] / (r * r * r);
            assert!(
                (g[a] - want).abs() <= 1e-15 * want.abs().max(1.0),
                "axis {a}: {} vs {want}",
                g[a]
            );
        }
        assert_eq!(particles.dtype(), DType::F64);
    }
}
