//! The position-dependent part of a continuous convolution, built once per step on the host and
//! shared by every conv over the same point sets (the four fluid→fluid convs of DLF share one,
//! the obstacle conv has its own).
//!
//! Per neighbour pair p = (query m, input i) and trilinear corner c it holds the kernel cell
//! `cell[p,c]` and the weight `window(p) · w_c(Λ(x_i − x_m))`; the convolution is then
//! `out[m] = bias + Σ_p Σ_c weight[p,c] · f_i · K[cell[p,c]]` (spec/dlf.md §2.1).

use std::sync::{Arc, OnceLock};

use burn::prelude::*;
use burn::tensor::DType;
use neurofluid_core::neighbors::{NeighborGrid, PairList};
use neurofluid_core::rows::RowIndex;
use rayon::prelude::*;

use crate::mapping::{
    KERNEL_CELLS, MappingBranches, filter_coordinates, trilinear_corners, window_poly6,
};

/// Corners per pair (trilinear interpolation).
pub const CORNERS: usize = 8;

/// Filter extent (support diameter) of the published DLF model: float32(1.5 · 6 · 0.025).
pub const FILTER_EXTENT: f32 = 0.225;

/// Search radius of a conv with the given extent: 0.5 · extent in float32.
pub fn search_radius(extent: f32) -> f32 {
    0.5 * extent
}

/// Host arrays of a geometry (pair-major: entry `p·8 + c`).
#[derive(Debug, Clone)]
pub struct HostGeometry {
    /// Output (query) points.
    pub num_out: usize,
    /// Input points.
    pub num_in: usize,
    /// Compressed-row pair lists (query → input indices, ascending).
    pub pairs: PairList,
    /// Query index of every pair.
    pub query_of_pair: Vec<u32>,
    /// Flat kernel cell of every pair corner.
    pub cells: Vec<u8>,
    /// Window × trilinear weight of every pair corner.
    pub weights: Vec<f32>,
    /// Mapping branches of every pair (kept for the differentiable geometry).
    pub branches: Vec<MappingBranches>,
    /// Lower trilinear index (x, y, z) of every pair (kept for the differentiable geometry).
    pub lower: Vec<[u8; 3]>,
}

impl HostGeometry {
    /// Neighbour count of every output point.
    pub fn counts(&self) -> Vec<u32> {
        self.pairs.counts()
    }

    /// Number of pairs.
    pub fn num_pairs(&self) -> usize {
        self.pairs.num_pairs()
    }
}

/// Builds the host geometry: fixed-radius search (float32 `d² ≤ R²`, bit-identical points skipped
/// when `ignore_identical`), then per pair the mapping, the corners and the window.
pub fn build_host_geometry(
    inputs: &[[f32; 3]],
    outputs: &[[f32; 3]],
    extent: f32,
    ignore_identical: bool,
    grid: Option<&NeighborGrid<'_>>,
) -> HostGeometry {
    let radius = search_radius(extent);
    let pairs = match grid {
        Some(g) => g.pairs(outputs, radius, ignore_identical),
        None => NeighborGrid::new(inputs, radius).pairs(outputs, radius, ignore_identical),
    };
    let query_of_pair = pairs.query_of_pair();
    let n = pairs.num_pairs();
    let r_sq = radius * radius;
    let two_over_extent = 2.0 * (1.0f32 / extent);
    let mut cells = vec![0u8; n * CORNERS];
    let mut weights = vec![0f32; n * CORNERS];
    let mut branches = vec![MappingBranches::default(); n];
    let mut lower = vec![[0u8; 3]; n];
    const CHUNK: usize = 4096;
    cells
        .par_chunks_mut(CHUNK * CORNERS)
        .zip(weights.par_chunks_mut(CHUNK * CORNERS))
        .zip(branches.par_chunks_mut(CHUNK))
        .zip(lower.par_chunks_mut(CHUNK))
        .enumerate()
        .for_each(|(chunk, (((cells, weights), branches), lower))| {
            let start = chunk * CHUNK;
            for k in 0..branches.len() {
                let p = start + k;
                let q = outputs[query_of_pair[p] as usize];
                let x = inputs[pairs.indices[p] as usize];
                let rel = [x[0] - q[0], x[1] - q[1], x[2] - q[2]];
                let (u, br) = filter_coordinates(rel, two_over_extent);
                let win = window_poly6(pairs.dist2[p] / r_sq);
                for (c, (cell, w)) in trilinear_corners(u).into_iter().enumerate() {
                    cells[k * CORNERS + c] = cell;
                    weights[k * CORNERS + c] = w * win;
                }
                branches[k] = br;
                lower[k] = u.map(|c| crate::mapping::axis_interp(c).0 as u8);
            }
        });
    HostGeometry {
        num_out: outputs.len(),
        num_in: inputs.len(),
        pairs,
        query_of_pair,
        cells,
        weights,
        branches,
        lower,
    }
}

