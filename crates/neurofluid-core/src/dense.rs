//! Dense layers `act(x·W + b)` (Burn's `Linear`, weight `[in, out]`) evaluated on the host,
//! forward and backward, with the host matmul ([`crate::matmul`]) split over rayon by rows. On
//! the flex backend [`linear`] is one operation (with autodiff: one autodiff operation with its
//! own backward pass); on other backends it is Burn's own ops.
//!
//! Why: with Burn's CPU matmul (the `gemm` crate) a 256-wide layer's forward and backward pass
//! runs at about 60 % of this rate on the test machine (BENCHMARKS.md), and the bias and the
//! ReLU are applied as the matmul writes its output.

use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::activation::relu;
use rayon::prelude::*;

use crate::half_matmul::{MatmulOperands, half_matmul, matmul_operands};
use crate::matmul::{Epilogue, Lanes, LayoutA, PackedB, matmul};
use crate::real::{Real, axpy, dot_in_lanes, par_zeros};
use crate::tensors::with_zero_rows;

/// Rows of `x` per task of the forward pass and of `dx`.
const ROWS_PER_TASK: usize = 1024;

/// Rows of `x` and `dz` per packed slice of `dz` in the weight gradient (the reduction's block).
const ROWS_PER_PACK: usize = 256;

/// Rows per partial sum of `dW` and `db`: an eighth of the batch in whole packed slices, at
/// most 4,096. A split by the batch size alone, so the sums do not depend on the number of
/// threads, and a small batch still has blocks for every thread.
fn rows_per_partial(m: usize) -> usize {
    m.div_ceil(8)
        .next_multiple_of(ROWS_PER_PACK)
        .min(16 * ROWS_PER_PACK)
}

/// The activation applied after `x·W + b`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Activation {
    /// None.
    Identity,
    /// `max(z, 0)`.
    Relu,
}

impl Activation {
    /// The activation with Burn's ops (the composed path).
    pub fn apply(self, z: Tensor<2>) -> Tensor<2> {
        match self {
            Activation::Identity => z,
            Activation::Relu => relu(z),
        }
    }
}

/// The input of a dense layer: column blocks side by side, `x = cat[x₁, x₂, …]`, each given
/// as its row-major values `[m, kᵢ]` and its column count `kᵢ ≥ 1` (the layer's skip and
/// direction inputs are not copied into one matrix: `x·W = Σ xᵢ·Wᵢ` over the row blocks Wᵢ).
pub type Blocks<'a, T> = [(&'a [T], usize)];

/// Rows of the layer's input (0 without blocks).
fn rows_of_blocks<T>(xs: &Blocks<'_, T>) -> usize {
    xs.first()
        .map_or(0, |(x, k)| x.len().checked_div(*k).unwrap_or(0))
}

/// Rows `r0..r0 + rows` of an input block.
fn row_range<'a, T>(&(x, k): &(&'a [T], usize), r0: usize, rows: usize) -> &'a [T] {
    &x[r0 * k..(r0 + rows) * k]
}

/// The first weight row of each block.
fn block_offsets<T>(xs: &Blocks<'_, T>) -> Vec<usize> {
    xs.iter()
        .scan(0, |at, &(_, k)| {
            let o = *at;
            *at += k;
            Some(o)
        })
        .collect()
}

