//! Fixed-radius neighbour pairs found on the GPU and left there, in padded slots: DLF's search
//! (every input point with float32 `d² ≤ r²` of each query, ascending by index, bit-identical
//! points skipped where asked) without the pairs ever passing through the host.
//!
//! The host bins the input points into a uniform grid (a counting sort, O(N), from the host
//! copy of the positions a step has anyway) and uploads them in cell order. Two kernels follow,
//! one thread per query, each scanning the 3×3×3 cells around its query: the first counts the
//! pairs (read back: the chunks' widths are planned from them on the host, and DLF's loss needs
//! the counts); the second writes each query's inputs into its `width` slots in ascending
//! order (insertion), the padding slots repeating its own pairs in turn (a query without pairs:
//! inputs picked by its index), and a `[S, 1]` column of ones for its own pairs, zeros for the
//! padding. The layout is [`plan_chunks`]'s, the host path's.
//!
//! The gradient of gathering rows through the slots, where the pairs are symmetric (inputs and
//! queries one point set, as DLF's fluid–fluid pairs), is a third kernel: the row of input `i`
//! sums, over `i`'s own neighbours `q` in ascending order, the slot of `q` that holds `i` (a
//! binary search in `q`'s sorted slots), in a fixed order and with no atomic adds. The padding
//! slots' rows are left out: their weights are zero, so their gradients are.
//!
//! Pairs found by the host's grid go into the same slots ([`device_pairs_from_host`]: the host
//! writes the layout and uploads it), so that a GPU step's geometry has one form whichever
//! search found its pairs.

use std::sync::Arc;

use burn::prelude::*;

use crate::rows::{RowIndex, RowSum};

/// A run of consecutive queries `q0..q1` with `width` slots each, from slot `start` on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SlotChunk {
    /// First query.
    pub q0: usize,
    /// One past the last query.
    pub q1: usize,
    /// Slots per query (the run's largest pair count, at least 1).
    pub width: usize,
    /// The chunk's first slot among all chunks' slots.
    pub start: usize,
}

impl SlotChunk {
    /// Slots in the chunk.
    pub fn len(&self) -> usize {
        (self.q1 - self.q0) * self.width
    }

    /// Whether the chunk has no slot (never, for a chunk of [`plan_chunks`]).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Cuts the queries, with `counts[q]` pairs each, into runs of at most `max_slots` slots (at
/// least one query per run), each as wide as its largest count.
pub fn plan_chunks(counts: &[u32], max_slots: usize) -> Vec<SlotChunk> {
    let count = |q: usize| counts[q] as usize;
    let mut chunks = Vec::new();
    let (mut q0, mut start) = (0, 0);
    while q0 < counts.len() {
        let mut width = count(q0).max(1);
        let mut q1 = q0 + 1;
        while q1 < counts.len() {
            let wider = width.max(count(q1));
            if (q1 + 1 - q0) * wider > max_slots {
                break;
            }
            width = wider;
            q1 += 1;
        }
        let chunk = SlotChunk {
            q0,
            q1,
            width,
            start,
        };
        start += chunk.len();
        chunks.push(chunk);
        q0 = q1;
    }
    chunks
}

/// The pairs of a search, in slots on the device.
#[derive(Debug, Clone)]
pub struct DevicePairs {
    /// Pairs of every query (read back).
    pub counts: Vec<u32>,
    /// The slots' layout.
    pub chunks: Vec<SlotChunk>,
    /// Input points.
    pub num_in: usize,
    /// The input row in every slot `[S]` (int32).
    pub slots: Tensor<1, Int>,
    /// 1 for a slot holding its query's own pair, 0 for padding `[S, 1]`.
    pub real: Tensor<2>,
    /// The symmetric gradient's kernel, where the pairs are symmetric.
    symmetric: Option<Arc<dyn RowSumOfChunk>>,
}

impl DevicePairs {
    /// Pairs in all.
    pub fn num_pairs(&self) -> usize {
        self.counts.iter().map(|&c| c as usize).sum()
    }

