//! The continuous convolution `out = Σ_p Σ_c w[p,c] · F[i_p] · K[cell[p,c]]` with its sparse
//! part on the host: on the flex backend (the CPU) all of it, forward and backward, as one
//! operation ([`try_fused_conv`]: [`host_forward`], [`host_backward`], the dense part as the
//! project's matmul); on other devices, for plain features, the sparse part on the host and the
//! dense part as device matmuls ([`conv_forward`]).
//!
//! The composed Burn path (gather, weight, scatter-add) materialises `[pairs, Cin]` temporaries
//! and its backward scatter-adds on one core; this one keeps only `G = T·F` for a chunk of output
//! points (recomputed in the backward pass rather than stored) and scatters the features'
//! gradient into one buffer per worker.

use std::sync::Arc;

use burn::prelude::*;
use burn::tensor::{DType, TensorCreationOptions};
use neurofluid_core::matmul::{Epilogue, Lanes, LayoutA, PackedB, par_matmul};
use neurofluid_core::real::{Real, par_zeros};

use crate::geometry::HostGeometry;
use crate::mapping::KERNEL_CELLS;
use crate::sparse::{self, SparseOp};

/// Elements of `G` per chunk of output points (16 MB in f32: reused heap memory, not fresh
/// pages, under glibc's largest mmap threshold).
const CHUNK_ELEMENTS: usize = 1 << 22;

/// Evaluation order: gather first (`G = T·F`, then `G·K`) unless the output is much narrower
/// than the input (conv3, 64 → 3), where `H = F·K` first moves less data.
pub fn gather_first(cin: usize, cout: usize) -> bool {
    4 * cout >= cin
}

/// Output points per chunk of the gather-first path.
fn rows_per_chunk(cin: usize) -> usize {
    (CHUNK_ELEMENTS / (KERNEL_CELLS * cin)).max(1)
}

/// A tensor's values on the host (no copy when it is contiguous and not shared).
fn host_data(t: Tensor<2>) -> TensorData {
    neurofluid_core::transfer::read_data(t)
}

fn values<T: Real>(data: &TensorData) -> &[T] {
    data.as_slice::<T>()
        .expect("conv tensors share one float type")
}

/// A tensor of `T`'s dtype (`from_data` alone would convert f64 data to the default f32).
fn device_tensor<T: Real>(v: Vec<T>, shape: [usize; 2], device: &Device) -> Tensor<2> {
    neurofluid_core::transfer::upload(
        TensorData::new(v, shape),
        TensorCreationOptions::new(device.clone()).with_dtype(T::dtype()),
    )
}

/// `[Cin, 64·Cout]` view of the kernel `[64·Cin, Cout]` (rows `cell·Cin + c`).
fn kernel_by_input(kernel: Tensor<2>, cin: usize) -> Tensor<2> {
    let cout = kernel.dims()[1];
    kernel
        .reshape([KERNEL_CELLS, cin, cout])
        .swap_dims(0, 1)
        .reshape([cin, KERNEL_CELLS * cout])
}

/// The conv without bias: `features [N, Cin]` (untracked), pair-corner `weights [8P, 1]`
/// (untracked), `kernel [64·Cin, Cout]` → `[M, Cout]`, gather first (`gather`) or kernel first,
/// in the features' float type (f64, else f32). With gather first, a tracked kernel keeps its
/// gradient (the last matmul is a device op).
pub fn conv_forward(
    host: &HostGeometry,
    features: Tensor<2>,
    weights: &TensorData,
    kernel: Tensor<2>,
    gather: bool,
) -> Tensor<2> {
    match features.dtype() {
        DType::F64 => conv_forward_in::<f64>(host, features, weights, kernel, gather),
        _ => conv_forward_in::<f32>(host, features, weights, kernel, gather),
    }
}

fn conv_forward_in<T: Real>(
    host: &HostGeometry,
    features: Tensor<2>,
    weights: &TensorData,
    kernel: Tensor<2>,
    gather: bool,
) -> Tensor<2> {
    let weights = values::<T>(weights);
    let [_, cin] = features.dims();
    let cout = kernel.dims()[1];
    let device = features.device();
    let m = host.num_out;
    if !gather {
        let h = host_data(features.matmul(kernel_by_input(kernel, cin)));
        return device_tensor(
            SparseOp::new(host, weights).contract(values(&h), cout),
            [m, cout],
            &device,
        );
    }
    let f = host_data(features);
    let f = values::<T>(&f);
    let step = rows_per_chunk(cin);
    let outs: Vec<Tensor<2>> = (0..m)
        .step_by(step)
        .map(|q0| {
            let rows = q0..(q0 + step).min(m);
            let len = rows.len();
            let g = SparseOp::new(host, weights).gather(f, cin, rows);
            device_tensor(g, [len, KERNEL_CELLS * cin], &device).matmul(kernel.clone())
        })
        .collect();
    Tensor::cat(outs, 0)
}