/// `act(x·W + b)` for `x = cat[xᵢ] [m, k]` ([`Blocks`]), `w [k, n]`, `b [n]` → `[m, n]`.
pub fn forward<T: Lanes>(
    xs: &Blocks<'_, T>,
    w: &[T],
    b: &[T],
    n: usize,
    act: Activation,
) -> Vec<T> {
    let k = rows_of(w, n);
    let m = rows_of_blocks(xs);
    let mut y = par_zeros(m * n);
    if m == 0 || n == 0 {
        return y;
    }
    let relu = act == Activation::Relu;
    let offsets = block_offsets(xs);
    let wt = narrow_transposed(w, k, n);
    // one packed Wᵢ per block
    let packed: Vec<PackedB<T>> = if n >= NARROW {
        xs.iter()
            .zip(&offsets)
            .map(|(&(_, kb), &o)| PackedB::new(&w[o * n..(o + kb) * n], n, 1, kb, n))
            .collect()
    } else {
        Vec::new()
    };
    y.par_chunks_mut(ROWS_PER_TASK * n)
        .enumerate()
        .for_each(|(task, yc)| {
            let rows = yc.len() / n;
            let r0 = task * ROWS_PER_TASK;
            if !packed.is_empty() {
                for (i, (xb, pb)) in xs.iter().zip(&packed).enumerate() {
                    let epilogue = match i {
                        0 => Epilogue::Bias {
                            bias: b,
                            relu: relu && xs.len() == 1,
                        },
                        _ => Epilogue::Add,
                    };
                    let layout = LayoutA::Rows { stride: xb.1 };
                    let xc = row_range(xb, r0, rows);
                    matmul(xc, layout, rows, pb, yc, n, epilogue);
                }
                if relu && xs.len() > 1 {
                    clamp_negative(yc);
                }
            } else {
                for yr in yc.chunks_mut(n) {
                    yr.copy_from_slice(b);
                }
                for (xb, &o) in xs.iter().zip(&offsets) {
                    let kb = xb.1;
                    for (yr, xr) in yc.chunks_mut(n).zip(row_range(xb, r0, rows).chunks(kb)) {
                        for (y, wj) in yr.iter_mut().zip(wt.chunks(k)) {
                            *y += dot_in_lanes(xr, &wj[o..o + kb]);
                        }
                    }
                }
                if relu {
                    clamp_negative(yc);
                }
            }
        });
    y
}

/// Outputs narrower than this (the σ and colour heads) take dot products and row updates
/// instead of the matmul, whose register tiles are two vectors wide.
const NARROW: usize = 8;

/// Rows of `w [k, n]`.
fn rows_of<T>(w: &[T], n: usize) -> usize {
    w.len().checked_div(n).unwrap_or(0)
}

/// `w [k, n]` as `[n, k]` when the output is narrow (the only path that reads it), else empty.
fn narrow_transposed<T: Real>(w: &[T], k: usize, n: usize) -> Vec<T> {
    if n < NARROW {
        transposed(w, k, n)
    } else {
        Vec::new()
    }
}

/// `w [k, n]` as `[n, k]` (row-major).
fn transposed<T: Real>(w: &[T], k: usize, n: usize) -> Vec<T> {
    let mut t = vec![T::default(); w.len()];
    for i in 0..k {
        for j in 0..n {
            t[j * k + i] = w[i * n + j];
        }
    }
    t
}

/// Negative values to zero; NaN stays NaN (so a diverged run is still caught).
fn clamp_negative<T: Real>(v: &mut [T]) {
    // written without a branch so that it vectorises
    for x in v {
        *x = if *x < T::zero() { T::zero() } else { *x };
    }
}

/// The element-wise sum of `parts` in their order.
fn sum_in_order<T: Real>(parts: &[Vec<T>], len: usize) -> Vec<T> {
    let mut total = vec![T::zero(); len];
    for p in parts {
        for (t, &v) in total.iter_mut().zip(p) {
            *t += v;
        }
    }
    total
}

/// Gradients of a dense layer, each only when asked for.
#[derive(Debug, Default)]
pub struct DenseGrads<T> {
    /// `[m, kᵢ]` for each input block.
    pub x: Vec<Option<Vec<T>>>,
    /// `[k, n]`.
    pub w: Option<Vec<T>>,
    /// `[n]`.
    pub b: Option<Vec<T>>,
}

