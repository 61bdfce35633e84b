//! The capped ball query in the working precision: f32 goes through
//! `neurofluid_core::neighbors` (uniform grid); f64 (precision tests) uses an exact brute-force
//! search with the same semantics: `d² = (dx² + dy²) + dz² < r²` strict, `r² = r·r` in the
//! working precision, K lowest indices (or K nearest), empty slots `idx = −1`, `d² = 0`.

use neurofluid_core::neighbors::{NeighborGrid, NeighborSelection};
use rayon::prelude::*;

use crate::real::Real;

/// Ball-query result in the working precision T.
#[derive(Debug, Clone)]
pub struct Neighbors<T> {
    /// Slots per query.
    pub k: usize,
    /// `[queries × k]` particle indices, −1 in empty slots.
    pub idx: Vec<i32>,
    /// `[queries × k]` squared distances, 0 in empty slots.
    pub dist2: Vec<T>,
}

impl<T: Real> Neighbors<T> {
    /// Number of queries.
    pub fn len(&self) -> usize {
        self.idx.len().checked_div(self.k).unwrap_or(0)
    }

    /// True when there are no queries.
    pub fn is_empty(&self) -> bool {
        self.idx.is_empty()
    }

    /// Valid slots of query q: `dist2 ≠ 0` (the reference's definition).
    pub fn num_valid(&self, q: usize) -> usize {
        self.dist2[q * self.k..(q + 1) * self.k]
            .iter()
            .filter(|&&d| d != T::zero())
            .count()
    }

    /// The occupancy gate of query q: every slot valid.
    pub fn gated(&self, q: usize) -> bool {
        self.num_valid(q) == self.k
    }

    /// Sum of the filled slots' indices of query q (a cheap fingerprint of the selection).
    pub fn index_sum(&self, q: usize) -> u64 {
        self.idx[q * self.k..(q + 1) * self.k]
            .iter()
            .filter(|&&i| i >= 0)
            .map(|&i| i as u64)
            .sum()
    }
}

/// Ball query of `queries` against `points` in the working precision (see the module docs).
pub fn ball_query<T: Real>(
    points: &[[T; 3]],
    queries: &[[T; 3]],
    radius: f64,
    k: usize,
    selection: NeighborSelection,
) -> Neighbors<T> {
    if T::DTYPE == burn::tensor::DType::F32 {
        let p: Vec<[f32; 3]> = points.iter().map(|v| v.map(|c| c.f64() as f32)).collect();
        let q: Vec<[f32; 3]> = queries.iter().map(|v| v.map(|c| c.f64() as f32)).collect();
        let r = radius as f32;
        let bq = NeighborGrid::new(&p, r).ball_query(&q, r, k, selection);
        Neighbors {
            k,
            idx: bq.idx,
            dist2: bq.dist2.into_iter().map(|d| T::of(d as f64)).collect(),
        }
    } else {
        brute_force(points, queries, radius, k, selection)
    }
}

fn dist2<T: Real>(a: [T; 3], b: [T; 3]) -> T {
    let dx = a[0] - b[0];
    let dy = a[1] - b[1];
    let dz = a[2] - b[2];
    dx * dx + dy * dy + dz * dz
}

/// Exact all-pairs ball query in T (with a bounding-box pre-filter); for small test cases.
pub fn brute_force<T: Real>(
    points: &[[T; 3]],
    queries: &[[T; 3]],
    radius: f64,
    k: usize,
    selection: NeighborSelection,
) -> Neighbors<T> {
    let r = T::of(radius);
    let r2 = r * r;
    let mut lo = [T::infinity(); 3];
    let mut hi = [T::neg_infinity(); 3];
    for p in points {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let mut idx = vec![-1i32; queries.len() * k];
    let mut d2 = vec![T::zero(); queries.len() * k];
    idx.par_chunks_mut(k.max(1))
        .zip(d2.par_chunks_mut(k.max(1)))
        .zip(queries.par_iter())
        .for_each(|((idx, d2), &q)| {
            if (0..3).any(|a| q[a] < lo[a] - r || q[a] > hi[a] + r) {
                return;
            }
            let mut found: Vec<(usize, T)> = Vec::new();
            for (i, &p) in points.iter().enumerate() {
                let d = dist2(p, q);
                if d < r2 {
                    found.push((i, d));
                    if selection == NeighborSelection::LowestIndex && found.len() == k {
                        break;
                    }
                }
            }
            if selection == NeighborSelection::Nearest {
                found.sort_by(|a, b| {
                    a.1.partial_cmp(&b.1)
                        .unwrap_or(std::cmp::Ordering::Equal)
                        .then(a.0.cmp(&b.0))
                });
                found.truncate(k);
            }
            for (s, (i, d)) in found.into_iter().enumerate() {
                idx[s] = i as i32;
                d2[s] = d;
            }
        });
    Neighbors { k, idx, dist2: d2 }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn grid_and_brute_force_agree() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let pts: Vec<[f32; 3]> = (0..2000)
            .map(|_| [rng.random::<f32>(), rng.random(), rng.random()])
            .collect();
        let qs: Vec<[f32; 3]> = (0..300)
            .map(|_| [rng.random::<f32>(), rng.random(), rng.random()])
            .collect();
        for sel in [NeighborSelection::LowestIndex, NeighborSelection::Nearest] {
            let a = ball_query(&pts, &qs, 0.1, 20, sel);
            let b = brute_force(&pts, &qs, 0.1, 20, sel);
            assert_eq!(a.idx, b.idx);
            assert_eq!(a.dist2, b.dist2);
        }
    }
}
