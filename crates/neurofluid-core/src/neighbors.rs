//! Neighbour search on a uniform grid, built once per point set.
//!
//! The grid is hashed (a cell key maps to one of ~2N buckets), so its memory is O(N) however far
//! the points spread (escaped particles falling to −50 m do not blow it up). Each bucket lists
//! its points in ascending index order, which lets the capped ball query stop scanning a bucket as
//! soon as the indices pass the worst one it keeps.
//!
//! Two queries with two semantics:
//! - [`NeighborGrid::pairs`]: every input point within `radius` (float32 `d² ≤ r²`, inclusive),
//!   the pair lists of DLF's continuous convolution (Open3D `FixedRadiusSearch`). An input point
//!   bit-identical to the query is skipped when asked (`radius_search_ignore_query_points`).
//! - [`NeighborGrid::ball_query`]: at most K points with `d² < r²` (strict), the K lowest-index
//!   ones (pytorch3d `ball_query`, PhysNeRF's default) or the K nearest; empty slots are flagged.
//!   The nearest K are searched on a finer dense grid built for the call (cells a quarter of the
//!   radius, one slice of points per column of cells), which stops near the query when it can
//!   prove that nothing farther is nearer; it falls back to the hashed grid when the points are
//!   spread too far for a dense one.
//!
//! [`exact_ball_query`] answers the capped ball query without a grid, in any float type: the
//! grid's oracle in tests, and the search of PhysNeRF's f64 renders.
//!
//! Why not a crate (kiddo, rstar): parity needs exactly these two semantics — Open3D's inclusive
//! float32 test and pytorch3d's strict, index-ordered cap of K — which a k-d tree's nearest-K or
//! range query does not give, and the hashed grid is faster for the dense, uniform-radius
//! queries of both models (BENCHMARKS.md). kiddo still serves the evaluation's nearest distances.

use num_traits::Float;
use rayon::prelude::*;

/// Fixed-radius neighbour lists in compressed-row form.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PairList {
    /// Row offsets: the neighbours of query q are `indices[offsets[q]..offsets[q + 1]]`.
    pub offsets: Vec<usize>,
    /// Input-point index of every pair, ascending within a row.
    pub indices: Vec<u32>,
    /// Squared distance of every pair (float32, `dx² + dy² + dz²`).
    pub dist2: Vec<f32>,
}

impl PairList {
    /// Number of query points (rows).
    pub fn num_queries(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Total number of pairs.
    pub fn num_pairs(&self) -> usize {
        self.indices.len()
    }

    /// Neighbour count of every query.
    pub fn counts(&self) -> Vec<u32> {
        self.offsets
            .windows(2)
            .map(|w| (w[1] - w[0]) as u32)
            .collect()
    }

    /// Query index of every pair (the row each pair belongs to).
    pub fn query_of_pair(&self) -> Vec<u32> {
        let mut out = Vec::with_capacity(self.num_pairs());
        for (q, w) in self.offsets.windows(2).enumerate() {
            out.extend(std::iter::repeat_n(q as u32, w[1] - w[0]));
        }
        out
    }
}

/// Which K points a capped ball query keeps when more than K are inside the ball. In files:
/// `"lowest_index"` or `"nearest"`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NeighborSelection {
    /// The K lowest particle indices, as pytorch3d's `ball_query` (the reference's behaviour).
    #[default]
    LowestIndex,
    /// The K nearest points (ties broken by index).
    Nearest,
}

/// Result of a capped ball query: K slots per query.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BallQuery<T = f32> {
    /// Slots per query.
    pub k: usize,
    /// `[queries × k]` point indices; `-1` marks an empty slot.
    pub idx: Vec<i32>,
    /// `[queries × k]` squared distances; `0` in empty slots.
    pub dist2: Vec<T>,
    /// Filled slots per query (≤ k).
    pub count: Vec<u32>,
}

impl<T> BallQuery<T> {
    /// Number of queries.
    pub fn num_queries(&self) -> usize {
        self.count.len()
    }