/// Pair corners per chunk of the composed path on a CPU backend: bounds the `[entries, C]`
/// temporaries of the gather/scatter (2^16 · 96 floats = 25 MB for the widest conv: below
/// glibc's largest mmap threshold, so freed blocks are reused instead of page-faulting fresh
/// memory).
pub const HOST_CHUNK_ENTRIES: usize = 1 << 16;

/// Pair corners per chunk on an accelerator (wgpu, CUDA): 2^21 · 96 floats = 0.8 GB for the
/// widest conv's largest temporary. Every chunk costs a few dozen kernel launches, and the
/// features' gradient of each chunk's gather is as long as the whole input, so small chunks
/// made a GPU step launch-bound and super-linear in N (the first H200 run: 172 chunks per conv
/// at 32k particles); a 32k-particle step (11M pair corners) now takes 6.
pub const DEVICE_CHUNK_ENTRIES: usize = 1 << 21;

/// Pair corners per chunk of the composed path on `device`.
pub fn chunk_entries(device: &Device) -> usize {
    if neurofluid_core::device::is_host(device) {
        HOST_CHUNK_ENTRIES
    } else {
        DEVICE_CHUNK_ENTRIES
    }
}

/// The device tensors of a run of consecutive output points (the autodiff path).
#[derive(Debug, Clone)]
pub struct GeometryChunk {
    /// First output point of the chunk.
    pub out_start: usize,
    /// Output points in the chunk.
    pub out_len: usize,
    /// `input·64 + cell` of every pair corner (rows of `F·K` viewed as `[N·64, Cout]`).
    pub in_cell_rows: RowIndex,
    /// Local query index of every pair corner.
    pub out_rows: RowIndex,
    /// Weight of every pair corner `[entries, 1]`; tracked when the geometry is differentiable.
    pub weights: Tensor<2>,
    /// Input index of every pair `[pairs]`.
    pub pair_in_rows: RowIndex,
    /// `local query·64 + cell` of every pair corner (rows of G viewed as `[M·64, Cin]`).
    pub out_cell_rows: RowIndex,
}

/// A geometry ready for [`crate::ContinuousConv`]: the host arrays (used directly by the
/// inference path) and, built on first use, the per-chunk index and weight tensors of the
/// autodiff path.
#[derive(Debug, Clone)]
pub struct ConvGeometry {
    /// The host arrays it was built from (shared with the backward passes that need them).
    pub host: Arc<HostGeometry>,
    /// Differentiable weights `[8P, 1]` (the differentiable-geometry mode), else `None`.
    pub weights_override: Option<Tensor<2>>,
    device: Device,
    chunk_entries: usize,
    chunks: OnceLock<Vec<GeometryChunk>>,
    host_weights: OnceLock<Tensor<2>>,
}

impl ConvGeometry {
    /// Wraps a host geometry; `weights` overrides the host weights (the differentiable path).
    pub fn new(
        host: impl Into<Arc<HostGeometry>>,
        weights: Option<Tensor<2>>,
        device: &Device,
    ) -> Self {
        Self {
            host: host.into(),
            weights_override: weights,
            device: device.clone(),
            chunk_entries: chunk_entries(device),
            chunks: OnceLock::new(),
            host_weights: OnceLock::new(),
        }
    }