/// The backward pass of [`forward`] for `dy [m, n]`; `y` is the forward output (read for the
/// ReLU's mask, may be empty for the identity). `need` = which of `[x₁, …, x_p, w, b]` to
/// compute (the order of the autodiff operation's parents).
///
/// One parallel pass over blocks of rows ([`rows_per_partial`]: sized by the batch, not by the
/// threads) masks `dy` and sums the blocks' `dW` and `db` (added in block order, so the result
/// does not depend on the number of threads); a second computes each `dxᵢ`.
pub fn backward<T: Lanes>(
    xs: &Blocks<'_, T>,
    w: &[T],
    y: &[T],
    mut dz: Vec<T>,
    n: usize,
    act: Activation,
    need: &[bool],
) -> DenseGrads<T> {
    let p = xs.len();
    assert_eq!(
        need.len(),
        p + 2,
        "one flag per input block, the weight and the bias"
    );
    let (need_x, need_w, need_b) = (&need[..p], need[p], need[p + 1]);
    let k = rows_of(w, n);
    let m = dz.len() / n.max(1);
    let offsets = block_offsets(xs);
    if m == 0 || n == 0 {
        return DenseGrads {
            x: xs
                .iter()
                .zip(need_x)
                .map(|(&(_, kb), &need)| need.then(|| vec![T::default(); m * kb]))
                .collect(),
            w: need_w.then(|| vec![T::default(); k * n]),
            b: need_b.then(|| vec![T::default(); n]),
        };
    }
    let partial = rows_per_partial(m);
    let block = partial * n;
    let (dws, dbs): (Vec<Vec<T>>, Vec<Vec<T>>) = dz
        .par_chunks_mut(block)
        .enumerate()
        .map(|(i, dzc)| {
            let rows = dzc.len() / n;
            let r0 = i * partial;
            if act == Activation::Relu {
                for (d, &y) in dzc.iter_mut().zip(&y[r0 * n..]) {
                    *d = if y <= T::zero() { T::zero() } else { *d };
                }
            }
            let mut db = Vec::new();
            if need_b {
                db = vec![T::zero(); n];
                for row in dzc.chunks(n) {
                    for (o, &v) in db.iter_mut().zip(row) {
                        *o += v;
                    }
                }
            }
            let mut dw = Vec::new();
            if need_w {
                dw = vec![T::zero(); k * n];
                if n < NARROW {
                    // dWᵀ[j, oᵢ..oᵢ + kᵢ] += dz[r, j] · xᵢ[r]
                    for (xb, &o) in xs.iter().zip(&offsets) {
                        let (xc, kb) = (row_range(xb, r0, rows), xb.1);
                        for (dzr, xr) in dzc.chunks(n).zip(xc.chunks(kb)) {
                            for (j, &g) in dzr.iter().enumerate() {
                                axpy(&mut dw[j * k + o..j * k + o + kb], g, xr);
                            }
                        }
                    }
                    dw = transposed(&dw, n, k);
                } else {
                    // dWᵢ = xᵢᵀ·dz, `dz` packed a slice of rows at a time, summed in row order
                    for (s, dzs) in dzc.chunks(ROWS_PER_PACK * n).enumerate() {
                        let packed = PackedB::new(dzs, n, 1, dzs.len() / n, n);
                        let epilogue = if s == 0 {
                            Epilogue::Store
                        } else {
                            Epilogue::Add
                        };
                        let pr0 = r0 + s * ROWS_PER_PACK;
                        let prows = dzs.len() / n;
                        for (xb, &o) in xs.iter().zip(&offsets) {
                            let kb = xb.1;
                            matmul(
                                row_range(xb, pr0, prows),
                                LayoutA::Cols { stride: kb },
                                kb,
                                &packed,
                                &mut dw[o * n..(o + kb) * n],
                                n,
                                epilogue,
                            );
                        }
                    }
                }
            }
            (dw, db)
        })
        .unzip();
    let d_w = need_w.then(|| sum_in_order(&dws, k * n));
    let d_b = need_b.then(|| sum_in_order(&dbs, n));
    let wt = narrow_transposed(w, k, n);
    let d_x = xs
        .iter()
        .zip(&offsets)
        .zip(need_x)
        .map(|((&(_, kb), &o), &need)| need.then(|| input_gradient(&dz, w, &wt, n, o, kb)))
        .collect();
    DenseGrads {
        x: d_x,
        w: d_w,
        b: d_b,
    }
}