    /// The filled slots of query q.
    pub fn neighbors(&self, q: usize) -> &[i32] {
        &self.idx[q * self.k..q * self.k + self.count[q] as usize]
    }
}

/// A hashed uniform grid over a borrowed point set.
#[derive(Debug, Clone)]
pub struct NeighborGrid<'a> {
    points: &'a [[f32; 3]],
    inv_cell: f32,
    /// `buckets + 1` offsets into `order`.
    starts: Vec<u32>,
    /// Point indices grouped by bucket, ascending within a bucket.
    order: Vec<u32>,
    mask: u64,
}

/// Cell key of a coordinate triple, or None for non-finite input.
fn cell_of(p: [f32; 3], inv_cell: f32) -> Option<[i64; 3]> {
    let mut c = [0i64; 3];
    for a in 0..3 {
        let v = (p[a] * inv_cell).floor();
        if !v.is_finite() {
            return None;
        }
        c[a] = v as i64;
    }
    Some(c)
}

fn hash_cell(c: [i64; 3], mask: u64) -> usize {
    let h = (c[0] as u64).wrapping_mul(73_856_093)
        ^ (c[1] as u64).wrapping_mul(19_349_663)
        ^ (c[2] as u64).wrapping_mul(83_492_791);
    // mix the high bits in so that small tables see all of the key
    let h = h ^ (h >> 29);
    (h & mask) as usize
}

/// Squared distance, summed as (dx² + dy²) + dz².
#[inline]
fn dist2<T: Float>(a: [T; 3], b: [T; 3]) -> T {
    let dx = a[0] - b[0];
    let dy = a[1] - b[1];
    let dz = a[2] - b[2];
    dx * dx + dy * dy + dz * dz
}

/// The half-width of a box around `q` that holds every point within `radius` of it: `radius`
/// and a margin of a few ulps, so that the cells found from the box's corners stay a superset
/// under float rounding.
fn conservative_reach(q: [f32; 3], radius: f32) -> f32 {
    let scale = q[0].abs().max(q[1].abs()).max(q[2].abs());
    radius * (1.0 + 1e-4) + 5e-7 * scale
}

/// Queries are split into chunks of this many for the parallel loops.
const CHUNK: usize = 1024;

impl<'a> NeighborGrid<'a> {
    /// Builds the grid with the given cell size (usually the search radius).
    ///
    /// # Panics
    /// When `cell_size` is not a positive finite number.
    pub fn new(points: &'a [[f32; 3]], cell_size: f32) -> Self {
        assert!(
            cell_size.is_finite() && cell_size > 0.0,
            "grid cell size must be positive and finite, got {cell_size}"
        );
        let inv_cell = 1.0 / cell_size;
        let buckets = (2 * points.len()).next_power_of_two().max(16);
        let mask = buckets as u64 - 1;
        let keys: Vec<usize> = points
            .iter()
            .map(|&p| cell_of(p, inv_cell).map_or(usize::MAX, |c| hash_cell(c, mask)))
            .collect();
        let (starts, order) = counting_sort(&keys, buckets, |k| (k != usize::MAX).then_some(k));
        Self {
            points,
            inv_cell,
            starts,
            order,
            mask,
        }
    }

