//! The capped ball query on the particles' GPU (a cubecl kernel), for PhysNeRF's samples.
//!
//! One thread per query scans every point in index order (brute force, as the reference's
//! CUDA ball query does; a query outside the points' bounding box widened by the radius skips
//! the scan): `"lowest_index"` keeps the first K points with `d² < r²` and stops,
//! `"nearest"` keeps the K smallest `(d², index)` by insertion. The semantics are the host
//! search's ([`crate::neighbors::exact_ball_query`]): `d² = (dx² + dy²) + dz²` with
//! `dx = point − query`, empty slots `idx = −1`, `d² = 0`. A GPU compiler may fuse the
//! products and sums into fused multiply-adds, so a point within an ulp of the radius, or an
//! exact tie in distance, can fall the other way than on the host: the search's place
//! (`neighbour_search` in an experiment) is part of what shapes a run.
//!
//! The points, the queries and the widened bounding box are uploaded, the slots' indices and
//! distances read back together: three uploads and one read per query batch, counted by
//! [`crate::transfer`].

use serde::{Deserialize, Serialize};

use crate::choice::{Choice, ProcessChoice};

/// Where the neighbour searches run: PhysNeRF's ball query (here) and DLF's pairs
/// ([`crate::device_pairs`]). In files: `"host"` or `"device"`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NeighbourSearch {
    /// On the host's cores, through the uniform grid (the default; the CPU backends always).
    #[default]
    Host,
    /// On the particles' GPU, where the particles live on one (cubecl backends); on the host
    /// otherwise.
    Device,
}

impl Choice for NeighbourSearch {
    const ALL: &'static [Self] = &[NeighbourSearch::Host, NeighbourSearch::Device];

    fn name(self) -> &'static str {
        match self {
            NeighbourSearch::Host => "host",
            NeighbourSearch::Device => "device",
        }
    }
}

/// The process's choice (host unless set).
static SEARCH: ProcessChoice = ProcessChoice::new();

/// Where the neighbour searches run in this process.
pub fn neighbour_search() -> NeighbourSearch {
    SEARCH.get()
}

/// Sets where the neighbour searches run in this process (the trainer sets the experiment's
/// `neighbour_search` when it opens a run).
pub fn set_neighbour_search(place: NeighbourSearch) {
    SEARCH.set(place);
}

/// The capped ball query of `queries` against `points` on `device`'s GPU; `None` where the
/// device is not a cubecl device (a CPU backend, or a build without a GPU backend).
///
/// # Errors
/// When the device fails to run the kernel or to read its result back.
pub fn ball_query(
    device: &burn::prelude::Device,
    points: &[[f32; 3]],
    queries: &[[f32; 3]],
    radius: f32,
    k: usize,
    selection: crate::neighbors::NeighborSelection,
) -> Option<Result<crate::neighbors::BallQuery<f32>, String>> {
    #[cfg(feature = "gpu")]
    {
        let cube = crate::cube_tensor::cube_device(device)?;
        Some(kernel::run(&cube, points, queries, radius, k, selection))
    }
    #[cfg(not(feature = "gpu"))]
    {
        let _ = (device, points, queries, radius, k, selection);
        None
    }
}

#[cfg(feature = "gpu")]
mod kernel {
    use cubecl::calculate_cube_count_elemwise;
    use cubecl::prelude::*;

    use crate::cube_tensor::{arg, f32_arg};
    use crate::neighbors::{BallQuery, NeighborSelection};

