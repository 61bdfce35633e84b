//! The position-dependent part of a continuous convolution, built once per step on the host and
//! shared by every conv over the same point sets (the four fluid→fluid convs of DLF share one,
//! the obstacle conv has its own).
//!
//! Per neighbour pair p = (query m, input i) and trilinear corner c it holds the kernel cell
//! `cell[p,c]` and the weight `window(p) · w_c(Λ(x_i − x_m))`; the convolution is then
//! `out[m] = bias + Σ_p Σ_c weight[p,c] · f_i · K[cell[p,c]]` (docs/spec/dlf.md §2.1).

use std::sync::{Arc, OnceLock};

use burn::prelude::*;
use burn::tensor::DType;
use burn::tensor::Float;
use neurofluid_core::device_pairs::{DevicePairs, plan_chunks};
use neurofluid_core::neighbors::{NeighborGrid, PairList};
use neurofluid_core::rows::{RowIndex, gather_rows};
use neurofluid_core::transfer::upload;
use rayon::prelude::*;

use crate::device_cells::slot_cell_weights;
use crate::diff_geometry::{Branches, pair_weights};
use crate::mapping::{
    KERNEL_CELLS, KERNEL_SIZE, MappingBranches, filter_coordinates, trilinear_corners, window_poly6,
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

/// Neighbour slots per chunk of the padded path on a CPU backend: bounds its largest
/// temporaries (the slots' kernel-cell weights, 2^14 · 64 floats; the gathered features, 2^14 · 96)
/// below glibc's largest mmap threshold, so freed blocks are reused instead of page-faulting fresh
/// memory.
pub const HOST_CHUNK_SLOTS: usize = 1 << 14;

/// Neighbour slots per chunk on an accelerator (wgpu, CUDA): 2^20 slots' kernel-cell weights are
/// 2^26 floats (256 MB in f32), the widest conv's `G` about as much; a 32k-particle step (about 50
/// neighbours each) takes two chunks. Every chunk costs a few kernel launches. Fewer where the
/// device allocates less in one buffer ([`SLOT_BYTES`]).
pub const DEVICE_CHUNK_SLOTS: usize = 1 << 20;

/// The largest bytes a chunk's temporaries hold per slot: the kernel-first conv (64 → 3) gathers
/// `H`'s rows of 64 cells × 3 outputs for every slot (192 f32), more than the cell weights (64)
/// or the widest gathered features (96).
pub const SLOT_BYTES: u64 = 192 * 4;

/// Neighbour slots per chunk of the padded path on `device`: [`HOST_CHUNK_SLOTS`] on a CPU
/// backend, else [`DEVICE_CHUNK_SLOTS`] or as many as the device's largest buffer holds at
/// [`SLOT_BYTES`] each (Mesa's lavapipe binds at most 128 MiB: 174,762 slots; an NVIDIA
/// driver through Vulkan, gigabytes).
pub fn chunk_slots(device: &Device) -> usize {
    if neurofluid_core::device::is_host(device) {
        return HOST_CHUNK_SLOTS;
    }
    let fits = neurofluid_core::device::max_buffer_bytes(device)
        .map_or(usize::MAX, |bytes| (bytes / SLOT_BYTES).max(1) as usize);
    DEVICE_CHUNK_SLOTS.min(fits)
}

/// A run of consecutive output points with their neighbours in `width` slots each (the run's
/// largest neighbour count; the slots past a point's count are padding), as device tensors: the
/// conv over the chunk is then dense, `G[m] = Wᵀ[m] · F[inputs[m]]` as one batched matmul, with no
/// scatter and no atomic adds.
#[derive(Debug, Clone)]
pub struct GeometryChunk {
    /// First output point of the chunk.
    pub out_start: usize,
    /// Output points in the chunk.
    pub out_len: usize,
    /// Neighbour slots per output point.
    pub width: usize,
    /// Input row of every slot `[out_len · width]` (a padding slot's is a real row, with zero
    /// weight).
    pub inputs: RowIndex,
    /// Weight of every slot on every kernel cell `[out_len · width, 64]`: the sum of its pair's
    /// corner weights on that cell, zero on padding; tracked when the geometry is differentiable.
    pub cell_weights: Tensor<2>,
}

/// A geometry ready for [`crate::ContinuousConv`]: the host arrays (used directly by the
/// inference path) and, built on first use, the per-chunk index and weight tensors of the
/// autodiff path; or, in slots on the GPU ([`ConvGeometry::on_device`]), the chunks alone.
#[derive(Debug, Clone)]
pub struct ConvGeometry {
    /// The host arrays it was built from (shared with the backward passes that need them);
    /// `None` for a geometry built on the device.
    pub host: Option<Arc<HostGeometry>>,
    /// Differentiable weights `[8P, 1]` (the differentiable-geometry mode), else `None`.
    pub weights_override: Option<Tensor<2>>,
    device: Device,
    chunk_slots: usize,
    chunks: OnceLock<Vec<GeometryChunk>>,
    host_weights: OnceLock<Tensor<2>>,
    counts: Arc<[u32]>,
    num_in: usize,
    tracked: bool,
}

impl ConvGeometry {
    /// Wraps a host geometry; `weights` overrides the host weights (the differentiable path).
    pub fn new(
        host: impl Into<Arc<HostGeometry>>,
        weights: Option<Tensor<2>>,
        device: &Device,
    ) -> Self {
        let host: Arc<HostGeometry> = host.into();
        Self {
            counts: host.counts().into(),
            num_in: host.num_in,
            tracked: weights.as_ref().is_some_and(|w| w.is_tracked()),
            host: Some(host),
            weights_override: weights,
            device: device.clone(),
            chunk_slots: chunk_slots(device),
            chunks: OnceLock::new(),
            host_weights: OnceLock::new(),
        }
    }

    /// The geometry of `pairs` in slots on the GPU ([`neurofluid_core::device_pairs`]: found
    /// there or by the host's grid), with the input and output positions `[N_in, 3]`, `[M, 3]` on
    /// that device: each chunk's slots gathered, their relative positions mapped to kernel-cell
    /// weights with the branches found from the values, the padding's weights zeroed — one kernel
    /// with its own backward on the cubecl backends ([`slot_cell_weights`]), else the tensor ops
    /// ([`pair_weights`]). Differentiable in the positions where they are tracked (the gathers'
    /// gradients by the pairs' symmetric kernel for the fluid's pairs; the box's points are
    /// constant). Without pairs it has no chunks (a conv over it gives its bias, and a padding
    /// slot could name a row of an empty point set).
    pub fn on_device(
        pairs: DevicePairs,
        inputs: Tensor<2>,
        outputs: Tensor<2>,
        extent: f32,
    ) -> Self {
        let device = outputs.device();
        let tracked = inputs.is_tracked() || outputs.is_tracked();
        let no_pairs = pairs.num_pairs() == 0;
        let chunks: Vec<GeometryChunk> = pairs
            .chunks
            .iter()
            .filter(|_| !no_pairs)
            .enumerate()
            .map(|(c, ch)| {
                let (m, width) = (ch.q1 - ch.q0, ch.width);
                let index = pairs.chunk_index(c);
                let queries = outputs
                    .clone()
                    .narrow(0, ch.q0, m)
                    .unsqueeze_dim::<3>(1)
                    .expand([m, width, 3])
                    .reshape([m * width, 3]);
                let rel = gather_rows(inputs.clone(), &index) - queries;
                let real = pairs.real.clone().narrow(0, ch.start, ch.len());
                let cells = slot_cell_weights(&rel, &real, extent).unwrap_or_else(|| {
                    let (corners, lower) = pair_weights(rel, extent, Branches::Values);
                    cell_weights(corners * real, lower)
                });
                GeometryChunk {
                    out_start: ch.q0,
                    out_len: m,
                    width,
                    inputs: index,
                    cell_weights: cells,
                }
            })
            .collect();
        Self {
            host: None,
            weights_override: None,
            device: device.clone(),
            chunk_slots: pairs.chunks.iter().map(|c| c.len()).max().unwrap_or(0),
            chunks: OnceLock::from(chunks),
            host_weights: OnceLock::new(),
            counts: pairs.counts.into(),
            num_in: pairs.num_in,
            tracked,
        }
    }

    /// The host arrays.
    ///
    /// # Panics
    /// For a geometry built on the device (a programming error: only the host paths ask).
    pub fn host(&self) -> &Arc<HostGeometry> {
        self.host
            .as_ref()
            .expect("a geometry built on the device has no host arrays")
    }

    /// The pair-corner weights `[8P, 1]` as a tensor of `dtype`: the override, or the host
    /// weights (uploaded on first call).
    pub fn weights_tensor(&self, dtype: DType) -> Tensor<2> {
        let w = match &self.weights_override {
            Some(w) => w.clone(),
            None => self
                .host_weights
                .get_or_init(|| {
                    let weights = &self.host().weights;
                    neurofluid_core::transfer::upload::<2, burn::tensor::Float, _>(
                        TensorData::new(weights.clone(), [weights.len(), 1]),
                        &self.device,
                    )
                })
                .clone(),
        };
        if w.dtype() == dtype { w } else { w.cast(dtype) }
    }

    /// Whether the weights carry gradients (differentiable geometry on tracked positions).
    pub fn weights_tracked(&self) -> bool {
        self.tracked
    }

    /// The same geometry cut into chunks of at most `slots` neighbour slots (at least one output
    /// point each) instead of the device's [`chunk_slots`]; the sums do not depend on it. A host
    /// geometry only.
    pub fn with_chunk_slots(mut self, slots: usize) -> Self {
        assert!(
            self.host.is_some(),
            "a geometry built on the device keeps its chunks"
        );
        self.chunk_slots = slots;
        self.chunks = OnceLock::new();
        self
    }

    /// The device chunks (built on first call).
    pub fn chunks(&self) -> &[GeometryChunk] {
        self.chunks.get_or_init(|| self.build_chunks())
    }

    fn build_chunks(&self) -> Vec<GeometryChunk> {
        plan_chunks(&self.counts, self.chunk_slots)
            .into_iter()
            .map(|ch| self.padded_chunk(ch.q0, ch.q1, ch.width))
            .collect()
    }

    /// The chunk of output points `q0..q1` in `width` slots each. The padding slots repeat their
    /// point's pairs in turn (a point without pairs: pairs picked by its index) with zero weight,
    /// so their terms are exact zeros and the gathers' gradients have no row that collects many
    /// padding slots (one zero row for every padding slot made a sum of 10⁵ rows, which the
    /// device ran serially: 12–29 ms per gather at 8k particles on an H100).
    fn padded_chunk(&self, q0: usize, q1: usize, width: usize) -> GeometryChunk {
        let host = self.host();
        let device = &self.device;
        let offsets = &host.pairs.offsets;
        let slots = (q1 - q0) * width;
        let num_pairs = host.num_pairs();
        // the pair in every slot, and whether it is the slot's own (not padding)
        let mut pair = vec![0usize; slots];
        let mut real = vec![false; slots];
        for q in q0..q1 {
            let (a, b) = (offsets[q], offsets[q + 1]);
            let row = (q - q0) * width;
            for k in 0..width {
                (pair[row + k], real[row + k]) = match b - a {
                    0 => ((q + k) % num_pairs, false),
                    c => (a + k % c, k < c),
                };
            }
        }
        let inputs = RowIndex::new(pair.iter().map(|&p| host.pairs.indices[p] as usize), device);
        let corner_weights = match &self.weights_override {
            Some(w) => {
                let dtype = w.dtype();
                let w = w.clone().reshape([num_pairs, CORNERS]);
                let real: Vec<f32> = real.iter().map(|&r| f32::from(u8::from(r))).collect();
                let real = upload::<2, Float, _>(TensorData::new(real, [slots, 1]), device);
                gather_rows(w, &RowIndex::new(pair.clone(), device)) * real.cast(dtype)
            }
            None => {
                let mut w = vec![0f32; slots * CORNERS];
                for (slot, &p) in pair.iter().enumerate().filter(|&(slot, _)| real[slot]) {
                    w[slot * CORNERS..][..CORNERS]
                        .copy_from_slice(&host.weights[p * CORNERS..][..CORNERS]);
                }
                upload::<2, Float, _>(TensorData::new(w, [slots, CORNERS]), device)
            }
        };
        let lower: Vec<f32> = pair
            .iter()
            .flat_map(|&p| host.lower[p].map(f32::from))
            .collect();
        let lower = upload::<2, Float, _>(TensorData::new(lower, [slots, 3]), device);
        GeometryChunk {
            out_start: q0,
            out_len: q1 - q0,
            width,
            inputs,
            cell_weights: cell_weights(corner_weights, lower),
        }
    }

    /// Output points.
    pub fn num_out(&self) -> usize {
        self.counts.len()
    }

    /// Input points.
    pub fn num_in(&self) -> usize {
        self.num_in
    }

    /// Neighbour count of every output point.
    pub fn counts(&self) -> Vec<u32> {
        self.counts.to_vec()
    }

    /// Pairs.
    pub fn num_pairs(&self) -> usize {
        self.counts.iter().map(|&c| c as usize).sum()
    }

    /// Pair corners (8 per pair).
    pub fn num_entries(&self) -> usize {
        self.num_pairs() * CORNERS
    }

    /// The device of the tensors.
    pub fn device(&self) -> &Device {
        &self.device
    }
}

/// `[S, 64]` kernel-cell weights of slots with trilinear corner weights `[S, 8]` (z outer, x
/// inner, as [`crate::mapping::trilinear_corners`]) and lower corners `[S, 3]` (x, y, z, as
/// floats): corner `(dz, dy, dx)` lies in cell `(min(z + dz, 3), min(y + dy, 3), min(x + dx, 3))`,
/// and corners in one cell add up. Float ops only (a one-hot by comparison), so it runs and
/// differentiates the same on every backend.
pub fn cell_weights(corner_weights: Tensor<2>, lower: Tensor<2>) -> Tensor<2> {
    let [slots, _] = corner_weights.dims();
    let device = corner_weights.device();
    let dtype = corner_weights.dtype();
    let top = (KERNEL_SIZE - 1) as f32;
    let axis = |a: usize, step: f32| (lower.clone().narrow(1, a, 1) + step).clamp_max(top);
    let cells: Vec<f32> = (0..KERNEL_CELLS).map(|c| c as f32).collect();
    let cells = upload::<2, Float, _>(TensorData::new(cells, [1, KERNEL_CELLS]), &device)
        .expand([slots, KERNEL_CELLS]);
    let k = KERNEL_SIZE as f32;
    let mut out = Tensor::<2>::zeros([slots, KERNEL_CELLS], (&device, dtype));
    let mut corner = 0;
    for dz in [0.0, 1.0] {
        for dy in [0.0, 1.0] {
            for dx in [0.0, 1.0] {
                let cell = (axis(2, dz) * k + axis(1, dy)) * k + axis(0, dx);
                let hit = cell.expand([slots, KERNEL_CELLS]).equal(cells.clone());
                let w = corner_weights.clone().narrow(1, corner, 1);
                out = out + hit.float().cast(dtype) * w;
                corner += 1;
            }
        }
    }
    out
}