/// `dxᵢ = dz·Wᵢᵀ [m, kᵢ]` for the input block whose weight rows are `o..o + kᵢ`; `wt` is `Wᵀ`
/// when the output is narrow ([`narrow_transposed`]).
fn input_gradient<T: Lanes>(dz: &[T], w: &[T], wt: &[T], n: usize, o: usize, kb: usize) -> Vec<T> {
    let m = dz.len() / n;
    let k = rows_of(w, n);
    let mut dx = par_zeros(m * kb);
    // Wᵢᵀ [n, kᵢ] packed
    let packed = (n >= NARROW).then(|| PackedB::new(&w[o * n..(o + kb) * n], 1, n, n, kb));
    dx.par_chunks_mut(ROWS_PER_TASK * kb)
        .zip(dz.par_chunks(ROWS_PER_TASK * n))
        .for_each(|(dxc, dzc)| {
            if let Some(packed) = &packed {
                let rows = dzc.len() / n;
                let layout = LayoutA::Rows { stride: n };
                matmul(dzc, layout, rows, packed, dxc, kb, Epilogue::Store);
            } else {
                // dxᵢ[r] = Σ_j dz[r, j] · Wᵢ[:, j]
                for (dxr, dzr) in dxc.chunks_mut(kb).zip(dzc.chunks(n)) {
                    for (&g, wj) in dzr.iter().zip(wt.chunks(k)) {
                        axpy(dxr, g, &wj[o..o + kb]);
                    }
                }
            }
        });
    dx
}

/// `act(layer(x))`: one host operation on flex (with or without autodiff) when the layer has a
/// bias and every tensor is f32 or f64 of one type; Burn's ops otherwise.
pub fn linear(layer: &Linear, x: Tensor<2>, act: Activation) -> Tensor<2> {
    linear_of_cat(layer, vec![x], act)
}

/// `act(layer(cat[x₁, x₂, …]))` (column blocks side by side, as the MLP's skip and direction
/// inputs): on flex one host operation that reads the blocks in place ([`Blocks`]); on an
/// accelerator Burn's ops with the rows in blocks ([`linear_in_row_blocks`]) when there are
/// more than [`split_rows`] of them or the process's matmuls take 16-bit operands
/// ([`crate::half_matmul::matmul_operands`]); Burn's `cat` and ops otherwise.
///
/// # Panics
/// When `xs` is empty.
pub fn linear_of_cat(layer: &Linear, xs: Vec<Tensor<2>>, act: Activation) -> Tensor<2> {
    if let Some(bias) = &layer.bias
        && let Some(y) = try_host_linear(&xs, &layer.weight.val(), &bias.val(), act)
    {
        return y;
    }
    let x = if xs.len() == 1 {
        xs.into_iter().next().expect("one input")
    } else {
        Tensor::cat(xs, 1)
    };
    if !crate::device::is_host(&x.device()) {
        let (m, block, operands) = (x.dims()[0], split_rows(), matmul_operands());
        if block > 0 && m > block {
            return linear_in_row_blocks(layer, x, act, block, operands);
        }
        if operands != MatmulOperands::F32 && m > 0 {
            return linear_in_row_blocks(layer, x, act, m, operands);
        }
    }
    act.apply(layer.forward(x))
}

