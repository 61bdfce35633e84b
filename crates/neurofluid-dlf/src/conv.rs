//! The continuous convolution as a Burn module (Open3D `ContinuousConv` with DLF's options).

use burn::module::Param;
use burn::prelude::*;
use burn::tensor::Distribution;
use neurofluid_core::rows::gather_rows;

use crate::fused;
use crate::geometry::{ConvGeometry, GeometryChunk};
use crate::mapping::{KERNEL_CELLS, KERNEL_SIZE};

/// A continuous convolution: kernel `[4, 4, 4, Cin, Cout]` indexed `[z, y, x, ..]`, bias `[Cout]`.
///
/// Parameter names (`kernel`, `bias`) match the PyTorch/Open3D state dict. The `offset` buffer of
/// Open3D's layer is always zero in DLF and is not stored (the weight loader checks it is zero).
#[derive(Module, Debug)]
pub struct ContinuousConv {
    /// Kernel `[kz, ky, kx, Cin, Cout]`.
    pub kernel: Param<Tensor<5>>,
    /// Bias `[Cout]`.
    pub bias: Param<Tensor<1>>,
}

impl ContinuousConv {
    /// A new conv with Open3D's default initialisation: kernel U(−0.05, 0.05), zero bias.
    pub fn new(in_channels: usize, out_channels: usize, device: &Device) -> Self {
        let k = KERNEL_SIZE;
        let kernel = Tensor::<5>::random(
            [k, k, k, in_channels, out_channels],
            Distribution::Uniform(-0.05, 0.05),
            device,
        );
        Self {
            kernel: Param::from_tensor(kernel),
            bias: Param::from_tensor(Tensor::zeros([out_channels], device)),
        }
    }

    /// A conv whose kernel and bias are zeros, to load weights into: it draws no random number
    /// (building with [`ContinuousConv::new`] would advance the backend's RNG).
    pub fn zeros(in_channels: usize, out_channels: usize, device: &Device) -> Self {
        let k = KERNEL_SIZE;
        Self {
            kernel: Param::from_tensor(Tensor::zeros([k, k, k, in_channels, out_channels], device)),
            bias: Param::from_tensor(Tensor::zeros([out_channels], device)),
        }
    }

    /// Input channels.
    pub fn in_channels(&self) -> usize {
        self.kernel.dims()[3]
    }

    /// Output channels.
    pub fn out_channels(&self) -> usize {
        self.kernel.dims()[4]
    }

    /// Applies the conv: `features` `[N_in, Cin]` at the geometry's input points → `[M, Cout]`.
    ///
    /// Paths, all computing the same sum:
    /// - flex with autodiff: one fused operation with its own backward pass
    ///   ([`crate::fused::try_fused_conv`]);
    /// - another CPU backend, features and weights without gradient (inference, or constant
    ///   features such as the box normals): the sparse part on the host, the dense part as
    ///   matmuls (tracked in K when the kernel is trained) ([`crate::fused::conv_forward`]);
    /// - otherwise (an accelerator, or gradients to the features or the weights): gathers and
    ///   batched matmuls over padded chunks of output points, on the device
    ///   ([`Self::forward_composed`]).
    pub fn forward(&self, features: Tensor<2>, geometry: &ConvGeometry) -> Tensor<2> {
        let [n_in, cin] = features.dims();
        let cout = self.out_channels();
        assert_eq!(cin, self.in_channels(), "conv input channels");
        assert_eq!(n_in, geometry.num_in(), "conv input points");
        let m = geometry.num_out();
        let device = features.device();
        let bias = self.bias.val().unsqueeze_dim::<2>(0);
        if geometry.num_entries() == 0 {
            // No pairs: the output is the bias. The kernel still gets a (zero) gradient, as
            // Open3D's op returns one, so optimiser state evolves the same way.
            let zero_kernel = self.kernel.val().sum().reshape([1, 1]) * 0.0;
            return Tensor::<2>::zeros([m, cout], &device) + bias + zero_kernel;
        }
        let kernel = self.kernel.val().reshape([KERNEL_CELLS * cin, cout]);
        let dtype = features.dtype();
        let weights = || geometry.weights_tensor(dtype);
        let Some(host) = geometry.host.as_ref() else {
            // in slots on the GPU: the chunks only
            return self.forward_composed(features, geometry) + bias;
        };
        if let Some(out) = fused::try_fused_conv(host, &features, weights, &kernel) {
            return out + bias;
        }
        let on_host = neurofluid_core::device::is_host(&device);
        if on_host && !features.is_tracked() && !geometry.weights_tracked() {
            // the kernel-first order would cut K's gradient at the host
            let gather_first = fused::gather_first(cin, cout) || kernel.is_tracked();
            // the host weights as they are (no device round trip) unless overridden
            let weights = match &geometry.weights_override {
                Some(w) => neurofluid_core::transfer::read_data(w.clone()),
                None => TensorData::new(host.weights.clone(), [geometry.num_entries(), 1]),
            }
            .convert_dtype(dtype);
            let out = fused::conv_forward(host, features, &weights, kernel, gather_first);
            return out + bias;
        }
        self.forward_composed(features, geometry) + bias
    }

