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
    /// Paths, all computing the same sum:
    /// - features need no gradient (inference, or constant features such as the box normals):
    ///   `G[M, 64·Cin] = S·F` is accumulated on the host, then one matmul `G·K` on the device
    ///   (tracked in K when the kernel is trained);
    /// - features need a gradient: gather/scatter with Burn ops over chunks of output points,
    ///   gather first (`G = S·F`, then `G·K`) or, for narrow outputs (64 → 3), kernel first
    ///   (`H[N, 64·Cout] = F·K`, then gather rows of H).
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
        if !features.is_tracked() && !geometry.weights_tracked() {
            return self.forward_host(features, geometry) + bias;
        }
        let chunks = geometry.chunks();
        let outs: Vec<Tensor<2>> = if gather_first(cin, cout) {
            // gather first: G = S·F per chunk, then G·K
            let k = self.kernel.val().reshape([KERNEL_CELLS * cin, cout]);
            chunks
                .iter()
                .map(|ch| {
                    // one gather per pair, shared by its 8 corners
                    let fp = features.clone().select(0, ch.pair_in_rows.clone());
                    let mut g = Tensor::<2>::zeros([ch.out_len * KERNEL_CELLS, cin], &device);
                    for (rows, w) in ch.corner_out_cell_rows.iter().zip(&ch.corner_weights) {
                        g = g.select_assign(
                            0,
                            rows.clone(),
                            fp.clone() * w.clone(),
                            IndexingUpdateOp::Add,
                        );
                    }
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

    /// Path for features without gradient, by chunks of output points: `G = S·F` accumulated on
    /// the host (rayon, one output row per task), then one matmul `G[M, 64·Cin] · K[64·Cin, Cout]`
    /// on the device; for narrow outputs (64 → 3) `H = F·K` on the device, then the host sums
    /// the weighted rows of H.
    fn forward_host(&self, features: Tensor<2>, geometry: &ConvGeometry) -> Tensor<2> {
        let [n_in, cin] = features.dims();
        let cout = self.out_channels();
        let device = features.device();
        let kernel = self.kernel.val();
        let kernel_dtype = kernel.dtype();
        let host = &geometry.host;
        let m = geometry.num_out();
        let to_vec = |t: Tensor<2>| -> Vec<f32> {
            t.into_data()
                .convert::<f32>()
                .try_into_vec::<f32>()
                .expect("float tensor")
        };
        if !gather_first(cin, cout) && !kernel.is_tracked() {
            let kt = kernel
                .reshape([KERNEL_CELLS, cin, cout])
                .swap_dims(0, 1)
                .reshape([cin, KERNEL_CELLS * cout]);
            let h = to_vec(features.matmul(kt));
            debug_assert_eq!(h.len(), n_in * KERNEL_CELLS * cout);
            let out = scatter_rows_host(host, &h, cout);
            return Tensor::<2>::from_data(TensorData::new(out, [m, cout]), &device)
                .cast(kernel_dtype);
        }
        let feats = to_vec(features);
        let k = kernel.reshape([KERNEL_CELLS * cin, cout]);
        // about 64 MB of G per chunk
        let rows_per_chunk = ((16usize << 20) / (KERNEL_CELLS * cin)).max(1);
        let mut outs = Vec::new();
        let mut q0 = 0;
        while q0 < m {
            let q1 = (q0 + rows_per_chunk).min(m);
            let g = gather_host(host, &feats, cin, q0..q1);
            let g =
                Tensor::<2>::from_data(TensorData::new(g, [q1 - q0, KERNEL_CELLS * cin]), &device)
                    .cast(kernel_dtype);
            outs.push(g.matmul(k.clone()));
            q0 = q1;
        }
        if outs.len() == 1 {
            outs.pop().expect("one chunk")
        } else {
            Tensor::cat(outs, 0)
        }
    }
}

/// `out[m, o] = Σ_{pairs (m, i)} Σ_corners weight · H[i, cell, o]` on the host, for `H = F·K`
/// laid out `[N, 64, Cout]`.
pub fn scatter_rows_host(host: &HostGeometry, h: &[f32], cout: usize) -> Vec<f32> {
    let mut out = vec![0f32; host.num_out * cout];
    let offsets = &host.pairs.offsets;
    let indices = &host.pairs.indices;
    out.par_chunks_mut(cout).enumerate().for_each(|(q, row)| {
        let (p0, p1) = (offsets[q], offsets[q + 1]);
        let corners = host.cells[p0 * CORNERS..p1 * CORNERS]
            .chunks_exact(CORNERS)
            .zip(host.weights[p0 * CORNERS..p1 * CORNERS].chunks_exact(CORNERS));
        for (&i, (cells, weights)) in indices[p0..p1].iter().zip(corners) {
            let base = i as usize * KERNEL_CELLS;
            for (&cell, &w) in cells.iter().zip(weights) {
                let src = &h[(base + cell as usize) * cout..(base + cell as usize + 1) * cout];
                for (d, &x) in row.iter_mut().zip(src) {
                    *d += w * x;
                }
            }
        }
    });
    out
}

/// `G[m, cell·Cin + c] = Σ_{pairs (m, i)} Σ_corners weight · F[i, c]` on the host, for the
/// output points `rows` (the result has `rows.len()` rows).
pub fn gather_host(
    host: &HostGeometry,
    features: &[f32],
    cin: usize,
    rows: std::ops::Range<usize>,
) -> Vec<f32> {
    let row_len = KERNEL_CELLS * cin;
    let mut g = vec![0f32; rows.len() * row_len];
    let offsets = &host.pairs.offsets;
    let indices = &host.pairs.indices;
    let first = rows.start;
    g.par_chunks_mut(row_len).enumerate().for_each(|(r, row)| {
        let q = first + r;
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