    /// The points the grid was built over.
    pub fn points(&self) -> &'a [[f32; 3]] {
        self.points
    }

    /// The distinct buckets whose cells touch the box `q ± radius` (a conservative superset).
    fn buckets_around(&self, q: [f32; 3], radius: f32, out: &mut Vec<usize>) {
        out.clear();
        if self.order.is_empty() {
            return;
        }
        let r = conservative_reach(q, radius);
        let (Some(lo), Some(hi)) = (
            cell_of([q[0] - r, q[1] - r, q[2] - r], self.inv_cell),
            cell_of([q[0] + r, q[1] + r, q[2] + r], self.inv_cell),
        ) else {
            return;
        };
        let cells = (0..3)
            .map(|a| (hi[a] - lo[a] + 1) as u128)
            .product::<u128>();
        if cells > (self.starts.len() - 1) as u128 {
            // the box covers more cells than there are buckets: every bucket is a candidate
            out.extend(
                (0..self.starts.len() - 1).filter(|&b| self.starts[b] != self.starts[b + 1]),
            );
            return;
        }
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    let b = hash_cell([x, y, z], self.mask);
                    if self.starts[b] != self.starts[b + 1] && !out.contains(&b) {
                        out.push(b);
                    }
                }
            }
        }
    }

    fn bucket(&self, b: usize) -> &[u32] {
        &self.order[self.starts[b] as usize..self.starts[b + 1] as usize]
    }

    /// All input points with float32 `d² ≤ radius²` of each query, ascending by index.
    ///
    /// With `ignore_identical`, an input point whose coordinates are bit-identical to the query's
    /// is skipped (a coordinate comparison, as Open3D does, not an index comparison).
    pub fn pairs(&self, queries: &[[f32; 3]], radius: f32, ignore_identical: bool) -> PairList {
        let r2 = radius * radius;
        let chunks: Vec<PairList> = queries
            .par_chunks(CHUNK)
            .map(|chunk| {
                let mut part = PairList {
                    offsets: Vec::with_capacity(chunk.len() + 1),
                    ..PairList::default()
                };
                part.offsets.push(0);
                let mut buckets = Vec::with_capacity(27);
                let mut row: Vec<(u32, f32)> = Vec::new();
                for &q in chunk {
                    row.clear();
                    self.buckets_around(q, radius, &mut buckets);
                    for &b in &buckets {
                        for &i in self.bucket(b) {
                            let p = self.points[i as usize];
                            if ignore_identical && p.map(f32::to_bits) == q.map(f32::to_bits) {
                                continue;
                            }
                            let d2 = dist2(p, q);
                            if d2 <= r2 {
                                row.push((i, d2));
                            }
                        }
                    }
                    row.sort_unstable_by_key(|&(i, _)| i);
                    part.indices.extend(row.iter().map(|&(i, _)| i));
                    part.dist2.extend(row.iter().map(|&(_, d)| d));
                    part.offsets.push(part.indices.len());
                }
                part
            })
            .collect();
        let mut out = PairList {
            offsets: Vec::with_capacity(queries.len() + 1),
            ..PairList::default()
        };
        out.offsets.push(0);
        for part in chunks {
            let base = out.indices.len();
            out.offsets
                .extend(part.offsets[1..].iter().map(|&o| base + o));
            out.indices.extend(part.indices);
            out.dist2.extend(part.dist2);
        }
        out
    }

    /// At most `k` input points with float32 `d² < radius²` per query (see [`NeighborSelection`]).
    ///
    /// Slots of a query are ordered by ascending index ([`NeighborSelection::LowestIndex`]) or by
    /// ascending distance ([`NeighborSelection::Nearest`]); empty slots hold index −1 and distance 0.
    pub fn ball_query(
        &self,
        queries: &[[f32; 3]],
        radius: f32,
        k: usize,
        selection: NeighborSelection,
    ) -> BallQuery {
        let r2 = radius * radius;
        let nq = queries.len();
        let mut idx = vec![-1i32; nq * k];
        let mut d2 = vec![0f32; nq * k];
        let mut count = vec![0u32; nq];
        if k == 0 {
            return BallQuery {
                k,
                idx,
                dist2: d2,
                count,
            };
        }
        let columns = match selection {
            NeighborSelection::Nearest => ColumnGrid::new(self.points, radius),
            NeighborSelection::LowestIndex => None,
        };
        idx.par_chunks_mut(CHUNK * k)
            .zip(d2.par_chunks_mut(CHUNK * k))
            .zip(count.par_chunks_mut(CHUNK))
            .zip(queries.par_chunks(CHUNK))
            .for_each(|(((idx, d2), count), chunk)| {
                let mut buckets = Vec::with_capacity(27);
                let mut best: Vec<(u32, f32)> = Vec::with_capacity(4 * k);
                for (qi, &q) in chunk.iter().enumerate() {
                    best.clear();
                    match (selection, &columns) {
                        (NeighborSelection::Nearest, Some(columns)) => {
                            columns.nearest_k(q, radius, k, &mut best)
                        }
                        (NeighborSelection::Nearest, None) => {
                            self.buckets_around(q, radius, &mut buckets);
                            self.nearest_k(q, r2, k, &buckets, &mut best)
                        }
                        (NeighborSelection::LowestIndex, _) => {
                            self.buckets_around(q, radius, &mut buckets);
                            self.lowest_k(q, r2, k, &buckets, &mut best)
                        }
                    }
                    count[qi] = best.len() as u32;
                    for (s, &(i, d)) in best.iter().enumerate() {
                        idx[qi * k + s] = i as i32;
                        d2[qi * k + s] = d;
                    }
                }
            });
        BallQuery {
            k,
            idx,
            dist2: d2,
            count,
        }
    }

    /// The `k` lowest indices inside the ball, ascending.
    fn lowest_k(
        &self,
        q: [f32; 3],
        r2: f32,
        k: usize,
        buckets: &[usize],
        best: &mut Vec<(u32, f32)>,
    ) {
        // `best` stays sorted by index and holds at most k entries; a bucket is sorted by index, so
        // once its index passes the k-th best there is nothing more to find in it.
        for &b in buckets {
            for &i in self.bucket(b) {
                if best.len() == k && i > best[k - 1].0 {
                    break;
                }
                let d = dist2(self.points[i as usize], q);
                if d < r2 {
                    let pos = best.partition_point(|&(j, _)| j < i);
                    if best.len() == k {
                        best.pop();
                    }
                    best.insert(pos, (i, d));
                }
            }
        }
    }

    /// The `k` nearest points inside the ball, by ascending (distance, index).
    fn nearest_k(
        &self,
        q: [f32; 3],
        r2: f32,
        k: usize,
        buckets: &[usize],
        best: &mut Vec<(u32, f32)>,
    ) {
        for &b in buckets {
            for &i in self.bucket(b) {
                let d = dist2(self.points[i as usize], q);
                if d < r2 {
                    best.push((i, d));
                }
            }
        }
        keep_nearest(best, k);
    }
}

