//! The continuous convolution as a Burn module (Open3D `ContinuousConv` with DLF's options).

use burn::module::Param;
use burn::prelude::*;
use burn::tensor::{Distribution, IndexingUpdateOp};

use rayon::prelude::*;

use crate::geometry::{CORNERS, ConvGeometry, HostGeometry};
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
        let needs_grad = features.is_require_grad()
            || self.kernel.val().is_require_grad()
            || geometry.weights_tracked();
        if !needs_grad {
            return self.forward_host(features, geometry) + bias;
        }
        let chunks = geometry.chunks();
        let outs: Vec<Tensor<2>> = if gather_first(cin, cout) {
            // gather first: G = S·F per chunk, then G·K
            let k = self.kernel.val().reshape([KERNEL_CELLS * cin, cout]);
            chunks
                .iter()
                .map(|ch| {
                    let vals = features.clone().select(0, ch.in_rows.clone()) * ch.weights.clone();
                    let g = Tensor::<2>::zeros([ch.out_len * KERNEL_CELLS, cin], &device)
                        .select_assign(0, ch.out_cell_rows.clone(), vals, IndexingUpdateOp::Add);
                    g.reshape([ch.out_len, KERNEL_CELLS * cin])
                        .matmul(k.clone())
                })
                .collect()
        } else {
            // kernel first: H = F·K (all cells), then gather the rows of H
            let kt = self
                .kernel
                .val()
                .reshape([KERNEL_CELLS, cin, cout])
                .swap_dims(0, 1)
                .reshape([cin, KERNEL_CELLS * cout]);
            let h = features.matmul(kt).reshape([n_in * KERNEL_CELLS, cout]);
            chunks
                .iter()
                .map(|ch| {
                    let vals = h.clone().select(0, ch.in_cell_rows.clone()) * ch.weights.clone();
                    Tensor::<2>::zeros([ch.out_len, cout], &device).select_assign(
                        0,
                        ch.out_rows.clone(),
                        vals,
                        IndexingUpdateOp::Add,
                    )
                })
                .collect()
        };
        let out = if outs.len() == 1 {
            outs.into_iter().next().expect("one chunk")
        } else {
            Tensor::cat(outs, 0)
        };
        out + bias
    }

    /// Inference path (no gradients needed): `G = S·F` is accumulated on the host (rayon, one
    /// output row per task), then one matmul `G[M, 64·Cin] · K[64·Cin, Cout]` on the device.
    fn forward_host(&self, features: Tensor<2>, geometry: &ConvGeometry) -> Tensor<2> {
        let [_, cin] = features.dims();
        let cout = self.out_channels();
        let device = features.device();
        let feats: Vec<f32> = features
            .into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .expect("float features");
        let g = gather_host(&geometry.host, &feats, cin);
        let m = geometry.num_out();
        let g = Tensor::<2>::from_data(TensorData::new(g, [m, KERNEL_CELLS * cin]), &device);
        g.matmul(self.kernel.val().reshape([KERNEL_CELLS * cin, cout]))
    }
}

/// `G[m, cell·Cin + c] = Σ_{pairs (m, i)} Σ_corners weight · F[i, c]` on the host.
pub fn gather_host(host: &HostGeometry, features: &[f32], cin: usize) -> Vec<f32> {
    let row_len = KERNEL_CELLS * cin;
    let mut g = vec![0f32; host.num_out * row_len];
    let offsets = &host.pairs.offsets;
    let indices = &host.pairs.indices;
    g.par_chunks_mut(row_len).enumerate().for_each(|(q, row)| {
        let (p0, p1) = (offsets[q], offsets[q + 1]);
        let corners = host.cells[p0 * CORNERS..p1 * CORNERS]
            .chunks_exact(CORNERS)
            .zip(host.weights[p0 * CORNERS..p1 * CORNERS].chunks_exact(CORNERS));
        for (&i, (cells, weights)) in indices[p0..p1].iter().zip(corners) {
            let i = i as usize;
            let f = &features[i * cin..(i + 1) * cin];
            for (&cell, &w) in cells.iter().zip(weights) {
                let cell = cell as usize;
                let dst = &mut row[cell * cin..(cell + 1) * cin];
                for (d, &x) in dst.iter_mut().zip(f) {
                    *d += w * x;
                }
            }
        }
    });
    g
}

/// Evaluation order of the autodiff path: gather first (`G = S·F`, then `G·K`) unless the
/// output is much narrower than the input (conv3, 64 → 3), where `F·K` first moves less data.
fn gather_first(cin: usize, cout: usize) -> bool {
    4 * cout >= cin
}
