//! Particle-set distances, reported in world units × 1000 as NeuroFluid does
//! (25.0 = one particle radius).

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;

/// Summary of the per-particle distances between ground truth and prediction (× 1000).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParticleDistance {
    /// Mean distance × 1000 (the reported figure).
    pub mean: f64,
    /// Median distance × 1000.
    pub median: f64,
    /// Largest distance × 1000.
    pub max: f64,
}

fn summarise(mut d: Vec<f64>) -> ParticleDistance {
    if d.is_empty() {
        return ParticleDistance {
            mean: f64::NAN,
            median: f64::NAN,
            max: f64::NAN,
        };
    }
    let mean = d.iter().sum::<f64>() / d.len() as f64;
    d.sort_by(f64::total_cmp);
    let n = d.len();
    let median = if n % 2 == 1 {
        d[n / 2]
    } else {
        0.5 * (d[n / 2 - 1] + d[n / 2])
    };
    ParticleDistance {
        mean: mean * 1000.0,
        median: median * 1000.0,
        max: d[n - 1] * 1000.0,
    }
}

/// NeuroFluid's particle distance d: for every **ground-truth** particle the Euclidean distance
/// to the nearest **predicted** particle (a KD-tree over the prediction), × 1000.
/// Returns NaN fields when either set is empty or a predicted position is not finite (a
/// diverged prediction has no distance).
pub fn gt_to_pred_distance(gt: &[[f32; 3]], pred: &[[f32; 3]]) -> ParticleDistance {
    summarise(nearest_distances(gt, pred).unwrap_or_default())
}

/// For every point of `from`, the Euclidean distance to the nearest point of `to` (world
/// units); `None` when `to` is empty or holds a non-finite point.
pub fn nearest_distances(from: &[[f32; 3]], to: &[[f32; 3]]) -> Option<Vec<f64>> {
    if to.is_empty() || !to.iter().flatten().all(|v| v.is_finite()) {
        return None;
    }
    let pts: Vec<[f64; 3]> = to.iter().map(|p| p.map(f64::from)).collect();
    let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&pts);
    Some(
        from.par_iter()
            .map(|g| {
                tree.nearest_one::<SquaredEuclidean>(&g.map(f64::from))
                    .distance
                    .sqrt()
            })
            .collect(),
    )
}