/// Orders `best` by (distance, index) and keeps its first `k`.
fn keep_nearest(best: &mut Vec<(u32, f32)>, k: usize) {
    let key = |a: &(u32, f32), b: &(u32, f32)| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0));
    if best.len() > k {
        best.select_nth_unstable_by(k - 1, key);
        best.truncate(k);
    }
    best.sort_unstable_by(key);
}

/// Cells per search radius of [`ColumnGrid`].
const CELLS_PER_RADIUS: f32 = 4.0;

/// Half-width in cells of the cube a nearest-K query scans first.
const FIRST_REACH: i64 = 2;

/// A dense grid over the points' bounding box for the nearest-K query, its cells a quarter of
/// the radius wide and its points sorted by cell with `z` fastest, so that a box of cells is
/// one contiguous slice per `(x, y)` column. A query scans the cube of cells 2 around its own
/// first and stops there when its K-th nearest is closer than anything outside that cube (in
/// PhysNeRF's fluids the K-th nearest is about a third of the radius away, inside the cube);
/// otherwise it scans every cell that touches the ball.
struct ColumnGrid {
    origin: [f32; 3],
    inv_cell: f32,
    dims: [i64; 3],
    /// `cells + 1` offsets into `order` and `pos`.
    starts: Vec<u32>,
    /// Point indices by cell (ascending within a cell).
    order: Vec<u32>,
    /// The points' positions in `order`'s order.
    pos: Vec<[f32; 3]>,
}

/// A box of cells `lo..=hi` (inclusive on every axis).
type CellBox = ([i64; 3], [i64; 3]);