    /// The input rows of chunk `c`'s slots as an index for [`crate::rows::gather_rows`]: its
    /// gradient by the symmetric kernel where the pairs are symmetric, else by a plan from a
    /// copy read back.
    pub fn chunk_index(&self, c: usize) -> RowIndex {
        let ch = self.chunks[c];
        let tensor = self.slots.clone().narrow(0, ch.start, ch.len());
        let transpose = self.symmetric.as_ref().map(|s| {
            Arc::new(ChunkTranspose {
                kernel: s.clone(),
                chunk: ch,
            }) as Arc<dyn RowSum>
        });
        RowIndex::on_device(tensor, transpose)
    }
}

/// The symmetric gradient of one chunk's gather, by a kernel that knows every chunk's slots.
trait RowSumOfChunk: std::fmt::Debug + Send + Sync {
    fn sum_chunk(&self, values: Tensor<2>, n: usize, chunk: SlotChunk) -> Option<Tensor<2>>;
}

#[derive(Debug)]
struct ChunkTranspose {
    kernel: Arc<dyn RowSumOfChunk>,
    chunk: SlotChunk,
}

impl RowSum for ChunkTranspose {
    fn sum_into(&self, values: Tensor<2>, n: usize) -> Option<Tensor<2>> {
        self.kernel.sum_chunk(values, n, self.chunk)
    }
}

/// The pairs of `queries` among `points` within `radius` (float32 `d² ≤ r²`; bit-identical
/// points skipped with `ignore_identical`), in slots of [`plan_chunks`] with `max_slots`, on
/// `device`'s GPU; `symmetric` when `points` and `queries` are one point set (the gradient's
/// kernel then serves the gathers). `None` where the device is not a cubecl device.
///
/// # Errors
/// When the device fails to run a kernel or to read the counts back.
pub fn device_pairs(
    device: &Device,
    points: &[[f32; 3]],
    queries: &[[f32; 3]],
    radius: f32,
    ignore_identical: bool,
    symmetric: bool,
    max_slots: usize,
) -> Option<Result<DevicePairs, String>> {
    #[cfg(feature = "gpu")]
    {
        let cube = crate::cube_tensor::cube_device(device)?;
        Some(kernel::run(
            &cube,
            points,
            queries,
            radius,
            ignore_identical,
            symmetric,
            max_slots,
        ))
    }
    #[cfg(not(feature = "gpu"))]
    {
        let _ = (
            device,
            points,
            queries,
            radius,
            ignore_identical,
            symmetric,
            max_slots,
        );
        None
    }
}

/// The pairs of a search made on the host (`pairs`: each query's inputs ascending, as
/// [`crate::neighbors::NeighborGrid::pairs`] gives them, among `num_in` input points) in the
/// slots [`device_pairs`] writes — the same layout, padding and gradient kernel — uploaded to
/// `device`'s GPU. `None` where the device is not a cubecl device.
///
/// # Errors
/// When a row of `pairs` is not ascending or names an input past `num_in`.
pub fn device_pairs_from_host(
    device: &Device,
    pairs: &crate::neighbors::PairList,
    num_in: usize,
    symmetric: bool,
    max_slots: usize,
) -> Option<Result<DevicePairs, String>> {
    #[cfg(feature = "gpu")]
    {
        let cube = crate::cube_tensor::cube_device(device)?;
        Some(kernel::from_host(
            &cube, pairs, num_in, symmetric, max_slots,
        ))
    }
    #[cfg(not(feature = "gpu"))]
    {
        let _ = (device, pairs, num_in, symmetric, max_slots);
        None
    }
}

/// The uniform grid of the input points: cell size a little above the radius (so that every
/// pair lies in neighbouring cells under float rounding), grown where the points spread so
/// far that the cells would outnumber `MAX_CELLS`; the points' positions and indices in cell
/// order (a stable counting sort: ascending index within a cell) and each cell's first point.
#[cfg(feature = "gpu")]
#[derive(Debug)]
struct Grid {
    lo: [f32; 3],
    inv_cell: f32,
    dims: [u32; 3],
    sorted: Vec<f32>,
    order: Vec<i32>,
    starts: Vec<u32>,
}

#[cfg(feature = "gpu")]
const MAX_CELLS: f64 = (1 << 22) as f64;

#[cfg(feature = "gpu")]
impl Grid {
    fn new(points: &[[f32; 3]], radius: f32) -> Self {
        let (lo, hi) = crate::neighbors::bounding_box(points);
        let span = |a: usize| f64::from(hi[a] - lo[a]).max(0.0);
        let mut cell = f64::from(radius) * (1.0 + 1e-4);
        let cells = |c: f64| (0..3).map(|a| (span(a) / c).floor() + 1.0).product::<f64>();
        while cells(cell) > MAX_CELLS {
            cell *= 1.25;
        }
        let inv_cell = (1.0 / cell) as f32;
        let dims = [0, 1, 2].map(|a| ((span(a) / cell).floor() as u32 + 1).max(1));
        let coord = |p: [f32; 3], a: usize| {
            (((p[a] - lo[a]) * inv_cell).floor().max(0.0) as u32).min(dims[a] - 1)
        };
        let cell_of =
            |p: [f32; 3]| ((coord(p, 2) * dims[1] + coord(p, 1)) * dims[0] + coord(p, 0)) as usize;
        let n_cells = (dims[0] * dims[1] * dims[2]) as usize;
        let (starts, order) =
            crate::neighbors::counting_sort(points, n_cells, |p| Some(cell_of(p)));
        Self {
            lo,
            inv_cell,
            dims,
            sorted: order.iter().flat_map(|&i| points[i as usize]).collect(),
            order: order.into_iter().map(|i| i as i32).collect(),
            starts,
        }
    }
}

#[cfg(feature = "gpu")]
mod kernel {
    use std::sync::Arc;

