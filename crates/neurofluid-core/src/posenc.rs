//! The positional encoding `γ_L(v) = [v, sin(v), cos(v), sin(2v), cos(2v), …,
//! sin(2^{L−1}v), cos(2^{L−1}v)]` (identity first, no π, for each frequency the sin of every
//! channel then the cos; `[Q, C] → [Q, C·(1 + 2L)]`), and the concatenation of several inputs'
//! encodings, each with its own L ([`posenc_cat`]: the network inputs e_x and e_d).
//!
//! On flex (with or without autodiff) it is one host operation: rows split over threads, each
//! sine and cosine evaluated once, the encodings of all inputs written into one output, and the
//! backward pass reading the sines and cosines back from the output (Burn's composed ops run on
//! one thread, evaluate them again for the gradient and copy every part into the
//! concatenation). Elsewhere it is built from Burn's ops ([`posenc_composed`]).

use burn::prelude::*;
use rayon::prelude::*;

use crate::real::{Real, par_zeros};

/// Rows per parallel task.
const ROWS_PER_TASK: usize = 512;

/// A block of input columns encoded with one number of frequencies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Block {
    /// Input columns C.
    pub channels: usize,
    /// Frequencies L.
    pub freqs: usize,
}

impl Block {
    /// Output columns `C·(1 + 2L)`.
    pub fn width(&self) -> usize {
        self.channels * (1 + 2 * self.freqs)
    }
}

/// `γ_L(v)` for `v [Q, C]` with `freqs` = L (see the module docs).
pub fn posenc(v: Tensor<2>, freqs: usize) -> Tensor<2> {
    posenc_cat(vec![(v, freqs)])
}

/// `cat[γ_{L₁}(v₁), γ_{L₂}(v₂), …]` along the columns for inputs `(vᵢ [Q, Cᵢ], Lᵢ)`.
///
/// # Panics
/// When `inputs` is empty.
pub fn posenc_cat(inputs: Vec<(Tensor<2>, usize)>) -> Tensor<2> {
    let (vs, blocks): (Vec<Tensor<2>>, Vec<Block>) = inputs
        .into_iter()
        .map(|(v, freqs)| {
            let channels = v.dims()[1];
            (v, Block { channels, freqs })
        })
        .unzip();
    let v = if vs.len() == 1 {
        vs.into_iter().next().expect("one input")
    } else {
        // narrow inputs (a few columns each): cheap beside the encoding
        Tensor::cat(vs, 1)
    };
    try_host_posenc(&v, &blocks).unwrap_or_else(|| posenc_composed(v, &blocks))
}

/// [`posenc_cat`] built from Burn's ops (any backend) on the concatenated inputs `v`.
pub fn posenc_composed(v: Tensor<2>, blocks: &[Block]) -> Tensor<2> {
    let mut out = Vec::new();
    let mut at = 0;
    for b in blocks {
        let part = v.clone().narrow(1, at, b.channels);
        at += b.channels;
        out.push(part.clone());
        for i in 0..b.freqs {
            let fv = part.clone().mul_scalar((1u64 << i) as f64);
            out.push(fv.clone().sin());
            out.push(fv.cos());
        }
    }
    Tensor::cat(out, 1)
}

/// The total input and output columns of `blocks`.
fn widths(blocks: &[Block]) -> (usize, usize) {
    blocks
        .iter()
        .fold((0, 0), |(c, w), b| (c + b.channels, w + b.width()))
}

/// [`posenc_cat`] of `v [Q, ΣCᵢ]` (row-major, the inputs side by side) on the host.
pub fn forward<T: Real>(v: &[T], blocks: &[Block]) -> Vec<T> {
    let (c, width) = widths(blocks);
    let mut out = par_zeros(v.len().checked_div(c).unwrap_or(0) * width);
    if c == 0 {
        return out;
    }
    out.par_chunks_mut(ROWS_PER_TASK * width)
        .zip(v.par_chunks(ROWS_PER_TASK * c))
        .for_each(|(out, v)| {
            for (o, v) in out.chunks_mut(width).zip(v.chunks(c)) {
                let (mut o, mut v) = (o, v);
                for b in blocks {
                    let (ob, o_rest) = o.split_at_mut(b.width());
                    let (vb, v_rest) = v.split_at(b.channels);
                    encode_row(vb, ob, b.freqs);
                    (o, v) = (o_rest, v_rest);
                }
            }
        });
    out
}

