//! The capped ball query in the working precision: f32 goes through
//! `neurofluid_core::neighbors` (uniform grid); f64 (precision tests) through its exact
//! all-pairs search (`exact_ball_query`), with the same semantics: `d² = (dx² + dy²) + dz² < r²`
//! strict, `r² = r·r` in the working precision, K lowest indices (or K nearest), empty slots
//! `idx = −1`, `d² = 0`.

use neurofluid_core::device_search;
use neurofluid_core::neighbors::{BallQuery, NeighborGrid, NeighborSelection, exact_ball_query};

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

/// `v` in f32 (exact for T = f32).
fn f32s<T: Real>(v: &[[T; 3]]) -> Vec<[f32; 3]> {
    v.iter().map(|p| p.map(|c| c.f64() as f32)).collect()
}

/// An f32 search's result in the working precision.
fn of_f32<T: Real>(bq: BallQuery<f32>) -> Neighbors<T> {
    Neighbors {
        k: bq.k,
        idx: bq.idx,
        dist2: bq.dist2.into_iter().map(|d| T::of(f64::from(d))).collect(),
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
        let (p, q) = (f32s(points), f32s(queries));
        let r = radius as f32;
        of_f32(NeighborGrid::new(&p, r).ball_query(&q, r, k, selection))
    } else {
        let bq = exact_ball_query(points, queries, T::of(radius), k, selection);
        Neighbors {
            k,
            idx: bq.idx,
            dist2: bq.dist2,
        }
    }
}

/// [`ball_query`] as a kernel on `device`'s GPU (`neurofluid_core::device_search`); `None` where
/// the device is not a GPU or the precision not f32.
pub fn ball_query_on_gpu<T: Real>(
    device: &burn::prelude::Device,
    points: &[[T; 3]],
    queries: &[[T; 3]],
    radius: f64,
    k: usize,
    selection: NeighborSelection,
) -> Option<Result<Neighbors<T>, String>> {
    if T::DTYPE != burn::tensor::DType::F32 {
        return None;
    }
    let (p, q) = (f32s(points), f32s(queries));
    device_search::ball_query(device, &p, &q, radius as f32, k, selection)
        .map(|found| found.map(of_f32))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn the_f32_path_matches_the_exact_search() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let pts: Vec<[f32; 3]> = (0..2000)
            .map(|_| [rng.random::<f32>(), rng.random(), rng.random()])
            .collect();
        let qs: Vec<[f32; 3]> = (0..300)
            .map(|_| [rng.random::<f32>(), rng.random(), rng.random()])
            .collect();
        for sel in [NeighborSelection::LowestIndex, NeighborSelection::Nearest] {
            let a = ball_query(&pts, &qs, 0.1, 20, sel);
            let b = exact_ball_query(&pts, &qs, 0.1, 20, sel);
            assert_eq!(a.idx, b.idx);
            assert_eq!(a.dist2, b.dist2);
        }
    }
}