    use burn::prelude::Tensor as BurnTensor;
    use cubecl::calculate_cube_count_elemwise;
    use cubecl::prelude::*;
    use cubecl::server::Handle;
    use cubecl::std::tensor::TensorHandle;
    use rayon::prelude::*;

    use super::{DevicePairs, Grid, RowSumOfChunk, SlotChunk, plan_chunks};
    use crate::cube_tensor;
    use crate::transfer::{count_read, count_upload};

    /// The first cell to scan along an axis: the query's cell less one, clamped to the grid.
    #[cube]
    fn scan_first(v: f32, lo: f32, inv_cell: f32) -> u32 {
        let c = f32::floor((v - lo) * inv_cell) - 1.0;
        let mut first = 0u32;
        if c > 0.0 {
            first = u32::cast_from(c);
        }
        first
    }

    /// One past the last cell to scan along an axis: the query's cell plus two, clamped.
    #[cube]
    fn scan_end(v: f32, lo: f32, inv_cell: f32, dim: u32) -> u32 {
        let c = f32::floor((v - lo) * inv_cell) + 2.0;
        let mut end = 0u32;
        if c > 0.0 {
            end = u32::cast_from(c);
        }
        if end > dim {
            end = dim;
        }
        end
    }

    /// The cells a query scans: `x0..x1`, `y0..y1`, `z0..z1` (its own cell's neighbours, clamped
    /// to the grid; `x0 ≤ x1 ≤ dims_x`, so that `starts[row + x0..=row + x1]` stays in the row),
    /// with the grid's row lengths.
    #[derive(CubeType, Clone, Copy)]
    struct CellScan {
        x0: u32,
        x1: u32,
        y0: u32,
        y1: u32,
        z0: u32,
        z1: u32,
        dims_x: u32,
        dims_y: u32,
    }

    /// The cells around `(qx, qy, qz)` in `grid`: its lowest corner, the inverse cell size and
    /// the cells along each axis.
    #[cube]
    fn cell_scan(qx: f32, qy: f32, qz: f32, grid: &Tensor<f32>) -> CellScan {
        let dims_x = u32::cast_from(grid[4]);
        let dims_y = u32::cast_from(grid[5]);
        let mut x0 = scan_first(qx, grid[0], grid[3]);
        let mut x1 = scan_end(qx, grid[0], grid[3], dims_x);
        if x0 > dims_x {
            x0 = dims_x;
        }
        if x1 < x0 {
            x1 = x0;
        }
        CellScan {
            x0,
            x1,
            y0: scan_first(qy, grid[1], grid[3]),
            y1: scan_end(qy, grid[1], grid[3], dims_y),
            z0: scan_first(qz, grid[2], grid[3]),
            z1: scan_end(qz, grid[2], grid[3], u32::cast_from(grid[6])),
            dims_x,
            dims_y,
        }
    }

