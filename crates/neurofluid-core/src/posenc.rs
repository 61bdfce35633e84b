//! The positional encoding `γ_L(v) = [v, sin(v), cos(v), sin(2v), cos(2v), …,
//! sin(2^{L−1}v), cos(2^{L−1}v)]` (identity first, no π, for each frequency the sin of every
//! channel then the cos; `[Q, C] → [Q, C·(1 + 2L)]`), and the concatenation of several inputs'
//! encodings, each with its own L ([`posenc_cat`]: the network inputs e_x and e_d).
//!
//! On flex (with or without autodiff) it is one host operation: rows split over threads, each
//! sine and cosine evaluated once, the encodings of all inputs written into one output, and the
//! backward pass reading the sines and cosines back from the output (Burn's composed ops run on
//! one thread, evaluate them again for the gradient and copy every part into the
//! concatenation). Elsewhere it is built from Burn's ops ([`posenc_composed`]): each input's
//! encoding one broadcast expression that a fusing backend runs as one kernel, not a
//! concatenation of `1 + 2L` pieces (a slice-assign kernel each on a GPU).

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
    if !inputs.first().is_some_and(|(v, _)| on_flex(v)) {
        return posenc_composed(inputs);
    }
    let blocks: Vec<Block> = inputs
        .iter()
        .map(|(v, freqs)| Block {
            channels: v.dims()[1],
            freqs: *freqs,
        })
        .collect();
    let vs: Vec<Tensor<2>> = inputs.into_iter().map(|(v, _)| v).collect();
    // narrow inputs (a few columns each): cheap beside the encoding
    let v = Tensor::cat(vs.clone(), 1);
    try_host_posenc(&v, &blocks).unwrap_or_else(|| {
        posenc_composed(vs.into_iter().zip(blocks.iter().map(|b| b.freqs)).collect())
    })
}

/// Whether `v` lives on the flex backend (with or without autodiff), where the host operation
/// runs.
fn on_flex(v: &Tensor<2>) -> bool {
    #[cfg(feature = "flex")]
    return v.device() == Device::flex();
    #[cfg(not(feature = "flex"))]
    return false;
}

/// [`posenc_cat`] built from Burn's ops (any backend): per input `v [Q, C]` the broadcast
/// `a = v·s [Q, 1 + 2L, C]` with the scales `s = (1, 1, 1, 2, 2, …, 2^{L−1}, 2^{L−1})` (exact:
/// powers of two), then `a·[slot is v] + sin(a)·[slot is a sine] + cos(a)·[slot is a cosine]`
/// (exact: the selectors are 0 and 1), reshaped to `[Q, C·(1 + 2L)]`; the inputs' encodings
/// side by side. The scales and selectors are uploaded once per device, precision and L.
///
/// # Panics
/// When `inputs` is empty.
pub fn posenc_composed(inputs: Vec<(Tensor<2>, usize)>) -> Tensor<2> {
    let mut parts: Vec<Tensor<2>> = inputs
        .into_iter()
        .map(|(v, freqs)| encode_block(v, freqs))
        .collect();
    assert!(!parts.is_empty(), "posenc of no input");
    if parts.len() == 1 {
        parts.pop().expect("one part")
    } else {
        Tensor::cat(parts, 1)
    }
}

/// `γ_L(v)` of one input as one broadcast expression (see [`posenc_composed`]).
fn encode_block(v: Tensor<2>, freqs: usize) -> Tensor<2> {
    if freqs == 0 {
        return v;
    }
    let [q, c] = v.dims();
    let [scale, is_v, is_sin, is_cos] = slot_constants(&v.device(), v.dtype(), freqs);
    let a = v.reshape([q, 1, c]) * scale;
    (a.clone() * is_v + a.clone().sin() * is_sin + a.cos() * is_cos)
        .reshape([q, c * (1 + 2 * freqs)])
}

/// The `[1, 1 + 2L, 1]` scales and the three slot selectors of [`encode_block`] on `device`,
/// uploaded on first use and kept for the process (a few numbers per device, precision and L).
fn slot_constants(device: &Device, dtype: burn::tensor::DType, freqs: usize) -> [Tensor<3>; 4] {
    type Entry = (Device, bool, burn::tensor::DType, usize, [Tensor<3>; 4]);
    static CACHE: std::sync::Mutex<Vec<Entry>> = std::sync::Mutex::new(Vec::new());
    // devices compare equal with and without autodiff; a tensor of one cannot meet the other's
    let tracked = device.is_autodiff();
    let mut cache = CACHE
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    if let Some(hit) = cache
        .iter()
        .find(|e| &e.0 == device && e.1 == tracked && e.2 == dtype && e.3 == freqs)
    {
        return hit.4.clone();
    }
    let slots = 1 + 2 * freqs;
    let column = |f: &dyn Fn(usize) -> f64| -> Tensor<3> {
        let values: Vec<f64> = (0..slots).map(f).collect();
        crate::transfer::upload(TensorData::new(values, [1, slots, 1]), (device, dtype))
    };
    let constants = [
        column(&|m| {
            if m == 0 {
                1.0
            } else {
                (1u64 << ((m - 1) / 2)) as f64
            }
        }),
        column(&|m| f64::from(m == 0)),
        column(&|m| f64::from(m > 0 && m % 2 == 1)),
        column(&|m| f64::from(m > 0 && m % 2 == 0)),
    ];
    cache.push((device.clone(), tracked, dtype, freqs, constants.clone()));
    constants
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
