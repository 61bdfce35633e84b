//! The capped ball query on the GPU (`neurofluid_core::device_search`) against the host's
//! all-pairs search (`exact_ball_query`), both selection rules, on the test device
//! (`NEUROFLUID_TEST_DEVICE=wgpu`: lavapipe without a GPU). On a lattice, where every squared
//! distance is exact in f32 (so fused multiply-adds cannot move one), the slots must be equal,
//! ties in distance broken by index included; on random points a differing slot must be one a
//! rounding can move (a point within 10⁻⁵ of the radius, or of the K-th kept distance). On a CPU
//! backend the GPU search declines (`None`) and the host search runs.

use neurofluid_core::device::{is_host, test_device};
use neurofluid_core::device_search::ball_query;
use neurofluid_core::neighbors::{BallQuery, NeighborSelection, exact_ball_query};
use neurofluid_core::transfer;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const SELECTIONS: [NeighborSelection; 2] =
    [NeighborSelection::LowestIndex, NeighborSelection::Nearest];

/// The GPU search's result; `None` on a CPU test device (checked to decline there).
fn on_device(
    points: &[[f32; 3]],
    queries: &[[f32; 3]],
    r: f32,
    k: usize,
    sel: NeighborSelection,
) -> Option<BallQuery<f32>> {
    let device = test_device();
    let result = ball_query(&device, points, queries, r, k, sel);
    if is_host(&device) {
        assert!(result.is_none(), "a CPU backend has no GPU search");
        return None;
    }
    Some(
        result
            .expect("a GPU device runs the search")
            .expect("the kernel runs"),
    )
}

/// Points on a 1/16 lattice of the unit cube (repeats allowed: exact ties) and queries on the
/// 1/32 lattice around it, some outside the points' box by more than the radius.
fn lattice(rng: &mut ChaCha8Rng, n: usize, q: usize) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let points = (0..n)
        .map(|_| [0, 1, 2].map(|_| rng.random_range(0..=16) as f32 / 16.0))
        .collect();
    let queries = (0..q)
        .map(|_| [0, 1, 2].map(|_| rng.random_range(-12..=44) as f32 / 32.0))
        .collect();
    (points, queries)
}

#[test]
fn on_a_lattice_the_slots_are_the_hosts() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let (points, queries) = lattice(&mut rng, 3000, 2000);
    // r² = 0.0225 lies between the achievable squared distances 23/1024 and 24/1024
    let (r, k) = (0.15f32, 16);
    for sel in SELECTIONS {
        let host = exact_ball_query(&points, &queries, r, k, sel);
        let capped = host.count.iter().filter(|&&c| c as usize == k).count();
        let partial = host
            .count
            .iter()
            .filter(|&&c| c > 0 && (c as usize) < k)
            .count();
        let empty = host.count.iter().filter(|&&c| c == 0).count();
        assert!(
            capped > 200 && partial > 50 && empty > 50,
            "the case holds capped, partial and empty queries ({capped}, {partial}, {empty})"
        );
        let Some(dev) = on_device(&points, &queries, r, k, sel) else {
            continue;
        };
        for q in 0..queries.len() {
            let s = q * k..(q + 1) * k;
            assert_eq!(
                dev.idx[s.clone()],
                host.idx[s.clone()],
                "{sel:?}, query {q}"
            );
            assert_eq!(dev.dist2[s.clone()], host.dist2[s], "{sel:?}, query {q}");
        }
        assert_eq!(dev.count, host.count, "{sel:?}");
    }
}

#[test]
fn on_random_points_only_a_rounding_can_move_a_slot() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let points: Vec<[f32; 3]> = (0..4000)
        .map(|_| [0, 1, 2].map(|_| rng.random_range(-0.7f32..0.7)))
        .collect();
    let queries: Vec<[f32; 3]> = (0..3000)
        .map(|_| [0, 1, 2].map(|_| rng.random_range(-0.9f32..0.9)))
        .collect();
    let (r, k) = (0.225f32, 20);
    let r2 = f64::from(r * r);
    let exact_d2 = |i: i32, q: usize| -> f64 {
        let p = points[i as usize];
        (0..3)
            .map(|a| (f64::from(p[a]) - f64::from(queries[q][a])).powi(2))
            .sum()
    };
    for sel in SELECTIONS {
        let host = exact_ball_query(&points, &queries, r, k, sel);
        let Some(dev) = on_device(&points, &queries, r, k, sel) else {
            continue;
        };
        let mut moved = 0;
        for q in 0..queries.len() {
            let s = q * k..(q + 1) * k;
            if dev.idx[s.clone()] == host.idx[s.clone()] {
                for (a, b) in dev.dist2[s.clone()].iter().zip(&host.dist2[s.clone()]) {
                    assert!(
                        (a - b).abs() <= 4.0 * f32::EPSILON * b.max(1e-12),
                        "query {q}"
                    );
                }
                continue;
            }
            moved += 1;
            // the K-th kept distance on the host: a point at it can swap with another
            let kth = host.idx[s.clone()]
                .iter()
                .filter(|&&i| i >= 0)
                .map(|&i| exact_d2(i, q))
                .fold(0.0f64, f64::max);
            let (h, d): (Vec<i32>, Vec<i32>) = (host.idx[s.clone()].to_vec(), dev.idx[s].to_vec());
            for &i in h
                .iter()
                .filter(|i| **i >= 0 && !d.contains(i))
                .chain(d.iter().filter(|i| **i >= 0 && !h.contains(i)))
            {
                let di = exact_d2(i, q);
                let near_radius = (di - r2).abs() <= 1e-5 * r2;
                let near_kth = sel == NeighborSelection::Nearest && (di - kth).abs() <= 1e-5 * r2;
                assert!(
                    near_radius || near_kth,
                    "{sel:?}, query {q}: point {i} at d² {di} (r² {r2}, K-th {kth})"
                );
            }
        }
        eprintln!(
            "{sel:?}: {moved} of {} queries differ from the host",
            queries.len()
        );
        assert!(
            moved <= queries.len() / 100,
            "{sel:?}: {moved} queries moved"
        );
    }
}

#[test]
fn edge_cases_and_the_copies_it_makes() {
    let points = vec![[0.0f32, 0.0, 0.0], [0.05, 0.0, 0.0], [0.0, 0.0, 0.05]];
    // a query on a point (d² = 0 is kept), one between them, one far away
    let queries = vec![[0.0f32, 0.0, 0.0], [0.02, 0.0, 0.02], [5.0, 5.0, 5.0]];
    for sel in SELECTIONS {
        for k in [1, 2, 8] {
            let host = exact_ball_query(&points, &queries, 0.1, k, sel);
            let before = transfer::counts();
            let Some(dev) = on_device(&points, &queries, 0.1, k, sel) else {
                continue;
            };
            let copies = transfer::counts().since(before);
            assert_eq!(
                (copies.uploads, copies.reads),
                (3, 1),
                "{}",
                copies.describe()
            );
            assert_eq!(copies.read_bytes, 2 * 4 * (queries.len() * k) as u64);
            assert_eq!(
                (dev.idx, dev.dist2, dev.count),
                (host.idx, host.dist2, host.count),
                "{sel:?}, k {k}"
            );
        }
        let none = on_device(&points, &[], 0.1, 4, sel);
        assert!(none.is_none_or(|b| b.idx.is_empty() && b.count.is_empty()));
        let no_points = on_device(&[], &queries, 0.1, 4, sel);
        assert!(no_points.is_none_or(|b| b.idx == vec![-1; 12] && b.count == vec![0; 3]));
    }
}