    /// Whether input `j` (in cell order) pairs with the query at `(qx, qy, qz)`: `d² ≤ r²` with
    /// `d = point − query` as the host computes it, and not bit-identical where asked.
    #[cube]
    fn pairs_with(
        points: &Tensor<f32>,
        j: usize,
        qx: f32,
        qy: f32,
        qz: f32,
        r2: f32,
        #[comptime] ignore_identical: bool,
    ) -> bool {
        let px = points[j * 3];
        let py = points[j * 3 + 1];
        let pz = points[j * 3 + 2];
        let mut ok = true;
        if comptime![ignore_identical] {
            let same = u32::reinterpret(px) == u32::reinterpret(qx)
                && u32::reinterpret(py) == u32::reinterpret(qy)
                && u32::reinterpret(pz) == u32::reinterpret(qz);
            ok = !same;
        }
        let dx = px - qx;
        let dy = py - qy;
        let dz = pz - qz;
        ok && dx * dx + dy * dy + dz * dz <= r2
    }

    /// The pair count of every query.
    #[allow(clippy::too_many_arguments)]
    #[cube(launch)]
    fn count_pairs(
        points: &Tensor<f32>,
        starts: &Tensor<u32>,
        queries: &Tensor<f32>,
        counts: &mut Tensor<u32>,
        grid: &Tensor<f32>,
        n_queries: usize,
        r2: f32,
        #[comptime] ignore_identical: bool,
    ) {
        let q = ABSOLUTE_POS;
        if q < n_queries {
            let qx = queries[q * 3];
            let qy = queries[q * 3 + 1];
            let qz = queries[q * 3 + 2];
            let scan = cell_scan(qx, qy, qz, grid);
            let mut count = 0u32;
            for z in scan.z0..scan.z1 {
                for y in scan.y0..scan.y1 {
                    let row = (z * scan.dims_y + y) * scan.dims_x;
                    let first = usize::cast_from(starts[usize::cast_from(row + scan.x0)]);
                    let last = usize::cast_from(starts[usize::cast_from(row + scan.x1)]);
                    for j in first..last {
                        if pairs_with(points, j, qx, qy, qz, r2, ignore_identical) {
                            count += 1;
                        }
                    }
                }
            }
            counts[q] = count;
        }
    }

    /// Every query's inputs in its slots, ascending, then its padding; see the module docs.
    #[allow(clippy::too_many_arguments)]
    #[cube(launch)]
    fn fill_slots(
        points: &Tensor<f32>,
        order: &Tensor<i32>,
        starts: &Tensor<u32>,
        queries: &Tensor<f32>,
        layout: &Tensor<u32>,
        slots: &mut Tensor<i32>,
        real: &mut Tensor<f32>,
        grid: &Tensor<f32>,
        n_queries: usize,
        n_points: u32,
        r2: f32,
        #[comptime] ignore_identical: bool,
    ) {
        let q = ABSOLUTE_POS;
        if q < n_queries {
            // layout: count, first slot, width of every query
            let count = layout[q * 3];
            let s0 = usize::cast_from(layout[q * 3 + 1]);
            let width = layout[q * 3 + 2];
            let qx = queries[q * 3];
            let qy = queries[q * 3 + 1];
            let qz = queries[q * 3 + 2];
            let scan = cell_scan(qx, qy, qz, grid);
            let mut n = 0u32;
            for z in scan.z0..scan.z1 {
                for y in scan.y0..scan.y1 {
                    let row = (z * scan.dims_y + y) * scan.dims_x;
                    let first = usize::cast_from(starts[usize::cast_from(row + scan.x0)]);
                    let last = usize::cast_from(starts[usize::cast_from(row + scan.x1)]);
                    for j in first..last {
                        if n < count && pairs_with(points, j, qx, qy, qz, r2, ignore_identical) {
                            let i = order[j];
                            let mut at = usize::cast_from(n);
                            loop {
                                if at == 0 {
                                    break;
                                }
                                let prev = slots[s0 + at - 1];
                                if prev <= i {
                                    break;
                                }
                                slots[s0 + at] = prev;
                                at -= 1;
                            }
                            slots[s0 + at] = i;
                            n += 1;
                        }
                    }
                }
            }
            for k in 0..width {
                let at = s0 + usize::cast_from(k);
                if k < n {
                    real[at] = 1.0;
                } else {
                    real[at] = 0.0;
                    if n > 0 {
                        slots[at] = slots[s0 + usize::cast_from(k % n)];
                    } else {
                        slots[at] = i32::cast_from((u32::cast_from(q) + k) % n_points);
                    }
                }
            }
        }
    }