/// The inputs of a network of dense layers (the same `m` rows each) with zero rows added up to
/// a whole number of [`linear_in_row_blocks`]' blocks where an accelerator cuts the layers' rows
/// into blocks, and `m`: every layer then runs on whole blocks and pads nothing (a padding is a
/// fill and a concatenation per layer, forward and backward, on a GPU), and the network's outputs
/// are cut back to `m` rows with [`first_rows`]. The real rows' values and gradients are those of
/// the unpadded network: a row's output depends on its own input alone, and the padding rows,
/// cut from the outputs, receive an exactly zero gradient, so their terms in the weights'
/// gradients are zeros.
pub fn pad_to_row_blocks(xs: Vec<Tensor<2>>) -> (Vec<Tensor<2>>, usize) {
    let on_host = xs
        .first()
        .is_none_or(|x| crate::device::is_host(&x.device()));
    pad_rows(xs, if on_host { 0 } else { split_rows() })
}

/// `xs` (the same `m` rows each) with zero rows added up to a multiple of `block` (none when
/// `block` is 0 or `m ≤ block`: one block, unpadded), and `m`; see [`pad_to_row_blocks`].
pub fn pad_rows(xs: Vec<Tensor<2>>, block: usize) -> (Vec<Tensor<2>>, usize) {
    let Some(first) = xs.first() else {
        return (xs, 0);
    };
    let m = first.dims()[0];
    if block == 0 || m <= block || m % block == 0 {
        return (xs, m);
    }
    let padded = m.div_ceil(block) * block;
    (
        xs.into_iter().map(|x| with_zero_rows(x, padded)).collect(),
        m,
    )
}

/// The first `m` rows of `x` (the output of a network whose inputs [`pad_to_row_blocks`]
/// padded); `x` itself when it has `m`.
pub fn first_rows(x: Tensor<2>, m: usize) -> Tensor<2> {
    let [rows, cols] = x.dims();
    if rows == m {
        x
    } else {
        x.slice([0..m, 0..cols])
    }
}

/// Rows per block of [`linear_in_row_blocks`] on an accelerator (0: off); see [`set_split_rows`].
static SPLIT_ROWS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(4096);

/// The rows per block of a dense layer on an accelerator (4,096 unless set).
pub fn split_rows() -> usize {
    SPLIT_ROWS.load(std::sync::atomic::Ordering::Relaxed)
}

/// Sets the rows per block of a dense layer on an accelerator; 0 turns the blocks off (one
/// matmul over every row). For benchmarks that compare the two.
pub fn set_split_rows(rows: usize) {
    SPLIT_ROWS.store(rows, std::sync::atomic::Ordering::Relaxed);
}

/// `act(layer(x))` with the rows of `x [m, k]` cut into blocks of `block` (the last padded with
/// zero rows): one batched matmul `[B, block, k]·[1, k, n]` whose weight gradient is `B`
/// products `x_bᵀ·dz_b` summed over the batch — the split of the reduction over the rows that a
/// GPU needs. A single matmul's weight gradient has an inner dimension of every row (PhysNeRF's
/// 150k samples), which the fixed matmul kernel runs on a few workgroups: on an H100 the MLPs'
/// backward took 48 times their forward (docs/notebook/benchmarks-history.md, "Issue 30, first H100 session").
/// With 16-bit `operands` the blocks' products are [`half_matmul`]s (forward and backward).
/// The same values as `act(layer.forward(x))` up to the order of the sums (and the 16-bit
/// operands' rounding).
pub fn linear_in_row_blocks(
    layer: &Linear,
    x: Tensor<2>,
    act: Activation,
    block: usize,
    operands: MatmulOperands,
) -> Tensor<2> {
    let [m, k] = x.dims();
    let block = block.max(1);
    let blocks = m.div_ceil(block);
    let padded = blocks * block;
    let x = with_zero_rows(x, padded);
    let w = layer.weight.val();
    let n = w.dims()[1];
    let x = x.reshape([blocks, block, k]);
    let z = match operands.half() {
        None => x.matmul(w.unsqueeze_dim::<3>(0)),
        Some(half) => half_matmul(x, w, half),
    }
    .reshape([padded, n]);
    let z = first_rows(z, m);
    let z = match &layer.bias {
        Some(b) => z + b.val().unsqueeze_dim::<2>(0),
        None => z,
    };
    act.apply(z)
}