impl ColumnGrid {
    /// The grid for ball queries of `radius`, or None when it would have more than 8 cells per
    /// point (particles spread far apart) or there are no finite points.
    fn new(points: &[[f32; 3]], radius: f32) -> Option<Self> {
        let finite = |p: &&[f32; 3]| p.iter().all(|c| c.is_finite());
        let (lo, hi) = bounding_box(points.iter().filter(finite));
        let inv_cell = CELLS_PER_RADIUS / radius;
        if lo[0] > hi[0] || !inv_cell.is_finite() {
            return None;
        }
        let mut dims = [0i64; 3];
        for a in 0..3 {
            let span = (f64::from(hi[a]) - f64::from(lo[a])) * f64::from(inv_cell);
            if span > 1e6 {
                return None;
            }
            dims[a] = span.floor() as i64 + 1;
        }
        let cells = (dims[0] * dims[1] * dims[2]) as usize;
        if cells > 8 * points.len() + 4096 {
            return None;
        }
        let mut grid = Self {
            origin: lo,
            inv_cell,
            dims,
            starts: Vec::new(),
            order: Vec::new(),
            pos: Vec::new(),
        };
        let keys: Vec<usize> = points
            .iter()
            .map(|p| {
                if finite(&p) {
                    grid.index(grid.cell_of(*p), true)
                } else {
                    usize::MAX
                }
            })
            .collect();
        (grid.starts, grid.order) = counting_sort(&keys, cells, |k| (k != usize::MAX).then_some(k));
        grid.pos = grid.order.iter().map(|&i| points[i as usize]).collect();
        Some(grid)
    }

    /// The cell of `p`, not bounded by the grid (a query may lie outside it) but by ±2⁴⁰, so
    /// that cell arithmetic cannot overflow.
    fn cell_of(&self, p: [f32; 3]) -> [i64; 3] {
        const FAR: i64 = 1 << 40;
        [0, 1, 2]
            .map(|a| (((p[a] - self.origin[a]) * self.inv_cell).floor() as i64).clamp(-FAR, FAR))
    }

    /// The index of cell `c`, clamped into the grid when `clamp` (a point's cell off the edge
    /// by rounding).
    fn index(&self, c: [i64; 3], clamp: bool) -> usize {
        let c = if clamp {
            [0, 1, 2].map(|a| c[a].clamp(0, self.dims[a] - 1))
        } else {
            c
        };
        ((c[0] * self.dims[1] + c[1]) * self.dims[2] + c[2]) as usize
    }

    /// The box `lo..=hi` clipped to the grid, None when nothing is left.
    fn clip(&self, (lo, hi): CellBox) -> Option<CellBox> {
        let lo = [0, 1, 2].map(|a| lo[a].max(0));
        let hi = [0, 1, 2].map(|a| hi[a].min(self.dims[a] - 1));
        (0..3).all(|a| lo[a] <= hi[a]).then_some((lo, hi))
    }

    /// Pushes every point of the (clipped) box with `d² < r2` onto `best`.
    fn scan(&self, q: [f32; 3], (lo, hi): CellBox, r2: f32, best: &mut Vec<(u32, f32)>) {
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                let first = self.starts[self.index([x, y, lo[2]], false)] as usize;
                let last = self.starts[self.index([x, y, hi[2]], false) + 1] as usize;
                for (&i, &p) in self.order[first..last].iter().zip(&self.pos[first..last]) {
                    let d = dist2(p, q);
                    if d < r2 {
                        best.push((i, d));
                    }
                }
            }
        }
    }

    /// The `k` nearest points with `d² < radius²`, by ascending (distance, index).
    fn nearest_k(&self, q: [f32; 3], radius: f32, k: usize, best: &mut Vec<(u32, f32)>) {
        if q.iter().any(|c| !c.is_finite()) {
            return;
        }
        let r2 = radius * radius;
        let c = self.cell_of(q);
        let cube = (c.map(|v| v - FIRST_REACH), c.map(|v| v + FIRST_REACH));
        if let Some(first) = self.clip(cube) {
            self.scan(q, first, r2, best);
            if best.len() >= k {
                keep_nearest(best, k);
                let kth = best.last().map_or(0.0, |&(_, d)| d);
                if f64::from(kth) < self.clearance(q, c) {
                    return;
                }
            }
            best.clear();
        }
        // every cell that touches the ball
        let r = conservative_reach(q, radius);
        let ball = (
            self.cell_of(q.map(|v| v - r)),
            self.cell_of(q.map(|v| v + r)),
        );
        if let Some(ball) = self.clip(ball) {
            self.scan(q, ball, r2, best);
        }
        keep_nearest(best, k);
    }

    /// A lower bound on `d²` from `q` (in cell `c`) to every point outside the cube of cells
    /// [`FIRST_REACH`] around `c` (sides at the grid's edge bound nothing), or 0 when none can
    /// be given safely.
    fn clearance(&self, q: [f32; 3], c: [i64; 3]) -> f64 {
        let h = 1.0 / f64::from(self.inv_cell);
        let mut gap = f64::INFINITY;
        let mut scale = 0f64;
        for a in 0..3 {
            let (qa, oa) = (f64::from(q[a]), f64::from(self.origin[a]));
            scale = scale.max(qa.abs()).max(oa.abs());
            if c[a] - FIRST_REACH > 0 {
                gap = gap.min(qa - (oa + (c[a] - FIRST_REACH) as f64 * h));
            }
            if c[a] + FIRST_REACH < self.dims[a] - 1 {
                gap = gap.min(oa + (c[a] + FIRST_REACH + 1) as f64 * h - qa);
            }
        }
        // rounding of the cell keys and of d² (a few ulps), kept well on the safe side
        let gap = gap - 1e-6 * (scale + 2.0 * h);
        if gap > 0.0 {
            gap * gap * (1.0 - 1e-5)
        } else {
            0.0
        }
    }
}