    /// The symmetric gradient of one chunk's gather: row `i` of `out` (column `col`) sums the
    /// chunk's rows of `dy` whose slot holds `i`, over `i`'s neighbours in ascending order.
    #[allow(clippy::too_many_arguments)]
    #[cube(launch)]
    fn symmetric_transpose(
        dy: &Tensor<f32>,
        slots: &Tensor<i32>,
        layout: &Tensor<u32>,
        out: &mut Tensor<f32>,
        n_rows: usize,
        cols: usize,
        q0: u32,
        q1: u32,
        chunk_start: u32,
    ) {
        let pos = ABSOLUTE_POS;
        if pos < n_rows * cols {
            let i = pos / cols;
            let col = pos % cols;
            let count = layout[i * 3];
            let s_i = usize::cast_from(layout[i * 3 + 1]);
            let target = i32::cast_from(i);
            let mut acc = 0.0f32;
            for t in 0..count {
                let q = u32::cast_from(slots[s_i + usize::cast_from(t)]);
                if q >= q0 && q < q1 {
                    let qs = usize::cast_from(q);
                    let c_q = layout[qs * 3];
                    let s_q = layout[qs * 3 + 1];
                    // the first of q's sorted slots not below i
                    let mut lo = 0u32;
                    let mut hi = c_q;
                    loop {
                        if lo >= hi {
                            break;
                        }
                        let mid = (lo + hi) / 2;
                        if slots[usize::cast_from(s_q + mid)] < target {
                            lo = mid + 1;
                        } else {
                            hi = mid;
                        }
                    }
                    if lo < c_q && slots[usize::cast_from(s_q + lo)] == target {
                        let row = usize::cast_from(s_q + lo - chunk_start);
                        acc += dy[row * cols + col];
                    }
                }
            }
            out[pos] = acc;
        }
    }

    fn f32s(h: &Handle, len: usize) -> TensorArg {
        cube_tensor::f32_arg(h, len)
    }

    fn u32s(h: &Handle, len: usize) -> TensorArg {
        cube_tensor::arg(h, len, u32::elem_type_native())
    }

    fn i32s(h: &Handle, len: usize) -> TensorArg {
        cube_tensor::arg(h, len, i32::elem_type_native())
    }

    /// Uploads `values` to `device`, counted.
    fn upload<T: bytemuck::Pod>(device: &cubecl::Device, values: &[T]) -> Handle {
        let bytes: &[u8] = bytemuck::cast_slice(values);
        count_upload(bytes.len());
        device.client().create_from_slice(bytes)
    }

    /// The symmetric gradient's kernel over every chunk's slots.
    #[derive(Debug)]
    struct Symmetric {
        device: cubecl::Device,
        slots: Handle,
        layout: Handle,
        num_slots: usize,
        num_queries: usize,
    }

    impl RowSumOfChunk for Symmetric {
        fn sum_chunk(
            &self,
            values: BurnTensor<2>,
            n: usize,
            chunk: SlotChunk,
        ) -> Option<BurnTensor<2>> {
            let [rows, cols] = values.dims();
            if values.dtype() != burn::tensor::DType::F32 || n != self.num_queries {
                return None;
            }
            debug_assert_eq!(rows, chunk.len());
            let dy = cube_tensor::float_buffer(values)?;
            let client = self.device.client();
            let out = client.empty(n * cols * 4);
            let cube_dim = CubeDim::new_1d(256);
            let cube_count = calculate_cube_count_elemwise(&client, n * cols, cube_dim);
            symmetric_transpose::launch(
                &client,
                cube_count,
                cube_dim,
                TensorHandle::new_contiguous(
                    [rows * cols],
                    dy.handle.clone(),
                    f32::elem_type_native(),
                )
                .into_arg(),
                i32s(&self.slots, self.num_slots),
                u32s(&self.layout, self.num_queries * 3),
                f32s(&out, n * cols),
                n,
                cols,
                chunk.q0 as u32,
                chunk.q1 as u32,
                chunk.start as u32,
            );
            Some(cube_tensor::float_tensor(&self.device, out, [n, cols]))
        }
    }

