//! The positional encoding `γ_L(v) = [v, sin(v), cos(v), sin(2v), cos(2v), …,
//! sin(2^{L−1}v), cos(2^{L−1}v)]` (identity first, no π, for each frequency the sin of every
//! channel then the cos; `[Q, C] → [Q, C·(1 + 2L)]`).
//!
//! On flex (with or without autodiff) it is one host operation: rows split over threads, each
//! sine and cosine evaluated once, and the backward pass reading them back from the output
//! (Burn's composed ops run on one thread and evaluate them again for the gradient). Elsewhere
//! it is built from Burn's ops ([`posenc_composed`]).

use burn::prelude::*;
use rayon::prelude::*;

use crate::real::{Real, par_zeros};

/// Rows per parallel task.
const ROWS_PER_TASK: usize = 512;

/// `γ_L(v)` for `v [Q, C]` with `freqs` = L (see the module docs).
pub fn posenc(v: Tensor<2>, freqs: usize) -> Tensor<2> {
    try_host_posenc(&v, freqs).unwrap_or_else(|| posenc_composed(v, freqs))
}

/// `γ_L(v)` built from Burn's ops (any backend).
pub fn posenc_composed(v: Tensor<2>, freqs: usize) -> Tensor<2> {
    let mut out = Vec::with_capacity(1 + 2 * freqs);
    out.push(v.clone());
    for i in 0..freqs {
        let fv = v.clone().mul_scalar((1u64 << i) as f64);
        out.push(fv.clone().sin());
        out.push(fv.cos());
    }
    Tensor::cat(out, 1)
}

/// `γ_L(v)` of `v [Q, C]` (row-major, `C ≥ 1`) on the host.
pub fn forward<T: Real>(v: &[T], c: usize, freqs: usize) -> Vec<T> {
    let width = c * (1 + 2 * freqs);
    let mut out = par_zeros(v.len() / c * width);
    out.par_chunks_mut(ROWS_PER_TASK * width)
        .zip(v.par_chunks(ROWS_PER_TASK * c))
        .for_each(|(out, v)| {
            for (o, v) in out.chunks_mut(width).zip(v.chunks(c)) {
                o[..c].copy_from_slice(v);
                for l in 0..freqs {
                    let scale = T::of_power_of_two(l);
                    let (sin, cos) = o[c * (1 + 2 * l)..c * (3 + 2 * l)].split_at_mut(c);
                    for ((s, co), &x) in sin.iter_mut().zip(cos).zip(v) {
                        (*s, *co) = (x * scale).sin_cos();
                    }
                }
            }
        });
    out
}

/// The gradient of `v` from the encoding's output `out` and its gradient `d_out` (both
/// `[Q, C·(1 + 2L)]`): `dv = d_out[v] + Σ_l 2^l (cos_l · d_sin_l − sin_l · d_cos_l)`.
pub fn backward<T: Real>(out: &[T], d_out: &[T], c: usize, freqs: usize) -> Vec<T> {
    let width = c * (1 + 2 * freqs);
    let mut dv = par_zeros(out.len() / width * c);
    dv.par_chunks_mut(ROWS_PER_TASK * c)
        .zip(out.par_chunks(ROWS_PER_TASK * width))
        .zip(d_out.par_chunks(ROWS_PER_TASK * width))
        .for_each(|((dv, out), d_out)| {
            let rows = dv
                .chunks_mut(c)
                .zip(out.chunks(width))
                .zip(d_out.chunks(width));
            for ((dv, o), d) in rows {
                dv.copy_from_slice(&d[..c]);
                for l in 0..freqs {
                    let scale = T::of_power_of_two(l);
                    let at = c * (1 + 2 * l);
                    let (sin, cos) = o[at..at + 2 * c].split_at(c);
                    let (d_sin, d_cos) = d[at..at + 2 * c].split_at(c);
                    for ((((g, &s), &co), &ds), &dc) in
                        dv.iter_mut().zip(sin).zip(cos).zip(d_sin).zip(d_cos)
                    {
                        *g += (co * ds - s * dc) * scale;
                    }
                }
            }
        });
    dv
}