/// Fixed-radius pairs (DLF semantics) with a grid built for this call; see [`NeighborGrid::pairs`].
pub fn fixed_radius_pairs(
    points: &[[f32; 3]],
    queries: &[[f32; 3]],
    radius: f32,
    ignore_identical: bool,
) -> PairList {
    NeighborGrid::new(points, radius).pairs(queries, radius, ignore_identical)
}

/// Capped ball query (PhysNeRF semantics) with a grid built for this call; see
/// [`NeighborGrid::ball_query`].
pub fn ball_query(
    points: &[[f32; 3]],
    queries: &[[f32; 3]],
    radius: f32,
    k: usize,
    selection: NeighborSelection,
) -> BallQuery {
    NeighborGrid::new(points, radius).ball_query(queries, radius, k, selection)
}

/// A stable counting sort of `keys` into `buckets` buckets (`bucket` of a key: its bucket, or
/// `None` to leave it out): each bucket's first position in the order (`buckets + 1` offsets)
/// and the keys' indices by bucket, ascending within a bucket.
pub(crate) fn counting_sort<K: Copy>(
    keys: &[K],
    buckets: usize,
    bucket: impl Fn(K) -> Option<usize>,
) -> (Vec<u32>, Vec<u32>) {
    let mut starts = vec![0u32; buckets + 1];
    for b in keys.iter().filter_map(|&k| bucket(k)) {
        starts[b + 1] += 1;
    }
    for b in 0..buckets {
        starts[b + 1] += starts[b];
    }
    let mut fill = starts.clone();
    let mut order = vec![0u32; starts[buckets] as usize];
    for (i, &k) in keys.iter().enumerate() {
        if let Some(b) = bucket(k) {
            order[fill[b] as usize] = i as u32;
            fill[b] += 1;
        }
    }
    (starts, order)
}