/// The host dense layer `act(cat[xᵢ]·w + b)` when the inputs (one or two blocks of at least
/// one column, the same rows), `w` and `b` are all flex tensors (with autodiff without
/// checkpointing, or plain) of one float type, f32 or f64, and the shapes fit; `None`
/// otherwise.
#[cfg(feature = "flex")]
pub use flex_op::try_host_linear;

/// Without the flex backend compiled in there is no host path.
#[cfg(not(feature = "flex"))]
pub fn try_host_linear(
    _xs: &[Tensor<2>],
    _w: &Tensor<2>,
    _b: &Tensor<1>,
    _act: Activation,
) -> Option<Tensor<2>> {
    None
}

#[cfg(feature = "flex")]
mod flex_op {
    use super::*;
    use crate::flex_host::{contiguous, slice, tensor};
    use burn::backend::autodiff::checkpoint::base::Checkpointer;
    use burn::backend::autodiff::checkpoint::strategy::NoCheckpointing;
    use burn::backend::autodiff::grads::Gradients;
    use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
    use burn::backend::flex::FlexTensor;
    use burn::backend::{Autodiff, Flex};
    use burn::tensor::DType;

    /// The backward step: parents (x₁, …, x_p, weight, bias), `N = p + 2`.
    #[derive(Debug)]
    struct DenseBackward<const N: usize>;

    #[derive(Debug, Clone)]
    struct State {
        xs: Vec<FlexTensor>,
        w: FlexTensor,
        /// The output, kept for the ReLU's mask.
        y: Option<FlexTensor>,
        act: Activation,
    }

    /// The input blocks' values and column counts.
    fn blocks<T: Real>(xs: &[FlexTensor]) -> Vec<(&[T], usize)> {
        xs.iter()
            .map(|x| (slice::<T>(x), x.layout().shape()[1]))
            .collect()
    }

    fn forward_in<T: Lanes>(
        xs: &[FlexTensor],
        w: &FlexTensor,
        b: &FlexTensor,
        act: Activation,
    ) -> FlexTensor {
        let m = xs[0].layout().shape()[0];
        let n = w.layout().shape()[1];
        let y = forward(&blocks::<T>(xs), slice(w), slice(b), n, act);
        tensor(y, vec![m, n])
    }

    impl<const N: usize> Backward<Flex, N> for DenseBackward<N> {
        type State = State;

        fn backward(self, ops: Ops<State, N>, grads: &mut Gradients, _: &mut Checkpointer) {
            let dy = contiguous(grads.consume::<Flex>(&ops.node));
            let need: Vec<bool> = ops.parents.iter().map(Option::is_some).collect();
            let s = ops.state;
            let g = match s.w.dtype() {
                DType::F64 => grads_in::<f64>(&s, dy, &need),
                _ => grads_in::<f32>(&s, dy, &need),
            };
            for (parent, grad) in ops.parents.into_iter().zip(g) {
                if let (Some(node), Some(grad)) = (parent, grad) {
                    grads.register::<Flex>(node.id, grad);
                }
            }
        }
    }

    /// The gradients of `[x₁, …, x_p, w, b]` as flex tensors, those in `need`.
    fn grads_in<T: Lanes>(s: &State, dy: FlexTensor, need: &[bool]) -> Vec<Option<FlexTensor>> {
        let [k, n] = [s.w.layout().shape()[0], s.w.layout().shape()[1]];
        let m = s.xs[0].layout().shape()[0];
        let dy: Vec<T> = dy
            .into_data()
            .try_into_vec()
            .expect("dy of the layer's float type");
        let y = s.y.as_ref().map(slice::<T>).unwrap_or(&[]);
        let g = backward(&blocks::<T>(&s.xs), slice(&s.w), y, dy, n, s.act, need);
        let mut out: Vec<Option<FlexTensor>> =
            g.x.into_iter()
                .zip(&s.xs)
                .map(|(v, x)| v.map(|v| tensor(v, vec![m, x.layout().shape()[1]])))
                .collect();
        out.push(g.w.map(|v| tensor(v, vec![k, n])));
        out.push(g.b.map(|v| tensor(v, vec![n])));
        out
    }