    pub(super) fn run(
        device: &cubecl::Device,
        points: &[[f32; 3]],
        queries: &[[f32; 3]],
        radius: f32,
        ignore_identical: bool,
        symmetric: bool,
        max_slots: usize,
    ) -> Result<DevicePairs, String> {
        let m = queries.len();
        if points.is_empty() {
            // no pairs: every query one padding slot (row 0 of an empty set, weight zero)
            let counts = vec![0u32; m];
            let chunks = plan_chunks(&counts, max_slots);
            let slots = cube_tensor::int_tensor(device, upload(device, &vec![0i32; m.max(1)]), [m]);
            let real =
                cube_tensor::float_tensor(device, upload(device, &vec![0f32; m.max(1)]), [m, 1]);
            return Ok(DevicePairs {
                counts,
                chunks,
                num_in: 0,
                slots,
                real,
                symmetric: None,
            });
        }
        let grid = Grid::new(points, radius);
        let client = device.client();
        // dims as floats: exact below 2^24 (the cells are at most MAX_CELLS)
        let params = [
            grid.lo[0],
            grid.lo[1],
            grid.lo[2],
            grid.inv_cell,
            grid.dims[0] as f32,
            grid.dims[1] as f32,
            grid.dims[2] as f32,
        ];
        let p_h = upload(device, &grid.sorted);
        let o_h = upload(device, &grid.order);
        let s_h = upload(device, &grid.starts);
        let q_h = upload(device, bytemuck::cast_slice::<[f32; 3], f32>(queries));
        let g_h = upload(device, &params);
        let n_cells1 = grid.starts.len();
        let r2 = radius * radius;
        let cube_dim = CubeDim::new_1d(256);
        let cube_count = calculate_cube_count_elemwise(&client, m.max(1), cube_dim);
        let counts_h = client.empty(m.max(1) * 4);
        count_pairs::launch(
            &client,
            cube_count.clone(),
            cube_dim,
            f32s(&p_h, grid.sorted.len()),
            u32s(&s_h, n_cells1),
            f32s(&q_h, m * 3),
            u32s(&counts_h, m.max(1)),
            f32s(&g_h, 7),
            m,
            r2,
            ignore_identical,
        );
        let bytes = client
            .read(vec![counts_h])
            .map_err(|e| format!("reading the pair counts: {e:?}"))?;
        count_read(m * 4);
        let counts: Vec<u32> = bytemuck::pod_collect_to_vec(&bytes[0][..m * 4]);
        let chunks = plan_chunks(&counts, max_slots);
        let num_slots = chunks.last().map_or(0, |c| c.start + c.len());
        let l_h = upload(device, &layout_of(&counts, &chunks));
        let slots_h = client.empty(num_slots.max(1) * 4);
        let real_h = client.empty(num_slots.max(1) * 4);
        fill_slots::launch(
            &client,
            cube_count,
            cube_dim,
            f32s(&p_h, grid.sorted.len()),
            i32s(&o_h, grid.order.len()),
            u32s(&s_h, n_cells1),
            f32s(&q_h, m * 3),
            u32s(&l_h, m * 3),
            i32s(&slots_h, num_slots.max(1)),
            f32s(&real_h, num_slots.max(1)),
            f32s(&g_h, 7),
            m,
            points.len().max(1) as u32,
            r2,
            ignore_identical,
        );
        let layout = symmetric.then_some(l_h);
        Ok(finish(
            device,
            (counts, chunks, points.len()),
            (slots_h, real_h),
            layout,
        ))
    }

    /// The pairs in their slots on `device`: `(counts, chunks, num_in)`, the slots' and the
    /// `real` column's buffers, and the layout's buffer where the pairs are symmetric (for the
    /// gradient's kernel).
    fn finish(
        device: &cubecl::Device,
        (counts, chunks, num_in): (Vec<u32>, Vec<SlotChunk>, usize),
        (slots_h, real_h): (Handle, Handle),
        layout: Option<Handle>,
    ) -> DevicePairs {
        let num_slots = chunks.last().map_or(0, |c| c.start + c.len());
        let symmetric = layout.map(|layout| {
            Arc::new(Symmetric {
                device: device.clone(),
                slots: slots_h.clone(),
                layout,
                num_slots,
                num_queries: counts.len(),
            }) as Arc<dyn RowSumOfChunk>
        });
        DevicePairs {
            counts,
            chunks,
            num_in,
            slots: cube_tensor::int_tensor(device, slots_h, [num_slots]),
            real: cube_tensor::float_tensor(device, real_h, [num_slots, 1]),
            symmetric,
        }
    }