/// `[Cin, 64·Cout]` copy of the host kernel `[64·Cin, Cout]` (`Kt[c, cell·Cout + o]`).
fn kernel_by_input_host<T: Real>(kernel: &[T], cin: usize, cout: usize) -> Vec<T> {
    let mut kt = vec![T::zero(); kernel.len()];
    for (cell, block) in kernel.chunks(cin * cout).enumerate() {
        for (c, row) in block.chunks(cout).enumerate() {
            kt[c * KERNEL_CELLS * cout + cell * cout..][..cout].copy_from_slice(row);
        }
    }
    kt
}

/// The conv without bias on the host: `features [N, Cin]`, pair-corner weights `[8P]`,
/// `kernel [64·Cin, Cout]` → `[M, Cout]`, in the order [`gather_first`] picks, with the dense
/// part as the project's matmul split over threads.
pub fn host_forward<T: Lanes>(
    op: SparseOp<'_, T>,
    features: &[T],
    cin: usize,
    kernel: &[T],
    cout: usize,
) -> Vec<T> {
    let m = op.host.num_out;
    if m == 0 || cout == 0 {
        return vec![T::zero(); m * cout];
    }
    if !gather_first(cin, cout) {
        let kt = kernel_by_input_host(kernel, cin, cout);
        return op.contract(&features_times(features, cin, &kt), cout);
    }
    let row_len = KERNEL_CELLS * cin;
    let packed = PackedB::new(kernel, cout, 1, row_len, cout);
    let mut out = vec![T::zero(); m * cout];
    let step = rows_per_chunk(cin);
    for (c, out_c) in out.chunks_mut(step * cout).enumerate() {
        let rows = c * step..c * step + out_c.len() / cout;
        let len = rows.len();
        let g = op.gather(features, cin, rows);
        let layout = LayoutA::Rows { stride: row_len };
        par_matmul(&g, layout, len, &packed, out_c, cout, Epilogue::Store);
    }
    out
}

/// `H = F·Kt` `[N, 64·Cout]` for `features [N, Cin]`, `kt [Cin, 64·Cout]`.
fn features_times<T: Lanes>(features: &[T], cin: usize, kt: &[T]) -> Vec<T> {
    let width = kt.len() / cin.max(1);
    let n = features.len() / cin.max(1);
    let mut h = par_zeros(n * width);
    let packed = PackedB::new(kt, width, 1, cin, width);
    let layout = LayoutA::Rows { stride: cin };
    par_matmul(features, layout, n, &packed, &mut h, width, Epilogue::Store);
    h
}

/// Gradients of the conv (without bias), each only when asked for: features `[N, Cin]`,
/// pair-corner weights `[8P]`, kernel `[64·Cin, Cout]`.
pub struct HostConvGrads<T> {
    /// `[N, Cin]`.
    pub features: Option<Vec<T>>,
    /// `[8P]`.
    pub weights: Option<Vec<T>>,
    /// `[64·Cin, Cout]`.
    pub kernel: Option<Vec<T>>,
}

