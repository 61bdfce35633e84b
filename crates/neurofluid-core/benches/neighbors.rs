//! Neighbour-search benchmark (issue: foundation).
//!
//! - PhysNeRF ball query: 100k particles (a jittered 2r lattice block), 1M query points spread
//!   over a box 1.5× the block (as NeRF samples are), r = 0.225, K = 20, lowest-index and nearest.
//! - DLF fixed-radius pairs: 30k particles against themselves, R = 0.1125, self excluded.
//!
//! Run: `cargo bench -p neurofluid-core --bench neighbors` (median of 3 after a warm-up).

use std::time::Instant;

use neurofluid_core::neighbors::{NeighborGrid, NeighborSelection};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn lattice(n: usize, rng: &mut ChaCha8Rng) -> Vec<[f32; 3]> {
    let side = (n as f64).cbrt().ceil() as usize;
    (0..n)
        .map(|i| {
            let (x, y, z) = (i % side, i / side % side, i / (side * side));
            [
                x as f32 * 0.05 + rng.random_range(-0.002..0.002),
                y as f32 * 0.05 + rng.random_range(-0.002..0.002),
                z as f32 * 0.05 + rng.random_range(-0.002..0.002),
            ]
        })
        .collect()
}

fn median_secs(mut f: impl FnMut() -> usize) -> (f64, usize) {
    let check = f();
    let mut t: Vec<f64> = (0..3)
        .map(|_| {
            let s = Instant::now();
            assert_eq!(f(), check);
            s.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    (t[1], check)
}

fn main() {
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let threads = rayon::current_num_threads();
    println!("neighbour search, {threads} threads, median of 3");

    let particles = lattice(100_000, &mut rng);
    let extent = 47.0 * 0.05;
    let queries: Vec<[f32; 3]> = (0..1_000_000)
        .map(|_| [0; 3].map(|_| rng.random_range(-0.25 * extent..1.25 * extent)))
        .collect();
    let (build, _) = median_secs(|| NeighborGrid::new(&particles, 0.225).points().len());
    println!("grid build, 100k particles: {:.4} s", build);
    let grid = NeighborGrid::new(&particles, 0.225);
    for sel in [NeighborSelection::LowestIndex, NeighborSelection::Nearest] {
        let (t, filled) = median_secs(|| {
            let q = grid.ball_query(&queries, 0.225, 20, sel);
            q.count.iter().map(|&c| c as usize).sum()
        });
        println!(
            "ball query {sel:?}: 100k particles, 1M queries, r 0.225, K 20: {t:.3} s ({:.2} M queries/s, {:.1} filled slots/query)",
            1.0 / t,
            filled as f64 / 1e6
        );
    }

    let fluid = lattice(30_000, &mut rng);
    let (t, pairs) = median_secs(|| {
        NeighborGrid::new(&fluid, 0.1125)
            .pairs(&fluid, 0.1125, true)
            .num_pairs()
    });
    println!(
        "fixed-radius pairs: 30k particles, R 0.1125, grid build included: {t:.4} s ({:.1} neighbours/particle)",
        pairs as f64 / 3e4
    );
}
