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

use crate::matmul::{Epilogue, Lanes, LayoutA, PackedB, matmul};
use crate::real::{Real, axpy, dot_in_lanes, par_zeros};

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

/// `act(x·W + b)` for `x [m, k]` (row-major, `k ≥ 1`), `w [k, n]`, `b [n]` → `[m, n]`.
pub fn forward<T: Lanes>(x: &[T], w: &[T], b: &[T], n: usize, act: Activation) -> Vec<T> {
    let k = rows_of(w, n);
    let m = x.len().checked_div(k).unwrap_or(0);
    let mut y = par_zeros(m * n);
    if m == 0 || n == 0 {
        return y;
    }
    let relu = act == Activation::Relu;
    let wt = narrow_transposed(w, k, n);
    let packed = (n >= NARROW).then(|| PackedB::new(w, n, 1, k, n));
    y.par_chunks_mut(ROWS_PER_TASK * n)
        .zip(x.par_chunks(ROWS_PER_TASK * k))
        .for_each(|(yc, xc)| {
            let rows = yc.len() / n;
            if let Some(packed) = &packed {
                let bias = Epilogue::Bias { bias: b, relu };
                matmul(xc, LayoutA::Rows { stride: k }, rows, packed, yc, n, bias);
            } else {
                for (yr, xr) in yc.chunks_mut(n).zip(xc.chunks(k)) {
                    for ((o, wj), &bj) in yr.iter_mut().zip(wt.chunks(k)).zip(b) {
                        *o = bj + dot_in_lanes(xr, wj);
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
    /// `[m, k]`.
    pub x: Option<Vec<T>>,
    /// `[k, n]`.
    pub w: Option<Vec<T>>,
    /// `[n]`.
    pub b: Option<Vec<T>>,
}

/// The backward pass of [`forward`] for `dy [m, n]`; `y` is the forward output (read for the
/// ReLU's mask, may be empty for the identity). `need` = which of `[x, w, b]` to compute.
///
/// One parallel pass over blocks of rows ([`rows_per_partial`]: sized by the batch, not by the
/// threads) masks `dy` and sums the blocks' `dW` and `db` (added in block order, so the result
/// does not depend on the number of threads); a second computes `dx`.
pub fn backward<T: Lanes>(
    x: &[T],
    w: &[T],
    y: &[T],
    mut dz: Vec<T>,
    n: usize,
    act: Activation,
    need: [bool; 3],
) -> DenseGrads<T> {
    let [need_x, need_w, need_b] = need;
    let k = rows_of(w, n);
    let m = dz.len() / n.max(1);
    if m == 0 || n == 0 {
        return DenseGrads {
            x: need_x.then(|| vec![T::default(); m * k]),
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
                let xc = &x[r0 * k..(r0 + rows) * k];
                dw = vec![T::zero(); k * n];
                if n < NARROW {
                    // dWᵀ[j] += dz[r, j] · x[r]
                    for (dzr, xr) in dzc.chunks(n).zip(xc.chunks(k.max(1))) {
                        for (j, &g) in dzr.iter().enumerate() {
                            axpy(&mut dw[j * k..(j + 1) * k], g, xr);
                        }
                    }
                    dw = transposed(&dw, n, k);
                } else if k > 0 {
                    // dW = xᵀ·dz, `dz` packed a slice of rows at a time, summed in row order
                    let slices = dzc
                        .chunks(ROWS_PER_PACK * n)
                        .zip(xc.chunks(ROWS_PER_PACK * k));
                    for (s, (dzs, xs)) in slices.enumerate() {
                        let packed = PackedB::new(dzs, n, 1, dzs.len() / n, n);
                        let epilogue = if s == 0 {
                            Epilogue::Store
                        } else {
                            Epilogue::Add
                        };
                        matmul(
                            xs,
                            LayoutA::Cols { stride: k },
                            k,
                            &packed,
                            &mut dw,
                            n,
                            epilogue,
                        );
                    }
                }
            }
            (dw, db)
        })
        .unzip();
    let d_w = need_w.then(|| sum_in_order(&dws, k * n));
    let d_b = need_b.then(|| sum_in_order(&dbs, n));
    let d_x = need_x.then(|| {
        let mut dx = par_zeros(m * k);
        if k == 0 {
            return dx;
        }
        let wt = narrow_transposed(w, k, n);
        // Wᵀ [n, k] packed
        let packed = (n >= NARROW).then(|| PackedB::new(w, 1, n, n, k));
        dx.par_chunks_mut(ROWS_PER_TASK * k)
            .zip(dz.par_chunks(ROWS_PER_TASK * n))
            .for_each(|(dxc, dzc)| {
                if let Some(packed) = &packed {
                    let rows = dzc.len() / n;
                    let layout = LayoutA::Rows { stride: n };
                    matmul(dzc, layout, rows, packed, dxc, k, Epilogue::Store);
                } else {
                    // dx[r] = Σ_j dz[r, j] · W[:, j]
                    for (dxr, dzr) in dxc.chunks_mut(k).zip(dzc.chunks(n)) {
                        for (&g, wj) in dzr.iter().zip(wt.chunks(k)) {
                            axpy(dxr, g, wj);
                        }
                    }
                }
            });
        dx
    });
    DenseGrads {
        x: d_x,
        w: d_w,
        b: d_b,
    }
}

/// `act(layer(x))`: one host operation on flex (with or without autodiff) when the layer has a
/// bias and every tensor is f32 or f64 of one type; Burn's ops otherwise.
pub fn linear(layer: &Linear, x: Tensor<2>, act: Activation) -> Tensor<2> {
    if let Some(bias) = &layer.bias
        && let Some(y) = try_host_linear(&x, &layer.weight.val(), &bias.val(), act)
    {
        return y;
    }
    act.apply(layer.forward(x))
}

/// The host dense layer `act(x·w + b)` when `x`, `w`, `b` are all flex tensors (with autodiff
/// without checkpointing, or plain) of one float type, f32 or f64; `None` otherwise.
#[cfg(feature = "flex")]
pub use flex_op::try_host_linear;

/// Without the flex backend compiled in there is no host path.
#[cfg(not(feature = "flex"))]
pub fn try_host_linear(
    _x: &Tensor<2>,
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

    /// The backward step: inputs (x, weight, bias).
    #[derive(Debug)]
    struct DenseBackward;

    #[derive(Debug, Clone)]
    struct State {
        x: FlexTensor,
        w: FlexTensor,
        /// The output, kept for the ReLU's mask.
        y: Option<FlexTensor>,
        act: Activation,
    }

    fn forward_in<T: Lanes>(
        x: &FlexTensor,
        w: &FlexTensor,
        b: &FlexTensor,
        act: Activation,
    ) -> FlexTensor {
        let m = x.layout().shape()[0];
        let n = w.layout().shape()[1];
        tensor(
            forward(slice::<T>(x), slice(w), slice(b), n, act),
            vec![m, n],
        )
    }

    impl Backward<Flex, 3> for DenseBackward {
        type State = State;

        fn backward(self, ops: Ops<State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
            let dy = contiguous(grads.consume::<Flex>(&ops.node));
            let [px, pw, pb] = ops.parents;
            let need = [px.is_some(), pw.is_some(), pb.is_some()];
            let s = ops.state;
            let [k, n] = [s.w.layout().shape()[0], s.w.layout().shape()[1]];
            let m = s.x.layout().shape()[0];
            let dtype = s.x.dtype();
            let shapes = [vec![m, k], vec![k, n], vec![n]];
            let g = match dtype {
                DType::F64 => grads_in::<f64>(&s, dy, n, need, shapes),
                _ => grads_in::<f32>(&s, dy, n, need, shapes),
            };
            for (parent, grad) in [px, pw, pb].into_iter().zip(g) {
                if let (Some(node), Some(grad)) = (parent, grad) {
                    grads.register::<Flex>(node.id, grad);
                }
            }
        }
    }

    /// The gradients of `[x, w, b]` as flex tensors of the given shapes.
    fn grads_in<T: Lanes>(
        s: &State,
        dy: FlexTensor,
        n: usize,
        need: [bool; 3],
        shapes: [Vec<usize>; 3],
    ) -> [Option<FlexTensor>; 3] {
        let dy: Vec<T> = dy
            .into_data()
            .try_into_vec()
            .expect("dy of the layer's float type");
        let y = s.y.as_ref().map(slice::<T>).unwrap_or(&[]);
        let g = backward(slice::<T>(&s.x), slice(&s.w), y, dy, n, s.act, need);
        let [sx, sw, sb] = shapes;
        [(g.x, sx), (g.w, sw), (g.b, sb)].map(|(v, shape)| v.map(|v| tensor(v, shape)))
    }

    /// See [`super::try_host_linear`].
    pub fn try_host_linear(
        x: &Tensor<2>,
        w: &Tensor<2>,
        b: &Tensor<1>,
        act: Activation,
    ) -> Option<Tensor<2>> {
        let dtype = x.dtype();
        if !matches!(dtype, DType::F32 | DType::F64) || w.dtype() != dtype || b.dtype() != dtype {
            return None;
        }
        let ([_, k], [kw, n], [nb]) = (x.dims(), w.dims(), b.dims());
        if k == 0 || k != kw || n != nb {
            // no inputs, or shapes that do not fit: Burn's `Linear` (and its error)
            return None;
        }
        let run = |x: &FlexTensor, w: &FlexTensor, b: &FlexTensor| match dtype {
            DType::F64 => forward_in::<f64>(x, w, b, act),
            _ => forward_in::<f32>(x, w, b, act),
        };
        if let (Ok(xp), Ok(wp), Ok(bp)) = (
            x.clone().try_into_primitive::<Flex>(),
            w.clone().try_into_primitive::<Flex>(),
            b.clone().try_into_primitive::<Flex>(),
        ) {
            let y = run(&contiguous(xp), &contiguous(wp), &contiguous(bp));
            return Some(Tensor::<2>::from_primitive::<Flex>(y));
        }
        let xa = x.clone().try_into_primitive::<Autodiff<Flex>>().ok()?;
        let wa = w.clone().try_into_primitive::<Autodiff<Flex>>().ok()?;
        let ba = b.clone().try_into_primitive::<Autodiff<Flex>>().ok()?;
        let xp = contiguous(xa.primitive().clone());
        let wp = contiguous(wa.primitive().clone());
        let y = run(&xp, &wp, &contiguous(ba.primitive().clone()));
        let prep = DenseBackward
            .prepare::<NoCheckpointing>([xa.node(), wa.node(), ba.node()])
            .compute_bound()
            .stateful();
        let out = match prep {
            OpsKind::Tracked(prep) => prep.finish(
                State {
                    x: xp,
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