/// The backward pass of [`host_forward`] for `d_out [M, Cout]`; `need` = which of
/// `[features, weights, kernel]` to compute. The kernel's and the weights' gradients are summed
/// in an order fixed by the sizes; the features' in one buffer per worker thread.
pub fn host_backward<T: Lanes>(
    op: SparseOp<'_, T>,
    features: &[T],
    cin: usize,
    kernel: &[T],
    cout: usize,
    d_out: &[T],
    need: [bool; 3],
) -> HostConvGrads<T> {
    let [need_f, need_w, need_k] = need;
    let n = features.len() / cin.max(1);
    let m = op.host.num_out;
    let row_len = KERNEL_CELLS * cin;
    let mut d_weights = need_w.then(|| vec![T::zero(); op.weights.len()]);
    if !gather_first(cin, cout) {
        let kt = kernel_by_input_host(kernel, cin, cout);
        let width = KERNEL_CELLS * cout;
        let h = need_w.then(|| features_times(features, cin, &kt));
        let mut accs = sparse::accumulators::<T>(need_f || need_k, n * width);
        op.contract_transpose(
            h.as_deref(),
            d_out,
            cout,
            &mut accs,
            d_weights.as_deref_mut(),
        );
        let d_h = (!accs.is_empty()).then(|| sparse::sum_accumulators(accs));
        let d_features = need_f.then(|| {
            // dF = dH·Ktᵀ
            let d_h = d_h.as_deref().expect("dH");
            let mut d_f = vec![T::zero(); n * cin];
            let kt_t = PackedB::new(&kt, 1, width, width, cin);
            let layout = LayoutA::Rows { stride: width };
            par_matmul(d_h, layout, n, &kt_t, &mut d_f, cin, Epilogue::Store);
            d_f
        });
        let d_kernel = need_k.then(|| {
            // dKt = Fᵀ·dH, then back to [64·Cin, Cout]
            let d_h = d_h.as_deref().expect("dH");
            let mut d_kt = vec![T::zero(); cin * width];
            let packed = PackedB::new(d_h, width, 1, n, width);
            let layout = LayoutA::Cols { stride: cin };
            par_matmul(
                features,
                layout,
                cin,
                &packed,
                &mut d_kt,
                width,
                Epilogue::Store,
            );
            let mut d_k = vec![T::zero(); kernel.len()];
            for (c, row) in d_kt.chunks(width).enumerate() {
                for (cell, v) in row.chunks(cout).enumerate() {
                    d_k[(cell * cin + c) * cout..][..cout].copy_from_slice(v);
                }
            }
            d_k
        });
        return HostConvGrads {
            features: d_features,
            weights: d_weights,
            kernel: d_kernel,
        };
    }
    let mut accs = sparse::accumulators::<T>(need_f, n * cin);
    let mut d_kernel = need_k.then(|| vec![T::zero(); kernel.len()]);
    // Kᵀ [Cout, 64·Cin] packed, for dG = dOut·Kᵀ
    let kt = (need_f || need_w).then(|| PackedB::new(kernel, 1, cout, cout, row_len));
    let step = rows_per_chunk(cin);
    for q0 in (0..m).step_by(step) {
        let rows = q0..(q0 + step).min(m);
        let len = rows.len();
        let d_out_c = &d_out[q0 * cout..(q0 + len) * cout];
        if let Some(d_k) = d_kernel.as_deref_mut() {
            // dK += Gᵀ·dOut, chunk after chunk
            let g = op.gather(features, cin, rows.clone());
            let packed = PackedB::new(d_out_c, cout, 1, len, cout);
            let epilogue = if q0 == 0 {
                Epilogue::Store
            } else {
                Epilogue::Add
            };
            let layout = LayoutA::Cols { stride: row_len };
            par_matmul(&g, layout, row_len, &packed, d_k, cout, epilogue);
        }
        if let Some(kt) = &kt {
            let mut d_g = par_zeros(len * row_len);
            let layout = LayoutA::Rows { stride: cout };
            par_matmul(d_out_c, layout, len, kt, &mut d_g, row_len, Epilogue::Store);
            op.gather_transpose(
                features,
                &d_g,
                cin,
                rows,
                &mut accs,
                d_weights.as_deref_mut(),
            );
        }
    }
    HostConvGrads {
        features: need_f.then(|| sparse::sum_accumulators(accs)),
        weights: d_weights,
        kernel: d_kernel,
    }
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
    use neurofluid_core::flex_host::{contiguous, slice, tensor};

    /// The backward step: inputs (features, weights, kernel).
    #[derive(Debug)]
    struct FusedConvBackward;

    #[derive(Debug, Clone)]
    struct State {
        host: Arc<HostGeometry>,
        features: FlexTensor,
        weights: FlexTensor,
        kernel: FlexTensor,
    }

    /// `(N, Cin, Cout)` of the state's features and kernel.
    fn sizes(features: &FlexTensor, kernel: &FlexTensor) -> (usize, usize, usize) {
        let [n, cin] = [features.layout().shape()[0], features.layout().shape()[1]];
        (n, cin, kernel.layout().shape()[1])
    }

    fn forward_in<T: Lanes>(s: &State) -> FlexTensor {
        let (_, cin, cout) = sizes(&s.features, &s.kernel);
        let op = SparseOp::new(&s.host, slice::<T>(&s.weights));
        let out = host_forward(op, slice(&s.features), cin, slice(&s.kernel), cout);
        tensor(out, vec![s.host.num_out, cout])
    }

    fn backward_in<T: Lanes>(
        s: &State,
        d_out: &FlexTensor,
        need: [bool; 3],
    ) -> [Option<FlexTensor>; 3] {
        let (n, cin, cout) = sizes(&s.features, &s.kernel);
        let op = SparseOp::new(&s.host, slice::<T>(&s.weights));
        let (f, k) = (slice(&s.features), slice(&s.kernel));
        let g = host_backward(op, f, cin, k, cout, slice(d_out), need);
        [
            g.features.map(|v| tensor(v, vec![n, cin])),
            g.weights
                .map(|v| tensor(v, vec![s.weights.layout().shape()[0], 1])),
            g.kernel.map(|v| tensor(v, vec![KERNEL_CELLS * cin, cout])),
        ]
    }

    impl Backward<Flex, 3> for FusedConvBackward {
        type State = State;

        fn backward(self, ops: Ops<State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
            let d_out = contiguous(grads.consume::<Flex>(&ops.node));
            let [pf, pw, pk] = ops.parents;
            let need = [pf.is_some(), pw.is_some(), pk.is_some()];
            let s = ops.state;
            let g = match s.features.dtype() {
                DType::F64 => backward_in::<f64>(&s, &d_out, need),
                _ => backward_in::<f32>(&s, &d_out, need),
            };
            for (parent, grad) in [pf, pw, pk].into_iter().zip(g) {
                if let (Some(node), Some(grad)) = (parent, grad) {
                    grads.register::<Flex>(node.id, grad);
                }
            }
        }
    }

    /// See [`super::try_fused_conv`].
    pub fn try_fused_conv(
        host: &Arc<HostGeometry>,
        features: &Tensor<2>,
        weights: impl FnOnce() -> Tensor<2>,
        kernel: &Tensor<2>,
    ) -> Option<Tensor<2>> {
        let dtype = features.dtype();
        if !matches!(dtype, DType::F32 | DType::F64) || kernel.dtype() != dtype {
            return None;
        }
        let run = |s: &State| match dtype {
            DType::F64 => forward_in::<f64>(s),
            _ => forward_in::<f32>(s),
        };
        let state = |f: FlexTensor, w: FlexTensor, k: FlexTensor| State {
            host: host.clone(),
            features: contiguous(f),
            weights: contiguous(w),
            kernel: contiguous(k),
        };
        if let (Ok(f), Ok(k)) = (
            features.clone().try_into_primitive::<Flex>(),
            kernel.clone().try_into_primitive::<Flex>(),
        ) {
            let weights = weights();
            if weights.dtype() != dtype {
                return None;
            }
            let w = weights.try_into_primitive::<Flex>().ok()?;
            let out = run(&state(f, w, k));
            return Some(Tensor::<2>::from_primitive::<Flex>(out));
        }
        let f = features
            .clone()
            .try_into_primitive::<Autodiff<Flex>>()
            .ok()?;
        let k = kernel.clone().try_into_primitive::<Autodiff<Flex>>().ok()?;
        let weights = weights();
        if weights.dtype() != dtype {
            return None;
        }
        let w = weights.try_into_primitive::<Autodiff<Flex>>().ok()?;
        let s = state(
            f.primitive().clone(),
            w.primitive().clone(),
            k.primitive().clone(),
        );
        let out = run(&s);
        let prep = FusedConvBackward
            .prepare::<NoCheckpointing>([f.node(), w.node(), k.node()])
            .compute_bound()
            .stateful();
        let result = match prep {
            OpsKind::Tracked(prep) => prep.finish(s, out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        };
        Some(Tensor::<2>::from_primitive::<Autodiff<Flex>>(result))
    }
}

/// The conv (no bias) as one host operation ([`host_forward`], with [`host_backward`] as its
/// backward pass under autodiff) when the features and the kernel are flex tensors (plain, or
/// with autodiff without checkpointing) of one float type, f32 or f64; `None` otherwise (the
/// caller takes another path). `weights` (`[8P, 1]`) is made only then.
#[cfg(feature = "flex")]
pub use flex_op::try_fused_conv;

/// Without the flex backend compiled in there is no fused path.
#[cfg(not(feature = "flex"))]
pub fn try_fused_conv(
    _host: &Arc<HostGeometry>,
    _features: &Tensor<2>,
    _weights: impl FnOnce() -> Tensor<2>,
    _kernel: &Tensor<2>,
) -> Option<Tensor<2>> {
    None
}
