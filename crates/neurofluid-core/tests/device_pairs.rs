//! Fixed-radius pairs found on the GPU (`neurofluid_core::device_pairs`) against the host's grid
//! search (`NeighborGrid::pairs`), on the test device (`NEUROFLUID_TEST_DEVICE=wgpu`: lavapipe
//! without a GPU). Points on a lattice, so every squared distance is exact in f32 and no fused
//! multiply-add can move a pair across the radius: the slots must hold the host's pairs, in
//! its order, with bit-identical points skipped (the lattice repeats points). The gradient of
//! a gather through the slots (the symmetric kernel) against the sum planned from a host copy
//! of the same index, and run twice for the same bits. On a CPU backend the search declines.

use burn::prelude::*;
use neurofluid_core::device::{is_host, test_device};
use neurofluid_core::device_pairs::{
    DevicePairs, device_pairs, device_pairs_from_host, plan_chunks,
};
use neurofluid_core::neighbors::NeighborGrid;
use neurofluid_core::rows::{RowIndex, gather_rows};
use neurofluid_core::transfer::{self, read_vec, upload};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Points on a 1/16 lattice (repeats allowed) spread over `[0, 1]³` and a far-off point.
fn lattice(rng: &mut ChaCha8Rng, n: usize) -> Vec<[f32; 3]> {
    let mut pts: Vec<[f32; 3]> = (0..n)
        .map(|_| [0, 1, 2].map(|_| rng.random_range(0..=16) as f32 / 16.0))
        .collect();
    pts.push([4.0, -3.0, 2.5]);
    pts
}

/// The GPU pairs; `None` on a CPU test device (checked to decline there).
fn on_device(
    points: &[[f32; 3]],
    queries: &[[f32; 3]],
    r: f32,
    symmetric: bool,
    max_slots: usize,
) -> Option<DevicePairs> {
    let device = test_device();
    let found = device_pairs(&device, points, queries, r, true, symmetric, max_slots);
    if is_host(&device) {
        assert!(found.is_none(), "a CPU backend has no GPU search");
        return None;
    }
    Some(found.expect("a GPU device").expect("the kernels run"))
}

fn ints(t: Tensor<1, Int>) -> Vec<i32> {
    read_vec::<i32, 1, Int>(t).expect("read")
}

fn floats<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    read_vec::<f32, D, burn::tensor::Float>(t).expect("read")
}

/// The slots must hold the host's pairs in ascending order, then padding that repeats them.
fn check_against_host(points: &[[f32; 3]], queries: &[[f32; 3]], r: f32, max_slots: usize) {
    let Some(found) = on_device(points, queries, r, false, max_slots) else {
        return;
    };
    let host = NeighborGrid::new(points, r).pairs(queries, r, true);
    assert_eq!(found.counts, host.counts(), "pair counts");
    assert_eq!(found.chunks, plan_chunks(&host.counts(), max_slots));
    let slots = ints(found.slots.clone());
    let real = floats(found.real.clone());
    for ch in &found.chunks {
        for q in ch.q0..ch.q1 {
            let own = &host.indices[host.offsets[q]..host.offsets[q + 1]];
            let at = ch.start + (q - ch.q0) * ch.width;
            for k in 0..ch.width {
                let (slot, is_real) = (slots[at + k], real[at + k]);
                if k < own.len() {
                    assert_eq!(slot as u32, own[k], "query {q} slot {k}");
                    assert_eq!(is_real, 1.0);
                } else {
                    assert_eq!(is_real, 0.0, "query {q} padding {k}");
                    let expected = match own.len() {
                        0 => ((q + k) % points.len()) as u32,
                        c => own[k % c],
                    };
                    assert_eq!(slot as u32, expected, "query {q} padding {k}");
                }
            }
        }
    }
}

#[test]
fn the_slots_hold_the_hosts_pairs_in_order() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let points = lattice(&mut rng, 1500);
    // r² = 0.0225 lies between the lattice's squared distances 23/1024 and 24/1024
    let r = 0.15f32;
    for max_slots in [1 << 20, 4096, 7] {
        check_against_host(&points, &points, r, max_slots);
    }
    // other queries (some far outside the points' grid, some without pairs)
    let queries: Vec<[f32; 3]> = (0..700)
        .map(|_| [0, 1, 2].map(|_| rng.random_range(-40..=60) as f32 / 32.0))
        .collect();
    check_against_host(&points, &queries, r, 4096);
}

#[test]
fn the_symmetric_gradient_is_the_planned_sum_and_the_same_each_run() {
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let points = lattice(&mut rng, 900);
    let r = 0.15f32;
    let Some(found) = on_device(&points, &points, r, true, 5000) else {
        return;
    };
    assert!(found.chunks.len() > 1, "several chunks");
    let device = test_device().autodiff();
    let n = points.len();
    let cols = 5;
    let features: Vec<f32> = (0..n * cols).map(|_| rng.random_range(-1.0..1.0)).collect();
    let slots = ints(found.slots.clone());
    let num_slots = slots.len();
    let weights: Vec<f32> = (0..num_slots * cols)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let gradient = |planned: bool| {
        let f = upload::<2, burn::tensor::Float, _>(
            TensorData::new(features.clone(), [n, cols]),
            &device,
        )
        .require_grad();
        let mut loss = Tensor::<1>::zeros([1], &device);
        for (c, ch) in found.chunks.iter().enumerate() {
            let idx = if planned {
                RowIndex::new(
                    slots[ch.start..ch.start + ch.len()]
                        .iter()
                        .map(|&i| i as usize),
                    &device,
                )
            } else {
                found.chunk_index(c)
            };
            let g = gather_rows(f.clone(), &idx);
            // a weight per slot and column, zero on padding (as the conv's weights are)
            let w = upload::<2, burn::tensor::Float, _>(
                TensorData::new(
                    weights[ch.start * cols..(ch.start + ch.len()) * cols].to_vec(),
                    [ch.len(), cols],
                ),
                &device,
            ) * found.real.clone().narrow(0, ch.start, ch.len());
            loss = loss + (g * w).sum();
        }
        let before = transfer::counts();
        let grads = loss.backward();
        let copies = transfer::counts().since(before);
        if !planned {
            // the kernel's sum: no index read back, no plan uploaded
            assert_eq!(
                (copies.reads, copies.uploads),
                (0, 0),
                "{}",
                copies.describe()
            );
        }
        floats(f.grad(&grads).expect("gradient"))
    };
    let on_kernel = gradient(false);
    let planned = gradient(true);
    let scale = planned.iter().fold(1e-30f32, |m, v| m.max(v.abs()));
    for (a, b) in on_kernel.iter().zip(&planned) {
        assert!((a - b).abs() <= 1e-5 * scale, "{a} against {b}");
    }
    assert!(planned.iter().any(|&v| v != 0.0));
    assert_eq!(on_kernel, gradient(false), "the same bits each run");
}

