//! Volume rendering (spec §2.7): `α = 1 − exp(−δ·relu(σ))`, `T_k = Π_{j<k}(1 − α_j + 1e-10)`,
//! `w = α·T`, `C = Σ w·c (+ 1 − Σ w on white)`, with `δ_k = (z_{k+1} − z_k)·|d|` and
//! `δ_last = 1e10·|d|`.

use burn::prelude::*;
use burn::tensor::activation::relu;

use crate::real::Real;

/// Added to `1 − α` in the transmittance product.
pub const T_EPS: f64 = 1e-10;
/// The "infinite" last interval.
pub const DELTA_LAST: f64 = 1e10;

/// Result of compositing R rays of S samples.
#[derive(Debug, Clone)]
pub struct Composite {
    /// `[R, 3]` pixel colours.
    pub rgb_map: Tensor<2>,
    /// `[R, S]` compositing weights `w = α·T`.
    pub weights: Tensor<2>,
    /// `[R, S]` opacities α.
    pub alpha: Tensor<2>,
    /// `[R, 1]` accumulated opacity Σ w.
    pub acc: Tensor<2>,
}

/// Host intervals `δ [R·S]` of sorted depths `z [R·S]` (S per ray), scaled by `|d|` of each ray.
pub fn deltas<T: Real>(z: &[T], s: usize, dirs: &[[T; 3]]) -> Vec<T> {
    let mut out = Vec::with_capacity(z.len());
    for (zr, d) in z.chunks(s).zip(dirs) {
        let norm = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        for k in 0..s {
            let delta = if k + 1 < s {
                zr[k + 1] - zr[k]
            } else {
                T::of(DELTA_LAST)
            };
            out.push(delta * norm);
        }
    }
    out
}

/// Composites masked colours `rgb [R, S, 3]` and masked raw densities `sigma [R, S]` with the
/// intervals `deltas [R, S]`.
pub fn volume_render(
    rgb: Tensor<3>,
    sigma: Tensor<2>,
    deltas: Tensor<2>,
    white_background: bool,
) -> Composite {
    let [r, s] = sigma.dims();
    let alpha = (deltas.neg() * relu(sigma)).exp().neg().add_scalar(1.0);
    let one_minus = alpha.clone().neg().add_scalar(1.0).add_scalar(T_EPS);
    let trans = Tensor::cat(
        vec![one_minus.clone().slice([0..r, 0..1]).ones_like(), one_minus],
        1,
    )
    .cumprod(1)
    .slice([0..r, 0..s]);
    let weights = alpha.clone() * trans;
    let acc = weights.clone().sum_dim(1);
    let mut rgb_map = (weights.clone().reshape([r, s, 1]) * rgb)
        .sum_dim(1)
        .reshape([r, 3]);
    if white_background {
        rgb_map = rgb_map.add_scalar(1.0) - acc.clone();
    }
    Composite {
        rgb_map,
        weights,
        alpha,
        acc,
    }
}