    /// Each query's layout: its pair count, its first slot and its chunk's width.
    fn layout_of(counts: &[u32], chunks: &[SlotChunk]) -> Vec<u32> {
        let mut layout = vec![0u32; counts.len() * 3];
        for ch in chunks {
            for q in ch.q0..ch.q1 {
                layout[q * 3] = counts[q];
                layout[q * 3 + 1] = (ch.start + (q - ch.q0) * ch.width) as u32;
                layout[q * 3 + 2] = ch.width as u32;
            }
        }
        layout
    }

    pub(super) fn from_host(
        device: &cubecl::Device,
        pairs: &crate::neighbors::PairList,
        num_in: usize,
        symmetric: bool,
        max_slots: usize,
    ) -> Result<DevicePairs, String> {
        let counts: Vec<u32> = pairs
            .offsets
            .windows(2)
            .map(|w| (w[1] - w[0]) as u32)
            .collect();
        let chunks = plan_chunks(&counts, max_slots);
        let num_slots = chunks.last().map_or(0, |c| c.start + c.len());
        let mut slots = vec![0i32; num_slots.max(1)];
        let mut real = vec![0f32; num_slots.max(1)];
        // each query's slots in parallel: its `width` slots follow the previous query's
        for ch in &chunks {
            let span = ch.start..ch.start + ch.len();
            slots[span.clone()]
                .par_chunks_mut(ch.width)
                .zip(real[span].par_chunks_mut(ch.width))
                .enumerate()
                .try_for_each(|(i, (slots, real))| {
                    let q = ch.q0 + i;
                    let row = &pairs.indices[pairs.offsets[q]..pairs.offsets[q + 1]];
                    if row.windows(2).any(|w| w[0] >= w[1])
                        || row.iter().any(|&i| i as usize >= num_in)
                    {
                        return Err(format!(
                            "query {q}'s pairs are not ascending inputs below {num_in}"
                        ));
                    }
                    for (k, (slot, real)) in slots.iter_mut().zip(real).enumerate() {
                        *slot = match row.len() {
                            0 => ((q + k) % num_in.max(1)) as i32,
                            n => row[k % n] as i32,
                        };
                        *real = f32::from(u8::from(k < row.len()));
                    }
                    Ok(())
                })?;
        }
        let slots_h = upload(device, &slots);
        let real_h = upload(device, &real);
        let layout = symmetric.then(|| upload(device, &layout_of(&counts, &chunks)));
        Ok(finish(
            device,
            (counts, chunks, num_in),
            (slots_h, real_h),
            layout,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunks_cover_every_query_within_the_slot_budget() {
        let counts = [3u32, 0, 7, 2, 2, 9, 1, 0, 0, 4];
        for max_slots in [1, 5, 9, 14, 30, 1000] {
            let chunks = plan_chunks(&counts, max_slots);
            let mut next = (0, 0);
            for ch in &chunks {
                assert_eq!((ch.q0, ch.start), next, "contiguous");
                assert!(ch.q1 > ch.q0);
                let widest = counts[ch.q0..ch.q1].iter().max().copied().unwrap_or(0) as usize;
                assert_eq!(ch.width, widest.max(1));
                assert!(
                    ch.len() <= max_slots.max(ch.width),
                    "{ch:?} over {max_slots}"
                );
                next = (ch.q1, ch.start + ch.len());
            }
            assert_eq!(next.0, counts.len());
        }
    }

    #[cfg(feature = "gpu")]
    #[test]
    fn the_grid_sorts_points_by_cell_stably() {
        let pts: Vec<[f32; 3]> = (0..200)
            .map(|i| {
                let f = i as f32;
                [(f * 0.37).sin(), (f * 0.91).cos(), (f * 0.13).sin() * 3.0]
            })
            .collect();
        let grid = Grid::new(&pts, 0.3);
        let mut seen = vec![false; pts.len()];
        let cells = grid.starts.len() - 1;
        for c in 0..cells {
            let run = &grid.order[grid.starts[c] as usize..grid.starts[c + 1] as usize];
            assert!(
                run.windows(2).all(|w| w[0] < w[1]),
                "ascending within a cell"
            );
            for &i in run {
                seen[i as usize] = true;
            }
        }
        assert!(seen.iter().all(|&s| s));
        assert_eq!(grid.starts[cells] as usize, pts.len());
    }
}