    /// One query per thread; see the module docs.
    #[allow(clippy::too_many_arguments)]
    #[cube(launch)]
    fn capped_ball_query(
        points: &Tensor<f32>,
        queries: &Tensor<f32>,
        idx: &mut Tensor<i32>,
        dist2: &mut Tensor<f32>,
        bounds: &Tensor<f32>,
        n_points: usize,
        n_queries: usize,
        r2: f32,
        #[comptime] k: usize,
        #[comptime] nearest: bool,
    ) {
        let q = ABSOLUTE_POS;
        if q < n_queries {
            let base = q * k;
            for s in 0..k {
                idx[base + s] = -1;
                dist2[base + s] = 0.0;
            }
            let qx = queries[q * 3];
            let qy = queries[q * 3 + 1];
            let qz = queries[q * 3 + 2];
            let outside = qx < bounds[0]
                || qy < bounds[1]
                || qz < bounds[2]
                || qx > bounds[3]
                || qy > bounds[4]
                || qz > bounds[5];
            if !outside {
                let mut count = 0usize;
                for i in 0..n_points {
                    let dx = points[i * 3] - qx;
                    let dy = points[i * 3 + 1] - qy;
                    let dz = points[i * 3 + 2] - qz;
                    let d = dx * dx + dy * dy + dz * dz;
                    if d < r2 {
                        if comptime![nearest] {
                            if count < k || d < dist2[base + k - 1] {
                                // the slot the new point would take at the end, then shifted
                                // down past every kept point strictly farther
                                let mut j = count;
                                if count == k {
                                    j = k - 1;
                                }
                                loop {
                                    if j == 0 {
                                        break;
                                    }
                                    let prev = dist2[base + j - 1];
                                    if prev <= d {
                                        break;
                                    }
                                    dist2[base + j] = prev;
                                    idx[base + j] = idx[base + j - 1];
                                    j -= 1;
                                }
                                dist2[base + j] = d;
                                idx[base + j] = i32::cast_from(i);
                                if count < k {
                                    count += 1;
                                }
                            }
                        } else {
                            dist2[base + count] = d;
                            idx[base + count] = i32::cast_from(i);
                            count += 1;
                            if count == k {
                                break;
                            }
                        }
                    }
                }
            }
        }
    }

    pub(super) fn run(
        device: &cubecl::Device,
        points: &[[f32; 3]],
        queries: &[[f32; 3]],
        radius: f32,
        k: usize,
        selection: NeighborSelection,
    ) -> Result<BallQuery<f32>, String> {
        let n = queries.len();
        if k == 0 || n == 0 || points.is_empty() {
            return Ok(BallQuery {
                k,
                idx: vec![-1; n * k],
                dist2: vec![0.0; n * k],
                count: vec![0; n],
            });
        }
        let (lo, hi) = crate::neighbors::bounding_box(points);
        // the host's test, `q < lo − r || q > hi + r`, in the same f32 arithmetic
        let bounds: [f32; 6] = [
            lo[0] - radius,
            lo[1] - radius,
            lo[2] - radius,
            hi[0] + radius,
            hi[1] + radius,
            hi[2] + radius,
        ];
        let client = device.client();
        let p_flat: &[f32] = bytemuck::cast_slice(points);
        let q_flat: &[f32] = bytemuck::cast_slice(queries);
        let p_handle = client.create_from_slice(bytemuck::cast_slice(p_flat));
        let q_handle = client.create_from_slice(bytemuck::cast_slice(q_flat));
        let b_handle = client.create_from_slice(bytemuck::cast_slice(&bounds));
        crate::transfer::count_upload(std::mem::size_of_val(p_flat));
        crate::transfer::count_upload(std::mem::size_of_val(q_flat));
        crate::transfer::count_upload(std::mem::size_of_val(&bounds));
        let slots = n * k;
        let idx_handle = client.empty(slots * 4);
        let d2_handle = client.empty(slots * 4);
        let cube_dim = CubeDim::new_1d(256);
        let cube_count = calculate_cube_count_elemwise(&client, n, cube_dim);
        capped_ball_query::launch(
            &client,
            cube_count,
            cube_dim,
            f32_arg(&p_handle, p_flat.len()),
            f32_arg(&q_handle, q_flat.len()),
            arg(&idx_handle, slots, i32::elem_type_native()),
            f32_arg(&d2_handle, slots),
            f32_arg(&b_handle, 6),
            points.len(),
            n,
            radius * radius,
            k,
            selection == NeighborSelection::Nearest,
        );
        // both slots' buffers in one read: one wait for the queue
        let bytes = client
            .read(vec![idx_handle, d2_handle])
            .map_err(|e| format!("reading the ball query's slots: {e:?}"))?;
        crate::transfer::count_read(2 * slots * 4);
        let (idx_bytes, d2_bytes) = (&bytes[0], &bytes[1]);
        let idx: Vec<i32> = bytemuck::pod_collect_to_vec(&idx_bytes[..slots * 4]);
        let dist2: Vec<f32> = bytemuck::pod_collect_to_vec(&d2_bytes[..slots * 4]);
        let count = idx
            .chunks_exact(k)
            .map(|s| s.iter().filter(|&&i| i >= 0).count() as u32)
            .collect();
        Ok(BallQuery {
            k,
            idx,
            dist2,
            count,
        })
    }
}