/// The lowest and highest coordinate on each axis of `points` (`lo > hi` when there are none).
pub(crate) fn bounding_box<'a, T: Float + 'a>(
    points: impl IntoIterator<Item = &'a [T; 3]>,
) -> ([T; 3], [T; 3]) {
    let mut lo = [T::infinity(); 3];
    let mut hi = [T::neg_infinity(); 3];
    for p in points {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    (lo, hi)
}

/// The capped ball query of [`NeighborGrid::ball_query`] in any float type, exact and without a
/// grid: every point against every query, after a bounding-box test that skips queries far from
/// all points. The grid's oracle in tests, and the search of f64 renders (precision checks).
pub fn exact_ball_query<T: Float + Send + Sync>(
    points: &[[T; 3]],
    queries: &[[T; 3]],
    radius: T,
    k: usize,
    selection: NeighborSelection,
) -> BallQuery<T> {
    if k == 0 {
        return BallQuery {
            k,
            idx: Vec::new(),
            dist2: Vec::new(),
            count: vec![0; queries.len()],
        };
    }
    let r2 = radius * radius;
    let (lo, hi) = bounding_box(points);
    let mut idx = vec![-1i32; queries.len() * k];
    let mut d2 = vec![T::zero(); queries.len() * k];
    let count = idx
        .par_chunks_mut(k)
        .zip(d2.par_chunks_mut(k))
        .zip(queries.par_iter())
        .map(|((idx, d2), &q)| {
            if (0..3).any(|a| q[a] < lo[a] - radius || q[a] > hi[a] + radius) {
                return 0;
            }
            let mut inside: Vec<(usize, T)> = Vec::new();
            for (i, &p) in points.iter().enumerate() {
                let d = dist2(p, q);
                if d < r2 {
                    inside.push((i, d));
                    if selection == NeighborSelection::LowestIndex && inside.len() == k {
                        break;
                    }
                }
            }
            if selection == NeighborSelection::Nearest {
                inside.sort_by(|a, b| {
                    a.1.partial_cmp(&b.1)
                        .unwrap_or(std::cmp::Ordering::Equal)
                        .then(a.0.cmp(&b.0))
                });
                inside.truncate(k);
            }
            for (s, &(i, d)) in inside.iter().enumerate() {
                idx[s] = i as i32;
                d2[s] = d;
            }
            inside.len() as u32
        })
        .collect();
    BallQuery {
        k,
        idx,
        dist2: d2,
        count,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn cloud(n: usize, extent: f32, seed: u64) -> Vec<[f32; 3]> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                [
                    rng.random_range(-extent..extent),
                    rng.random_range(-extent..extent),
                    rng.random_range(-extent..extent),
                ]
            })
            .collect()
    }

    /// All-pairs version of `pairs`.
    fn brute_pairs(points: &[[f32; 3]], queries: &[[f32; 3]], r: f32, ignore: bool) -> PairList {
        let mut out = PairList {
            offsets: vec![0],
            ..PairList::default()
        };
        for &q in queries {
            for (i, &p) in points.iter().enumerate() {
                if ignore && p.map(f32::to_bits) == q.map(f32::to_bits) {
                    continue;
                }
                let d = dist2(p, q);
                if d <= r * r {
                    out.indices.push(i as u32);
                    out.dist2.push(d);
                }
            }
            out.offsets.push(out.indices.len());
        }
        out
    }

    fn check_all(points: &[[f32; 3]], queries: &[[f32; 3]], r: f32, k: usize) {
        for ignore in [false, true] {
            assert_eq!(
                fixed_radius_pairs(points, queries, r, ignore),
                brute_pairs(points, queries, r, ignore),
                "pairs, ignore_identical = {ignore}"
            );
        }
        for sel in [NeighborSelection::LowestIndex, NeighborSelection::Nearest] {
            assert_eq!(
                ball_query(points, queries, r, k, sel),
                exact_ball_query(points, queries, r, k, sel),
                "ball query {sel:?}"
            );
        }
    }

    #[test]
    fn random_clouds_match_brute_force() {
        let points = cloud(3000, 1.0, 1);
        let queries = cloud(1500, 1.2, 2);
        check_all(&points, &queries, 0.1125, 20);
        check_all(&points, &queries, 0.225, 20);
        check_all(&points, &queries, 0.3, 5);
    }

    #[test]
    fn lattices_with_tied_distances_match_brute_force() {
        // PhysNeRF's case: K = 20 of ~380 particles in the ball, the K-th a third of the radius
        // away, many exactly tied distances on a lattice (ties go to the lower index)
        let lattice: Vec<[f32; 3]> = (0..13 * 13 * 13)
            .map(|i| [i % 13, i / 13 % 13, i / 169].map(|c| 0.05 * c as f32 - 0.3))
            .collect();
        let mut queries = lattice[..400].to_vec();
        queries.extend(cloud(800, 0.45, 8));
        check_all(&lattice, &queries, 0.225, 20);
        check_all(&lattice, &queries, 0.225, 1);
        check_all(&lattice, &queries, 0.1, 60);
    }

    #[test]
    fn no_slots_is_an_empty_answer_per_query() {
        let points = cloud(50, 0.5, 4);
        for sel in [NeighborSelection::LowestIndex, NeighborSelection::Nearest] {
            let q = exact_ball_query(&points, &points[..7], 0.2, 0, sel);
            assert_eq!((q.num_queries(), q.idx.len()), (7, 0));
            assert!(q.neighbors(6).is_empty());
        }
    }

    #[test]
    fn points_as_their_own_queries() {
        // the DLF case: fluid→fluid, the particle itself is dropped only with ignore_identical
        let points = cloud(2000, 0.5, 3);
        let with_self = fixed_radius_pairs(&points, &points, 0.1125, false);
        let without = fixed_radius_pairs(&points, &points, 0.1125, true);
        assert_eq!(with_self.num_pairs(), without.num_pairs() + points.len());
        check_all(&points, &points, 0.1125, 20);
    }

    #[test]
    fn degenerate_inputs() {
        let q = cloud(50, 1.0, 4);
        // no particles
        check_all(&[], &q, 0.2, 20);
        let empty = ball_query(&[], &q, 0.2, 20, NeighborSelection::LowestIndex);
        assert!(empty.idx.iter().all(|&i| i == -1) && empty.count.iter().all(|&c| c == 0));
        // no queries
        check_all(&q, &[], 0.2, 20);
        // every particle in one cell
        let tight = cloud(500, 0.01, 5);
        check_all(&tight, &q, 0.2, 20);
        check_all(&tight, &tight, 0.2, 20);
        // queries far outside the cloud, and at huge coordinates
        let far: Vec<[f32; 3]> = vec![[100.0, 0.0, 0.0], [-1e6, 3.0, 2.0], [0.0, 1e7, -1e7]];
        check_all(&q, &far, 0.2, 20);
        // duplicates: identical points are all found, and all dropped by ignore_identical
        let mut dup = cloud(100, 0.2, 6);
        dup.extend_from_slice(&dup.clone());
        dup.push(dup[0]);
        check_all(&dup, &dup, 0.15, 20);
        let p = fixed_radius_pairs(&dup, &dup[..1], 0.15, true);
        assert!(!p.indices.contains(&0) && !p.indices.contains(&100) && !p.indices.contains(&200));
        // non-finite particles are never neighbours, non-finite queries have none
        let mut bad = cloud(100, 0.2, 7);
        bad[3] = [f32::NAN, 0.0, 0.0];
        bad[4] = [f32::INFINITY, 0.0, 0.0];
        check_all(&bad, &[[0.0; 3], [f32::NAN, 0.0, 0.0]], 0.3, 20);
    }

    #[test]
    fn boundary_inclusion_rules() {
        // d² = r² exactly: counted by pairs (≤), not by the ball query (<)
        let r = 0.5f32;
        let points = [[0.5f32, 0.0, 0.0], [0.0, 0.25, 0.0]];
        let q = [[0.0f32; 3]];
        assert_eq!(
            fixed_radius_pairs(&points, &q, r, false).indices,
            vec![0, 1]
        );
        assert_eq!(
            ball_query(&points, &q, r, 4, NeighborSelection::LowestIndex).neighbors(0),
            &[1]
        );
    }

    #[test]
    fn lowest_index_differs_from_nearest_and_both_are_capped() {
        // a line of points, the far ones with low indices
        let points: Vec<[f32; 3]> = (0..30).map(|i| [0.3 - 0.01 * i as f32, 0.0, 0.0]).collect();
        let q = [[0.0f32; 3]];
        let low = ball_query(&points, &q, 0.245, 5, NeighborSelection::LowestIndex);
        let near = ball_query(&points, &q, 0.245, 5, NeighborSelection::Nearest);
        assert_eq!(low.neighbors(0), &[6, 7, 8, 9, 10]);
        assert_eq!(near.neighbors(0), &[29, 28, 27, 26, 25]);
        assert_eq!(low.count, vec![5]);
    }
}
