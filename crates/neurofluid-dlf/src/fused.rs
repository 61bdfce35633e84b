//! The continuous convolution `out = Σ_p Σ_c w[p,c] · F[i_p] · K[cell[p,c]]` evaluated on the
//! host in one pass, forward and backward: [`conv_forward`] for any device's plain tensors and,
//! on the flex backend with autodiff, [`try_fused_conv`], one autodiff operation with its own
//! backward pass (features, weights and kernel gradients).
//!
//! The composed Burn path (gather, weight, scatter-add) materialises `[pairs, Cin]` temporaries
//! and its backward scatter-adds on one core; this one keeps only `G = T·F` for a chunk of output
//! points (recomputed in the backward pass rather than stored), scatters the features' gradient
//! into one buffer per worker and does the dense part as matmuls.

use std::sync::Arc;

use burn::prelude::*;
use burn::tensor::{DType, TensorCreationOptions};
use neurofluid_core::real::Real;

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
    t.into_data()
}

fn values<T: Real>(data: &TensorData) -> &[T] {
    data.as_slice::<T>()
        .expect("conv tensors share one float type")
}

/// A tensor of `T`'s dtype (`from_data` alone would convert f64 data to the default f32).
fn device_tensor<T: Real>(v: Vec<T>, shape: [usize; 2], device: &Device) -> Tensor<2> {
    Tensor::<2>::from_data(
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

/// Gradients of the conv (without bias) for `d_out [M, Cout]`; each only when asked for.
struct ConvGrads {
    features: Option<Tensor<2>>,
    weights: Option<Tensor<2>>,
    kernel: Option<Tensor<2>>,
}

/// The backward pass of [`conv_forward`] on plain tensors.
fn conv_backward<T: Real>(
    host: &HostGeometry,
    features: Tensor<2>,
    weights: &TensorData,
    kernel: Tensor<2>,
    d_out: Tensor<2>,
    need: [bool; 3],
) -> ConvGrads {
    let weights = values::<T>(weights);
    let [need_f, need_w, need_k] = need;
    let [n, cin] = features.dims();
    let cout = kernel.dims()[1];
    let device = features.device();
    let m = host.num_out;
    let op = SparseOp::new(host, weights);
    let mut d_weights = need_w.then(|| vec![T::default(); weights.len()]);
    if !gather_first(cin, cout) {
        let kt = kernel_by_input(kernel, cin);
        let h = need_w.then(|| host_data(features.clone().matmul(kt.clone())));
        let mut accs = sparse::accumulators::<T>(need_f || need_k, n * KERNEL_CELLS * cout);
        op.contract_transpose(
            h.as_ref().map(values),
            values(&host_data(d_out)),
            cout,
            &mut accs,
            d_weights.as_deref_mut(),
        );
        let d_h = (!accs.is_empty()).then(|| {
            device_tensor(
                sparse::sum_accumulators(accs),
                [n, KERNEL_CELLS * cout],
                &device,
            )
        });
        let d_features = need_f.then(|| {
            let d_h = d_h.clone().expect("dH");
            d_h.matmul(kt.transpose())
        });
        let d_kernel = need_k.then(|| {
            features
                .transpose()
                .matmul(d_h.expect("dH"))
                .reshape([cin, KERNEL_CELLS, cout])
                .swap_dims(0, 1)
                .reshape([KERNEL_CELLS * cin, cout])
        });
        return ConvGrads {
            features: d_features,
            weights: d_weights.map(|v| device_tensor(v, [weights.len(), 1], &device)),
            kernel: d_kernel,
        };
    }
    let f = host_data(features);
    let f = values::<T>(&f);
    let kt = kernel.transpose();
    let mut accs = sparse::accumulators::<T>(need_f, n * cin);
    let mut d_kernel: Option<Tensor<2>> = None;
    let step = rows_per_chunk(cin);
    for q0 in (0..m).step_by(step) {
        let rows = q0..(q0 + step).min(m);
        let len = rows.len();
        let d_out_c = d_out.clone().narrow(0, q0, len);
        if need_k {
            let g = op.gather(f, cin, rows.clone());
            let g = device_tensor(g, [len, KERNEL_CELLS * cin], &device);
            let dk = g.transpose().matmul(d_out_c.clone());
            d_kernel = Some(match d_kernel {
                Some(acc) => acc + dk,
                None => dk,
            });
        }
        if need_f || need_w {
            let d_g = host_data(d_out_c.matmul(kt.clone()));
            op.gather_transpose(
                f,
                values(&d_g),
                cin,
                rows,
                &mut accs,
                d_weights.as_deref_mut(),
            );
        }
    }
    ConvGrads {
        features: need_f.then(|| device_tensor(sparse::sum_accumulators(accs), [n, cin], &device)),
        weights: d_weights.map(|v| device_tensor(v, [weights.len(), 1], &device)),
        kernel: d_kernel,
    }
}

#[cfg(feature = "flex")]
mod flex_autodiff {
    use super::*;
    use burn::backend::autodiff::checkpoint::base::Checkpointer;
    use burn::backend::autodiff::checkpoint::strategy::NoCheckpointing;
    use burn::backend::autodiff::grads::Gradients;
    use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
    use burn::backend::{Autodiff, Flex};

    type Primitive = <Flex as burn::backend::BackendTypes>::FloatTensorPrimitive;

    /// The backward step: inputs (features, weights, kernel).
    #[derive(Debug)]
    struct FusedConvBackward;

    #[derive(Debug, Clone)]
    struct State {
        host: Arc<HostGeometry>,
        features: Primitive,
        /// The weights on the host, read once in the forward pass.
        weights: Arc<TensorData>,
        kernel: Primitive,
    }

    fn plain(p: Primitive) -> Tensor<2> {
        Tensor::<2>::from_primitive::<Flex>(p)
    }

    fn primitive(t: Tensor<2>) -> Primitive {
        t.try_into_primitive::<Flex>().expect("a plain flex tensor")
    }

    impl Backward<Flex, 3> for FusedConvBackward {
        type State = State;

        fn backward(self, ops: Ops<State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
            let d_out = plain(grads.consume::<Flex>(&ops.node));
            let [pf, pw, pk] = ops.parents;
            let need = [pf.is_some(), pw.is_some(), pk.is_some()];
            let s = ops.state;
            let features = plain(s.features);
            let kernel = plain(s.kernel);
            let w = &s.weights;
            let g = match features.dtype() {
                DType::F64 => conv_backward::<f64>(&s.host, features, w, kernel, d_out, need),
                _ => conv_backward::<f32>(&s.host, features, w, kernel, d_out, need),
            };
            for (parent, grad) in [(pf, g.features), (pw, g.weights), (pk, g.kernel)] {
                if let (Some(node), Some(grad)) = (parent, grad) {
                    grads.register::<Flex>(node.id, primitive(grad));
                }
            }
        }
    }

    /// The fused conv when the features, the weights (made by `weights` only then) and the
    /// kernel all live on flex with autodiff (no checkpointing) and are f32 or f64; `None`
    /// otherwise (the caller takes the composed path).
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
        let (fp, wp, kp) = (
            f.primitive().clone(),
            w.primitive().clone(),
            k.primitive().clone(),
        );
        let [_, cin] = features.dims();
        let order = gather_first(cin, kernel.dims()[1]);
        let w_data = Arc::new(host_data(plain(wp)));
        let out = conv_forward(host, plain(fp.clone()), &w_data, plain(kp.clone()), order);
        let out = primitive(out);
        let prep = FusedConvBackward
            .prepare::<NoCheckpointing>([f.node(), w.node(), k.node()])
            .compute_bound()
            .stateful();
        let result = match prep {
            OpsKind::Tracked(prep) => prep.finish(
                State {
                    host: host.clone(),
                    features: fp,
                    weights: w_data,
                    kernel: kp,
                },
                out,
            ),
            OpsKind::UnTracked(prep) => prep.finish(out),
        };
        Some(Tensor::<2>::from_primitive::<Autodiff<Flex>>(result))
    }
}

/// The fused conv (no bias) when the tensors live on flex with autodiff; `None` otherwise.
#[cfg(feature = "flex")]
pub use flex_autodiff::try_fused_conv;

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