/// `γ_L` of one row `v [C]` into `o [C·(1 + 2L)]`.
fn encode_row<T: Real>(v: &[T], o: &mut [T], freqs: usize) {
    let c = v.len();
    o[..c].copy_from_slice(v);
    for l in 0..freqs {
        let scale = T::of_power_of_two(l);
        let (sin, cos) = o[c * (1 + 2 * l)..c * (3 + 2 * l)].split_at_mut(c);
        for ((s, co), &x) in sin.iter_mut().zip(cos).zip(v) {
            (*s, *co) = (x * scale).sin_cos();
        }
    }
}

/// The gradient of `v [Q, ΣCᵢ]` from the encoding's output `out` and its gradient `d_out`
/// (both `[Q, Σ Cᵢ·(1 + 2Lᵢ)]`): per block, `dv = d_out[v] + Σ_l 2^l (cos_l · d_sin_l −
/// sin_l · d_cos_l)`.
pub fn backward<T: Real>(out: &[T], d_out: &[T], blocks: &[Block]) -> Vec<T> {
    let (c, width) = widths(blocks);
    let mut dv = par_zeros(out.len().checked_div(width).unwrap_or(0) * c);
    if c == 0 {
        return dv;
    }
    dv.par_chunks_mut(ROWS_PER_TASK * c)
        .zip(out.par_chunks(ROWS_PER_TASK * width))
        .zip(d_out.par_chunks(ROWS_PER_TASK * width))
        .for_each(|((dv, out), d_out)| {
            let rows = dv
                .chunks_mut(c)
                .zip(out.chunks(width))
                .zip(d_out.chunks(width));
            for ((dv, o), d) in rows {
                let (mut dv, mut o, mut d) = (dv, o, d);
                for b in blocks {
                    let (dvb, dv_rest) = dv.split_at_mut(b.channels);
                    let (ob, o_rest) = o.split_at(b.width());
                    let (db, d_rest) = d.split_at(b.width());
                    gradient_row(ob, db, dvb, b.freqs);
                    (dv, o, d) = (dv_rest, o_rest, d_rest);
                }
            }
        });
    dv
}

/// The gradient `dv [C]` of one row of `γ_L` from its output `o` and output gradient `d`.
fn gradient_row<T: Real>(o: &[T], d: &[T], dv: &mut [T], freqs: usize) {
    let c = dv.len();
    dv.copy_from_slice(&d[..c]);
    for l in 0..freqs {
        let scale = T::of_power_of_two(l);
        let at = c * (1 + 2 * l);
        let (sin, cos) = o[at..at + 2 * c].split_at(c);
        let (d_sin, d_cos) = d[at..at + 2 * c].split_at(c);
        for ((((g, &s), &co), &ds), &dc) in dv.iter_mut().zip(sin).zip(cos).zip(d_sin).zip(d_cos) {
            *g += (co * ds - s * dc) * scale;
        }
    }
}

/// The host encoding of `v [Q, ΣCᵢ]` when it is a flex tensor (plain, or with autodiff without
/// checkpointing) of f32 or f64 whose columns are those of `blocks`, at least one; `None`
/// otherwise.
#[cfg(feature = "flex")]
pub use flex_op::try_host_posenc;

/// Without the flex backend compiled in there is no host path.
#[cfg(not(feature = "flex"))]
pub fn try_host_posenc(_v: &Tensor<2>, _blocks: &[Block]) -> Option<Tensor<2>> {
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
        blocks: Vec<Block>,
    }

    fn forward_in<T: Real>(v: &FlexTensor, blocks: &[Block]) -> FlexTensor {
        let rows = v.layout().shape()[0];
        let out = forward(slice::<T>(v), blocks);
        tensor(out, vec![rows, widths(blocks).1])
    }

    fn backward_in<T: Real>(s: &State, d_out: &FlexTensor) -> FlexTensor {
        let rows = s.out.layout().shape()[0];
        let dv = backward(slice::<T>(&s.out), slice(d_out), &s.blocks);
        tensor(dv, vec![rows, widths(&s.blocks).0])
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
    pub fn try_host_posenc(v: &Tensor<2>, blocks: &[Block]) -> Option<Tensor<2>> {
        let dtype = v.dtype();
        let [_, c] = v.dims();
        if !matches!(dtype, DType::F32 | DType::F64) || c == 0 || c != widths(blocks).0 {
            return None;
        }
        let run = |v: &FlexTensor| match dtype {
            DType::F64 => forward_in::<f64>(v, blocks),
            _ => forward_in::<f32>(v, blocks),
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
                    blocks: blocks.to_vec(),
                },
                out,
            ),
            OpsKind::UnTracked(prep) => prep.finish(out),
        };
        Some(Tensor::<2>::from_primitive::<Autodiff<Flex>>(result))
    }
}