    /// The pair-corner weights `[8P, 1]` as a tensor of `dtype`: the override, or the host
    /// weights (uploaded on first call).
    pub fn weights_tensor(&self, dtype: DType) -> Tensor<2> {
        let w = match &self.weights_override {
            Some(w) => w.clone(),
            None => self
                .host_weights
                .get_or_init(|| {
                    let n = self.host.weights.len();
                    neurofluid_core::transfer::upload::<2, burn::tensor::Float, _>(
                        TensorData::new(self.host.weights.clone(), [n, 1]),
                        &self.device,
                    )
                })
                .clone(),
        };
        if w.dtype() == dtype { w } else { w.cast(dtype) }
    }

    /// Whether the weights carry gradients (differentiable geometry on tracked positions).
    pub fn weights_tracked(&self) -> bool {
        self.weights_override
            .as_ref()
            .is_some_and(|w| w.is_tracked())
    }

    /// The same geometry cut into chunks of at most `entries` pair corners (at least one output
    /// point each) instead of the device's [`chunk_entries`]; the sums do not depend on it.
    pub fn with_chunk_entries(mut self, entries: usize) -> Self {
        self.chunk_entries = entries;
        self.chunks = OnceLock::new();
        self
    }

    /// The device chunks (built on first call).
    pub fn chunks(&self) -> &[GeometryChunk] {
        self.chunks.get_or_init(|| self.build_chunks())
    }

    fn build_chunks(&self) -> Vec<GeometryChunk> {
        let host = &self.host;
        let device = &self.device;
        let offsets = &host.pairs.offsets;
        let mut chunks = Vec::new();
        let mut q0 = 0;
        while q0 < host.num_out {
            let mut q1 = q0 + 1;
            while q1 < host.num_out
                && (offsets[q1 + 1] - offsets[q0]) * CORNERS <= self.chunk_entries
            {
                q1 += 1;
            }
            let (p0, p1) = (offsets[q0], offsets[q1]);
            let n8 = (p1 - p0) * CORNERS;
            let mut in_rows = Vec::with_capacity(p1 - p0);
            let mut out_cell_rows = Vec::with_capacity(n8);
            let mut in_cell_rows = Vec::with_capacity(n8);
            let mut out_rows = Vec::with_capacity(n8);
            for p in p0..p1 {
                let q = (host.query_of_pair[p] as usize - q0) as i64;
                let i = host.pairs.indices[p] as i64;
                in_rows.push(i);
                for c in 0..CORNERS {
                    let cell = host.cells[p * CORNERS + c] as i64;
                    out_rows.push(q);
                    out_cell_rows.push(q * KERNEL_CELLS as i64 + cell);
                    in_cell_rows.push(i * KERNEL_CELLS as i64 + cell);
                }
            }
            let int = |v: Vec<i64>| RowIndex::new(v.into_iter().map(|i| i as usize), device);
            let weights = match &self.weights_override {
                Some(w) => w.clone().narrow(0, p0 * CORNERS, n8),
                None => neurofluid_core::transfer::upload::<2, burn::tensor::Float, _>(
                    TensorData::new(host.weights[p0 * CORNERS..p1 * CORNERS].to_vec(), [n8, 1]),
                    device,
                ),
            };
            chunks.push(GeometryChunk {
                pair_in_rows: int(in_rows),
                out_cell_rows: int(out_cell_rows),
                out_start: q0,
                out_len: q1 - q0,
                in_cell_rows: int(in_cell_rows),
                out_rows: int(out_rows),
                weights,
            });
            q0 = q1;
        }
        chunks
    }

    /// Output points.
    pub fn num_out(&self) -> usize {
        self.host.num_out
    }

    /// Input points.
    pub fn num_in(&self) -> usize {
        self.host.num_in
    }

    /// Pair corners (8 per pair).
    pub fn num_entries(&self) -> usize {
        self.host.cells.len()
    }

    /// The device of the tensors.
    pub fn device(&self) -> &Device {
        &self.device
    }
}