    /// The conv (without bias) built from Burn ops over the geometry's padded chunks
    /// ([`crate::geometry::GeometryChunk`]): per output point `m`, its neighbours' rows gathered
    /// into `width` slots and contracted with the slots' kernel-cell weights `W[m]` as batched
    /// matmuls; gather first (`G[m] = W[m]ᵀ · F[slots]`, then `G · K`) or, for narrow outputs
    /// (64 → 3), kernel first (`H = F · K` for every cell, then `W[m] · H[slots]`). No scatter: the
    /// only sum into rows is the gather's gradient, in the fixed order of [`gather_rows`]. Any
    /// backend, any tracking.
    pub fn forward_composed(&self, features: Tensor<2>, geometry: &ConvGeometry) -> Tensor<2> {
        let [_, cin] = features.dims();
        let cout = self.out_channels();
        let dtype = features.dtype();
        if geometry.num_entries() == 0 {
            return Tensor::<2>::zeros([geometry.num_out(), cout], (&features.device(), dtype));
        }
        let cell_weights = |ch: &GeometryChunk| {
            let w = ch.cell_weights.clone();
            if w.dtype() == dtype { w } else { w.cast(dtype) }
        };
        let chunks = geometry.chunks();
        let outs: Vec<Tensor<2>> = if fused::gather_first(cin, cout) {
            let k = self.kernel.val().reshape([KERNEL_CELLS * cin, cout]);
            chunks
                .iter()
                .map(|ch| {
                    let (m, width) = (ch.out_len, ch.width);
                    let f = gather_rows(features.clone(), &ch.inputs).reshape([m, width, cin]);
                    let w = cell_weights(ch).reshape([m, width, KERNEL_CELLS]);
                    w.swap_dims(1, 2)
                        .matmul(f)
                        .reshape([m, KERNEL_CELLS * cin])
                        .matmul(k.clone())
                })
                .collect()
        } else {
            let kt = self
                .kernel
                .val()
                .reshape([KERNEL_CELLS, cin, cout])
                .swap_dims(0, 1)
                .reshape([cin, KERNEL_CELLS * cout]);
            let h = features.matmul(kt);
            chunks
                .iter()
                .map(|ch| {
                    let (m, width) = (ch.out_len, ch.width);
                    let h =
                        gather_rows(h.clone(), &ch.inputs).reshape([m, width * KERNEL_CELLS, cout]);
                    cell_weights(ch)
                        .reshape([m, 1, width * KERNEL_CELLS])
                        .matmul(h)
                        .reshape([m, cout])
                })
                .collect()
        };
        if outs.len() == 1 {
            outs.into_iter().next().expect("one chunk")
        } else {
            Tensor::cat(outs, 0)
        }
    }
}