/// The host encoding when `v` is a flex tensor (plain, or with autodiff without
/// checkpointing) of f32 or f64 with at least one channel; `None` otherwise.
#[cfg(feature = "flex")]
pub use flex_op::try_host_posenc;

/// Without the flex backend compiled in there is no host path.
#[cfg(not(feature = "flex"))]
pub fn try_host_posenc(_v: &Tensor<2>, _freqs: usize) -> Option<Tensor<2>> {
    None
}

#[cfg(feature = "flex")]
mod flex_op {
    use super::*;
    use burn::backend::autodiff::checkpoint::base::Checkpointer;
    use burn::backend::autodiff::checkpoint::strategy::NoCheckpointing;
    use burn::backend::autodiff::grads::Gradients;
    use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
    use burn::backend::flex::FlexTensor;
    use burn::backend::{Autodiff, Flex};
    use burn::tensor::DType;

    use crate::flex_host::{contiguous, slice, tensor};

    /// The backward step: input `v`.
    #[derive(Debug)]
    struct PosencBackward;

    #[derive(Debug, Clone)]
    struct State {
        /// The encoding (its sines and cosines give the gradient).
        out: FlexTensor,
        channels: usize,
        freqs: usize,
    }

    fn forward_in<T: Real>(v: &FlexTensor, c: usize, freqs: usize) -> FlexTensor {
        let rows = v.layout().shape()[0];
        let out = forward(slice::<T>(v), c, freqs);
        tensor(out, vec![rows, c * (1 + 2 * freqs)])
    }

    fn backward_in<T: Real>(s: &State, d_out: &FlexTensor) -> FlexTensor {
        let rows = s.out.layout().shape()[0];
        let dv = backward(slice::<T>(&s.out), slice(d_out), s.channels, s.freqs);
        tensor(dv, vec![rows, s.channels])
    }

    impl Backward<Flex, 1> for PosencBackward {
        type State = State;

        fn backward(self, ops: Ops<State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
            let d_out = contiguous(grads.consume::<Flex>(&ops.node));
            let [parent] = ops.parents;
            let s = ops.state;
            if let Some(node) = parent {
                let dv = match s.out.dtype() {
                    DType::F64 => backward_in::<f64>(&s, &d_out),
                    _ => backward_in::<f32>(&s, &d_out),
                };
                grads.register::<Flex>(node.id, dv);
            }
        }
    }

    /// See [`super::try_host_posenc`].
    pub fn try_host_posenc(v: &Tensor<2>, freqs: usize) -> Option<Tensor<2>> {
        let dtype = v.dtype();
        let [_, c] = v.dims();
        if !matches!(dtype, DType::F32 | DType::F64) || c == 0 {
            return None;
        }
        let run = |v: &FlexTensor| match dtype {
            DType::F64 => forward_in::<f64>(v, c, freqs),
            _ => forward_in::<f32>(v, c, freqs),
        };
        if let Ok(p) = v.clone().try_into_primitive::<Flex>() {
            return Some(Tensor::<2>::from_primitive::<Flex>(run(&contiguous(p))));
        }
        let a = v.clone().try_into_primitive::<Autodiff<Flex>>().ok()?;
        let out = run(&contiguous(a.primitive().clone()));
        let prep = PosencBackward
            .prepare::<NoCheckpointing>([a.node()])
            .compute_bound()
            .stateful();
        let result = match prep {
            OpsKind::Tracked(prep) => prep.finish(
                State {
                    out: out.clone(),
                    channels: c,
                    freqs,
                },
                out,
            ),
            OpsKind::UnTracked(prep) => prep.finish(out),
        };
        Some(Tensor::<2>::from_primitive::<Autodiff<Flex>>(result))
    }
}
