//! The continuous convolution as a Burn module (Open3D `ContinuousConv` with DLF's options).

use burn::module::Param;
use burn::prelude::*;
use burn::tensor::{Distribution, IndexingUpdateOp};

use crate::geometry::ConvGeometry;
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
    /// Two equivalent evaluation orders are used, whichever moves less data:
    /// - Cout > Cin (the layer-0 convs): gather first, `G[M, 64·Cin] = S·F`, then `G·K`;
    /// - Cout ≤ Cin: kernel first, `H[N, 64·Cout] = F·K`, then gather rows of H.
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
        let out = if cout > cin {
            let vals = features.select(0, geometry.in_rows.clone()) * geometry.weights.clone();
            let g = Tensor::<2>::zeros([m * KERNEL_CELLS, cin], &device).select_assign(
                0,
                geometry.out_cell_rows.clone(),
                vals,
                IndexingUpdateOp::Add,
            );
            let k = self.kernel.val().reshape([KERNEL_CELLS * cin, cout]);
            g.reshape([m, KERNEL_CELLS * cin]).matmul(k)
        } else {
            let kt = self
                .kernel
                .val()
                .reshape([KERNEL_CELLS, cin, cout])
                .swap_dims(0, 1)
                .reshape([cin, KERNEL_CELLS * cout]);
            let h = features.matmul(kt).reshape([n_in * KERNEL_CELLS, cout]);
            let vals = h.select(0, geometry.in_cell_rows.clone()) * geometry.weights.clone();
            Tensor::<2>::zeros([m, cout], &device).select_assign(
                0,
                geometry.out_rows.clone(),
                vals,
                IndexingUpdateOp::Add,
            )
        };
        out + bias
    }
}