/// Index-matched distance: mean over i of ‖pred_i − gt_i‖, × 1000 (both sets in the same order).
///
/// # Panics
/// When the two sets differ in length.
pub fn index_matched_distance(gt: &[[f32; 3]], pred: &[[f32; 3]]) -> ParticleDistance {
    assert_eq!(
        gt.len(),
        pred.len(),
        "index-matched distance needs equal particle counts"
    );
    let d = gt
        .iter()
        .zip(pred)
        .map(|(g, p)| {
            (0..3)
                .map(|a| (g[a] as f64 - p[a] as f64).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .collect();
    summarise(d)
}

/// For every point, the indices of its `k` nearest other points, nearest first (all the others
/// when there are at most `k`); `None` when a point is not finite.
pub fn nearest_others(points: &[[f32; 3]], k: usize) -> Option<Vec<Vec<usize>>> {
    if !points.iter().flatten().all(|v| v.is_finite()) {
        return None;
    }
    let Some(want) = std::num::NonZero::new((k + 1).min(points.len())) else {
        return Some(vec![Vec::new(); points.len()]);
    };
    let pts: Vec<[f64; 3]> = points.iter().map(|p| p.map(f64::from)).collect();
    let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&pts);
    Some(
        pts.par_iter()
            .enumerate()
            .map(|(i, q)| {
                let mut found: Vec<usize> = tree
                    .nearest_n::<SquaredEuclidean>(q, want)
                    .into_iter()
                    .map(|n| n.item as usize)
                    .filter(|&j| j != i)
                    .collect();
                found.truncate(k);
                found
            })
            .collect(),
    )
}

/// The share of `points` with no other point within `reach` (world units): particles alone. A
/// fluid packs its particles two radii apart, so at three radii none of a resting or flowing
/// body is alone, and what is counted is spray. 0 for fewer than two points (none has another to
/// be far from); `None` when a point is not finite.
pub fn alone_share(points: &[[f32; 3]], reach: f64) -> Option<f64> {
    let nearest = nearest_others(points, 1)?;
    let alone = points
        .iter()
        .zip(&nearest)
        .filter(|(p, nb)| {
            nb.first().is_some_and(|&j| {
                let d2: f64 = (0..3).map(|a| f64::from(points[j][a] - p[a]).powi(2)).sum();
                d2 > reach * reach
            })
        })
        .count();
    Some(alone as f64 / points.len().max(1) as f64)
}

/// Where a prediction's far particles lie against the truth, each a share of all predicted
/// particles: what d′ counts, split by place.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct FarSplit {
    /// Outside the truth's footprint: no true particle within the reach horizontally (fluid
    /// spread, or thrown, past where the truth is).
    pub beside: f64,
    /// Over the footprint and higher than every true particle within the reach horizontally
    /// (fluid held up, or thrown, over the truth).
    pub above: f64,
    /// Neither: in the truth's column, below its top (fluid in the truth's gaps or under it).
    pub within: f64,
}

impl FarSplit {
    /// The share of far particles, all places together.
    pub fn total(&self) -> f64 {
        self.beside + self.above + self.within
    }
}

/// The shares of `pred` farther than `reach` from every point of `truth`, split by where they
/// lie ([`FarSplit`]); `up` is the vertical (a unit vector). `None` when either set is empty or
/// holds a non-finite point.
pub fn far_split(
    pred: &[[f32; 3]],
    truth: &[[f32; 3]],
    up: [f32; 3],
    reach: f64,
) -> Option<FarSplit> {
    if pred.is_empty() || !pred.iter().flatten().all(|v| v.is_finite()) {
        return None;
    }
    let nearest = nearest_distances(pred, truth)?;
    let up = up.map(f64::from);
    let height = |p: &[f32; 3]| (0..3).map(|a| f64::from(p[a]) * up[a]).sum::<f64>();
    // horizontal positions: the points moved along `up` onto the plane through the origin
    let flat = |p: &[f32; 3]| {
        let h = height(p);
        [0, 1, 2].map(|a| f64::from(p[a]) - h * up[a])
    };
    let truth_flat: Vec<[f64; 3]> = truth.iter().map(flat).collect();
    let truth_height: Vec<f64> = truth.iter().map(height).collect();
    let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&truth_flat);
    let mut split = FarSplit::default();
    let share = 1.0 / pred.len() as f64;
    for (p, d) in pred.iter().zip(nearest) {
        if d <= reach {
            continue;
        }
        let column = tree.within_unsorted::<SquaredEuclidean>(&flat(p), reach * reach);
        let top = column
            .iter()
            .map(|n| truth_height[n.item as usize])
            .fold(f64::NEG_INFINITY, f64::max);
        if column.is_empty() {
            split.beside += share;
        } else if height(p) > top {
            split.above += share;
        } else {
            split.within += share;
        }
    }
    Some(split)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_non_finite_prediction_has_no_distance() {
        let gt = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0]];
        for bad in [f32::NAN, f32::INFINITY] {
            let pred = [[0.0f32, 0.0, 0.0], [bad, 0.0, 0.0]];
            assert!(gt_to_pred_distance(&gt, &pred).mean.is_nan());
        }
    }
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Brute force: every pair, alone when no other point lies within the reach.
    fn alone_brute(points: &[[f32; 3]], reach: f64) -> f64 {
        let alone = (0..points.len())
            .filter(|&i| {
                (0..points.len()).filter(|&j| j != i).all(|j| {
                    let d2: f64 = (0..3)
                        .map(|a| f64::from(points[i][a] - points[j][a]).powi(2))
                        .sum();
                    d2 > reach * reach
                })
            })
            .count();
        alone as f64 / points.len() as f64
    }

    #[test]
    fn alone_share_matches_brute_force() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for n in [2usize, 3, 40, 300] {
            let pts: Vec<[f32; 3]> = (0..n)
                .map(|_| {
                    [
                        rng.random::<f32>(),
                        rng.random::<f32>(),
                        rng.random::<f32>(),
                    ]
                })
                .collect();
            for reach in [0.05, 0.1, 0.3] {
                let got = alone_share(&pts, reach).unwrap();
                assert!(
                    (got - alone_brute(&pts, reach)).abs() < 1e-12,
                    "n {n} reach {reach}"
                );
            }
        }
    }

    #[test]
    fn a_lattice_has_no_particle_alone_until_one_strays() {
        // a block packed two radii apart (r = 0.025), as the scenes' fluids start
        let mut pts: Vec<[f32; 3]> = (0..216)
            .map(|i| {
                [
                    (i % 6) as f32 * 0.05,
                    (i / 6 % 6) as f32 * 0.05,
                    (i / 36) as f32 * 0.05,
                ]
            })
            .collect();
        assert_eq!(alone_share(&pts, 0.075), Some(0.0));
        pts.push([1.0, 1.0, 1.0]);
        assert_eq!(alone_share(&pts, 0.075), Some(1.0 / 217.0));
        pts.push([f32::NAN, 0.0, 0.0]);
        assert_eq!(alone_share(&pts, 0.075), None);
        assert_eq!(alone_share(&[[0.0; 3]], 0.075), Some(0.0));
    }

    fn brute(gt: &[[f32; 3]], pred: &[[f32; 3]]) -> f64 {
        let s: f64 = gt
            .iter()
            .map(|g| {
                pred.iter()
                    .map(|p| {
                        (0..3)
                            .map(|a| (g[a] as f64 - p[a] as f64).powi(2))
                            .sum::<f64>()
                    })
                    .fold(f64::INFINITY, f64::min)
                    .sqrt()
            })
            .sum();
        1000.0 * s / gt.len() as f64
    }

    #[test]
    fn kd_tree_matches_brute_force() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let mut cloud = |n| -> Vec<[f32; 3]> {
            (0..n)
                .map(|_| {
                    [
                        rng.random_range(-1.0..1.0),
                        rng.random_range(0.0..2.0),
                        rng.random_range(-1.0..1.0),
                    ]
                })
                .collect()
        };
        let gt = cloud(700);
        let pred = cloud(500);
        let d = gt_to_pred_distance(&gt, &pred);
        assert!(
            (d.mean - brute(&gt, &pred)).abs() < 1e-9 * d.mean.max(1.0),
            "{d:?}"
        );
        assert!(d.median <= d.max && d.median > 0.0);
    }

    #[test]
    fn lattices_with_shared_coordinates() {
        // a 13³ lattice (169 particles share every x value) against itself shifted by 1 mm
        let lattice: Vec<[f32; 3]> = (0..13 * 13 * 13)
            .map(|i| {
                [
                    (i % 13) as f32 * 0.05,
                    (i / 13 % 13) as f32 * 0.05,
                    (i / 169) as f32 * 0.05,
                ]
            })
            .collect();
        let shifted: Vec<[f32; 3]> = lattice.iter().map(|p| [p[0], p[1] + 0.001, p[2]]).collect();
        assert_eq!(gt_to_pred_distance(&lattice, &lattice).mean, 0.0);
        let d = gt_to_pred_distance(&lattice, &shifted);
        assert!((d.mean - 1.0).abs() < 1e-3, "{d:?}");
        let m = index_matched_distance(&lattice, &shifted);
        assert!((m.mean - 1.0).abs() < 1e-3 && (m.max - 1.0).abs() < 1e-3);
    }

    #[test]
    fn direction_is_gt_to_pred() {
        // prediction collapsed onto one GT particle: every GT particle measures to it
        let gt = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0]];
        let pred = [[0.0f32, 0.0, 0.0]; 5];
        assert!((gt_to_pred_distance(&gt, &pred).mean - 500.0).abs() < 1e-9);
        assert_eq!(gt_to_pred_distance(&pred, &gt).mean, 0.0);
        assert!(gt_to_pred_distance(&gt, &[]).mean.is_nan());
    }
    #[test]
    fn nearest_others_match_brute_force() {
        let mut rng = 7u64;
        let mut next = || {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (rng >> 40) as f32 / (1u64 << 24) as f32
        };
        let pts: Vec<[f32; 3]> = (0..300).map(|_| [next(), next(), next()]).collect();
        let k = 20;
        let found = nearest_others(&pts, k).unwrap();
        for (i, p) in pts.iter().enumerate() {
            let d2 = |j: usize| (0..3).map(|a| (pts[j][a] - p[a]).powi(2)).sum::<f32>();
            let mut brute: Vec<usize> = (0..pts.len()).filter(|&j| j != i).collect();
            brute.sort_by(|&a, &b| d2(a).total_cmp(&d2(b)));
            assert!(!found[i].contains(&i));
            assert_eq!(found[i].len(), k);
            // the same k distances (ties could swap indices)
            let got: Vec<f32> = found[i].iter().map(|&j| d2(j)).collect();
            let want: Vec<f32> = brute[..k].iter().map(|&j| d2(j)).collect();
            assert_eq!(got, want, "point {i}");
        }
        // fewer points than k: every other point
        let few = nearest_others(&pts[..4], k).unwrap();
        assert!(few.iter().all(|f| f.len() == 3));
        assert!(nearest_others(&[[f32::NAN, 0.0, 0.0]], 3).is_none());
    }

    /// Brute force of [`far_split`] with z up: every pair, distances and columns written out.
    fn far_brute(pred: &[[f32; 3]], truth: &[[f32; 3]], reach: f64) -> FarSplit {
        let dist = |a: &[f32; 3], b: &[f32; 3], axes: &[usize]| -> f64 {
            axes.iter()
                .map(|&k| f64::from(a[k] - b[k]).powi(2))
                .sum::<f64>()
                .sqrt()
        };
        let mut split = FarSplit::default();
        let share = 1.0 / pred.len() as f64;
        for p in pred {
            if truth.iter().all(|t| dist(p, t, &[0, 1, 2]) > reach) {
                let column: Vec<&[f32; 3]> = truth
                    .iter()
                    .filter(|t| dist(p, t, &[0, 1]) <= reach)
                    .collect();
                if column.is_empty() {
                    split.beside += share;
                } else if column.iter().all(|t| p[2] > t[2]) {
                    split.above += share;
                } else {
                    split.within += share;
                }
            }
        }
        split
    }

    #[test]
    fn far_split_matches_brute_force() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut cloud = |n: usize, spread: f32| -> Vec<[f32; 3]> {
            (0..n)
                .map(|_| [0; 3].map(|_| rng.random_range(0.0..spread)))
                .collect()
        };
        for (n, m) in [(1usize, 1usize), (30, 50), (200, 300)] {
            let truth = cloud(n, 0.5);
            let pred = cloud(m, 1.0);
            for reach in [0.05, 0.1, 0.2] {
                let got = far_split(&pred, &truth, [0.0, 0.0, 1.0], reach).unwrap();
                let want = far_brute(&pred, &truth, reach);
                for (g, w) in [
                    (got.beside, want.beside),
                    (got.above, want.above),
                    (got.within, want.within),
                ] {
                    assert!(
                        (g - w).abs() < 1e-12,
                        "n {n} m {m} reach {reach}: {got:?} {want:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn far_particles_are_placed_beside_above_or_within_a_pool() {
        // a pool on the floor of a y-up scene: 10 × 10 particles, one layer at y = 0.1
        let pool: Vec<[f32; 3]> = (0..100)
            .map(|i| [(i % 10) as f32 * 0.05, 0.1, (i / 10) as f32 * 0.05])
            .collect();
        let (up, reach) = ([0.0, 1.0, 0.0], 0.1);
        let at = |p: [f32; 3]| far_split(&[p], &pool, up, reach).unwrap();
        // on the pool: not far
        assert_eq!(at([0.2, 0.12, 0.2]).total(), 0.0);
        // spread past the pool's edge on the floor
        assert_eq!(at([0.9, 0.0, 0.2]).beside, 1.0);
        // held up over the pool
        assert_eq!(at([0.2, 0.5, 0.2]).above, 1.0);
        // a lump in a pool with a hole in its middle and a lid over it
        let mut ring: Vec<[f32; 3]> = pool
            .iter()
            .copied()
            .filter(|p| (p[0] - 0.225).abs() > 0.15 || (p[2] - 0.225).abs() > 0.15)
            .collect();
        ring.push([0.225, 0.6, 0.225]);
        let lump = far_split(&[[0.225, 0.3, 0.225]], &ring, up, reach).unwrap();
        assert_eq!(lump.within, 1.0);
        // half the prediction far: shares of the whole
        let half = far_split(&[[0.2, 0.1, 0.2], [0.2, 0.5, 0.2]], &pool, up, reach).unwrap();
        assert_eq!(
            half,
            FarSplit {
                beside: 0.0,
                above: 0.5,
                within: 0.0
            }
        );
        assert_eq!(far_split(&[[f32::NAN, 0.0, 0.0]], &pool, up, reach), None);
        assert_eq!(far_split(&[], &pool, up, reach), None);
        assert_eq!(far_split(&pool, &[], up, reach), None);
    }
}