#[test]
fn one_read_and_the_grids_uploads_per_search() {
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    let points = lattice(&mut rng, 300);
    let before = transfer::counts();
    if on_device(&points, &points, 0.15, true, 1 << 20).is_none() {
        return;
    }
    let copies = transfer::counts().since(before);
    assert_eq!(
        (copies.reads, copies.uploads),
        (1, 6),
        "{}",
        copies.describe()
    );
}

#[test]
fn searches_without_pairs_have_padding_only() {
    let mut rng = ChaCha8Rng::seed_from_u64(14);
    let points = lattice(&mut rng, 200);
    let far: Vec<[f32; 3]> = (0..50).map(|i| [10.0 + i as f32, -7.0, 3.0]).collect();
    for (pts, queries) in [(&points, &far), (&Vec::new(), &points)] {
        let Some(found) = on_device(pts, queries, 0.15, false, 4096) else {
            return;
        };
        assert_eq!(found.counts, vec![0; queries.len()]);
        assert_eq!(found.num_pairs(), 0);
        let slots = found.chunks.iter().map(|c| c.len()).sum::<usize>();
        assert_eq!(slots, queries.len(), "one padding slot a query");
        assert!(floats(found.real).iter().all(|&r| r == 0.0));
    }
}

/// A host search's pairs put in slots on the GPU are the GPU search's slots, padding and chunks
/// to the bit (lattice points, where no rounding can move a pair; the points' own pairs and
/// other queries'), and their symmetric gradient kernel serves the gathers the same way.
#[test]
fn the_hosts_pairs_in_slots_are_the_gpu_searchs() {
    let mut rng = ChaCha8Rng::seed_from_u64(13);
    let points = lattice(&mut rng, 1200);
    let r = 0.15f32;
    let queries: Vec<[f32; 3]> = (0..500)
        .map(|_| [0, 1, 2].map(|_| rng.random_range(-40..=60) as f32 / 32.0))
        .collect();
    let device = test_device();
    for (qs, symmetric, max_slots) in [
        (&points, true, 1usize << 20),
        (&points, true, 3000),
        (&queries, false, 2000),
    ] {
        let host = NeighborGrid::new(&points, r).pairs(qs, r, true);
        let moved = device_pairs_from_host(&device, &host, points.len(), symmetric, max_slots);
        let Some(found) = on_device(&points, qs, r, symmetric, max_slots) else {
            assert!(moved.is_none(), "a CPU backend has no GPU slots");
            return;
        };
        let moved = moved.expect("a GPU device").expect("uploaded");
        assert_eq!(moved.counts, found.counts);
        assert_eq!(moved.chunks, found.chunks);
        assert_eq!(ints(moved.slots.clone()), ints(found.slots.clone()));
        assert_eq!(floats(moved.real.clone()), floats(found.real.clone()));
        if symmetric {
            // the gradient of a gather through each chunk: the same kernel, the same bits
            let autodiff = device.clone().autodiff();
            let grad = |pairs: &DevicePairs| {
                let f = upload::<2, burn::tensor::Float, _>(
                    TensorData::new(
                        (0..points.len() * 2)
                            .map(|i| i as f32 * 0.01)
                            .collect::<Vec<_>>(),
                        [points.len(), 2],
                    ),
                    &autodiff,
                )
                .require_grad();
                let mut loss = Tensor::<1>::zeros([1], &autodiff);
                for c in 0..pairs.chunks.len() {
                    let g = gather_rows(f.clone(), &pairs.chunk_index(c));
                    let ch = pairs.chunks[c];
                    loss = loss + (g * pairs.real.clone().narrow(0, ch.start, ch.len())).sum();
                }
                floats(f.grad(&loss.backward()).expect("gradient"))
            };
            let (a, b) = (grad(&moved), grad(&found));
            assert!(a.iter().any(|&v| v != 0.0));
            assert_eq!(a, b, "the same gradient");
        }
    }
    // a row that is not ascending is refused
    let mut bad = NeighborGrid::new(&points, r).pairs(&points, r, true);
    let q = (0..points.len())
        .find(|&q| bad.offsets[q + 1] - bad.offsets[q] > 1)
        .expect("a query with two pairs");
    bad.indices.swap(bad.offsets[q], bad.offsets[q] + 1);
    let refused = device_pairs_from_host(&device, &bad, points.len(), true, 1 << 20)
        .expect("a GPU device")
        .expect_err("a row out of order");
    assert!(refused.contains(&format!("query {q}")), "{refused}");
}