    /// See [`super::try_host_linear`].
    pub fn try_host_linear(
        xs: &[Tensor<2>],
        w: &Tensor<2>,
        b: &Tensor<1>,
        act: Activation,
    ) -> Option<Tensor<2>> {
        let dtype = w.dtype();
        if !matches!(dtype, DType::F32 | DType::F64)
            || b.dtype() != dtype
            || xs.iter().any(|x| x.dtype() != dtype)
        {
            return None;
        }
        let ([kw, n], [nb]) = (w.dims(), b.dims());
        let m = xs.first()?.dims()[0];
        let k: usize = xs.iter().map(|x| x.dims()[1]).sum();
        if xs.iter().any(|x| x.dims()[1] == 0 || x.dims()[0] != m) || k != kw || n != nb {
            // no inputs, or shapes that do not fit: Burn's `Linear` (and its error)
            return None;
        }
        let plain = (
            w.clone().try_into_primitive::<Flex>(),
            b.clone().try_into_primitive::<Flex>(),
        );
        if let (Ok(wp), Ok(bp)) = plain {
            let xps = xs
                .iter()
                .map(|x| x.clone().try_into_primitive::<Flex>().ok().map(contiguous))
                .collect::<Option<Vec<_>>>()?;
            let y = run(&xps, &contiguous(wp), &contiguous(bp), act);
            return Some(Tensor::<2>::from_primitive::<Flex>(y));
        }
        match xs.len() {
            1 => tracked::<3>(xs, w, b, act),
            2 => tracked::<4>(xs, w, b, act),
            _ => None,
        }
    }

    /// The forward pass in the weights' float type.
    fn run(xs: &[FlexTensor], w: &FlexTensor, b: &FlexTensor, act: Activation) -> FlexTensor {
        match w.dtype() {
            DType::F64 => forward_in::<f64>(xs, w, b, act),
            _ => forward_in::<f32>(xs, w, b, act),
        }
    }

    /// The layer on autodiff tensors, with `N − 2` input blocks.
    fn tracked<const N: usize>(
        xs: &[Tensor<2>],
        w: &Tensor<2>,
        b: &Tensor<1>,
        act: Activation,
    ) -> Option<Tensor<2>> {
        let xa = xs
            .iter()
            .map(|x| x.clone().try_into_primitive::<Autodiff<Flex>>().ok())
            .collect::<Option<Vec<_>>>()?;
        let wa = w.clone().try_into_primitive::<Autodiff<Flex>>().ok()?;
        let ba = b.clone().try_into_primitive::<Autodiff<Flex>>().ok()?;
        let xps: Vec<FlexTensor> = xa
            .iter()
            .map(|a| contiguous(a.primitive().clone()))
            .collect();
        let wp = contiguous(wa.primitive().clone());
        let y = run(&xps, &wp, &contiguous(ba.primitive().clone()), act);
        let nodes: Vec<_> = xa
            .iter()
            .map(|a| a.node())
            .chain([wa.node(), ba.node()])
            .collect();
        let nodes: [_; N] = nodes.try_into().ok()?;
        let prep = DenseBackward::<N>
            .prepare::<NoCheckpointing>(nodes)
            .compute_bound()
            .stateful();
        let out = match prep {
            OpsKind::Tracked(prep) => prep.finish(
                State {
                    xs: xps,
                    w: wp,
                    y: (act == Activation::Relu).then(|| y.clone()),
                    act,
                },
                y,
            ),
            OpsKind::UnTracked(prep) => prep.finish(y),
        };
        Some(Tensor::<2>::from_primitive::<Autodiff<Flex>>(out))
    }
}
