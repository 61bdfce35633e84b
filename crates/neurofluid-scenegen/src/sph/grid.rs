//! Uniform-grid fixed-radius neighbour lists (counting sort by cell), deterministic: the
//! neighbours of each query are listed by ascending index.

use glam::DVec3;
use rayon::prelude::*;

/// Points binned into cubic cells of side `cell`, as a CSR over linear cell ids.
#[derive(Debug, Clone)]
pub struct Grid {
    origin: DVec3,
    cell: f64,
    dims: [i64; 3],
    starts: Vec<u32>,
    items: Vec<u32>,
}

impl Grid {
    /// Bins `points` into cells of side `cell` covering `[lo, hi]` (points outside are clamped
    /// into the border cells, which keeps the search exact because it checks distances).
    pub fn build(points: &[DVec3], cell: f64, lo: DVec3, hi: DVec3) -> Self {
        let origin = lo - DVec3::splat(cell);
        let ext = hi - origin + DVec3::splat(cell);
        let dims = [
            ((ext.x / cell).ceil() as i64).max(1),
            ((ext.y / cell).ceil() as i64).max(1),
            ((ext.z / cell).ceil() as i64).max(1),
        ];
        let ncell = (dims[0] * dims[1] * dims[2]) as usize;
        let mut g = Self {
            origin,
            cell,
            dims,
            starts: vec![0; ncell + 1],
            items: vec![0; points.len()],
        };
        let ids: Vec<usize> = points.iter().map(|p| g.linear(g.coords(*p))).collect();
        for &c in &ids {
            g.starts[c + 1] += 1;
        }
        for c in 0..ncell {
            g.starts[c + 1] += g.starts[c];
        }
        let mut fill = g.starts.clone();
        for (i, &c) in ids.iter().enumerate() {
            g.items[fill[c] as usize] = i as u32;
            fill[c] += 1;
        }
        g
    }

    fn coords(&self, p: DVec3) -> [i64; 3] {
        let q = (p - self.origin) / self.cell;
        [
            (q.x.floor() as i64).clamp(0, self.dims[0] - 1),
            (q.y.floor() as i64).clamp(0, self.dims[1] - 1),
            (q.z.floor() as i64).clamp(0, self.dims[2] - 1),
        ]
    }

    fn linear(&self, c: [i64; 3]) -> usize {
        ((c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0]) as usize
    }

    /// Indices of `points` (the set the grid was built from) within `radius` (≤ the cell size)
    /// of `q`, appended to `out` in ascending order; `skip` excludes one index (the query itself).
    pub fn query(
        &self,
        points: &[DVec3],
        q: DVec3,
        radius: f64,
        skip: Option<u32>,
        out: &mut Vec<u32>,
    ) {
        let c = self.coords(q);
        let start = out.len();
        let r2 = radius * radius;
        for dz in -1..=1 {
            let z = c[2] + dz;
            if z < 0 || z >= self.dims[2] {
                continue;
            }
            for dy in -1..=1 {
                let y = c[1] + dy;
                if y < 0 || y >= self.dims[1] {
                    continue;
                }
                for dx in -1..=1 {
                    let x = c[0] + dx;
                    if x < 0 || x >= self.dims[0] {
                        continue;
                    }
                    let id = self.linear([x, y, z]);
                    for &j in &self.items[self.starts[id] as usize..self.starts[id + 1] as usize] {
                        if Some(j) != skip && (points[j as usize] - q).length_squared() < r2 {
                            out.push(j);
                        }
                    }
                }
            }
        }
        out[start..].sort_unstable();
    }
}

/// Neighbour lists in CSR form.
#[derive(Debug, Clone, Default)]
pub struct Neighbours {
    /// Row offsets, one more than the number of queries.
    pub offsets: Vec<usize>,
    /// Neighbour indices.
    pub indices: Vec<u32>,
}

impl Neighbours {
    /// Neighbours of query `i`.
    pub fn of(&self, i: usize) -> &[u32] {
        &self.indices[self.offsets[i]..self.offsets[i + 1]]
    }

    /// Lists, for every query, the points of `grid` within `radius`, in parallel and in a
    /// deterministic order. With `self_set`, query i skips point i.
    pub fn search(
        grid: &Grid,
        points: &[DVec3],
        queries: &[DVec3],
        radius: f64,
        self_set: bool,
    ) -> Self {
        let rows: Vec<Vec<u32>> = queries
            .par_iter()
            .enumerate()
            .map(|(i, q)| {
                let mut v = Vec::with_capacity(64);
                grid.query(points, *q, radius, self_set.then_some(i as u32), &mut v);
                v
            })
            .collect();
        let mut offsets = Vec::with_capacity(rows.len() + 1);
        offsets.push(0);
        let mut indices = Vec::with_capacity(rows.iter().map(Vec::len).sum());
        for r in rows {
            indices.extend_from_slice(&r);
            offsets.push(indices.len());
        }
        Self { offsets, indices }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn matches_brute_force() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let pts: Vec<DVec3> = (0..500)
            .map(|_| DVec3::new(rng.random(), rng.random(), rng.random()))
            .collect();
        let grid = Grid::build(&pts, 0.1, DVec3::ZERO, DVec3::ONE);
        let nb = Neighbours::search(&grid, &pts, &pts, 0.1, true);
        for (i, p) in pts.iter().enumerate() {
            let brute: Vec<u32> = (0..pts.len() as u32)
                .filter(|&j| j as usize != i && (pts[j as usize] - *p).length_squared() < 0.01)
                .collect();
            assert_eq!(nb.of(i), brute.as_slice());
        }
    }
}
