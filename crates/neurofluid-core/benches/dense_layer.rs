//! One dense layer `relu(x·W + b)` forward and backward on the renderer's shapes: Burn's flex ops
//! (`Linear` + ReLU, Burn's autodiff; its matmul is the `gemm` crate) against the host dense
//! layer (`neurofluid_core::dense::linear`, the host matmul), f32, with GFLOP/s.
//!
//! Shapes: the paper's fine network (≈152k gated samples of 1,024 rays, width 256), its coarse
//! one (≈35k), the quick configs' width 128 (16k samples of 256 rays), and the σ head (256 → 1).
//!
//! Run: `cargo bench -p neurofluid-core --bench dense_layer` (best of 3 after a warm-up). Without
//! `--bench` (as under `cargo test --benches`) it runs one small shape once as a smoke test.

use std::time::Instant;

use burn::nn::LinearConfig;
use burn::prelude::*;
use burn::tensor::Distribution;
use neurofluid_core::dense::{Activation, linear};
use neurofluid_core::transfer::read_scalar;

/// Best wall time of `f` over `repeats` runs after one warm-up.
fn best(repeats: usize, mut f: impl FnMut()) -> f64 {
    f();
    (0..repeats)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

fn main() {
    neurofluid_core::malloc::keep_freed_memory();
    let full = std::env::args().any(|a| a == "--bench");
    let shapes: &[(usize, usize, usize)] = if full {
        &[
            (152_000, 256, 256),
            (35_000, 256, 256),
            (16_000, 128, 128),
            (152_000, 256, 1),
        ]
    } else {
        &[(500, 16, 8)]
    };
    let repeats = if full { 3 } else { 1 };
    let device = Device::flex().autodiff();
    println!(
        "allocator: {}",
        neurofluid_core::malloc::allocator_setting()
    );
    println!("| rows | in → out | Burn fwd | host fwd | Burn fwd+bwd | host fwd+bwd |");
    println!("|---:|---|---:|---:|---:|---:|");
    for &(m, k, n) in shapes {
        let layer = LinearConfig::new(k, n).init(&device);
        let x = Tensor::<2>::random([m, k], Distribution::Normal(0.0, 1.0), &device).require_grad();
        let run = |host: bool, backward: bool| {
            let y = if host {
                linear(&layer, x.clone(), Activation::Relu)
            } else {
                Activation::Relu.apply(layer.forward(x.clone()))
            };
            if backward {
                let g = y.sum().backward();
                let _ = read_scalar(x.grad(&g).expect("input gradient").sum());
            } else {
                let _ = read_scalar(y.sum());
            }
        };
        let flop = 2.0 * (m * k * n) as f64;
        let rate = |secs: f64, passes: f64| passes * flop / secs / 1e9;
        let [bf, hf] = [false, true].map(|h| best(repeats, || run(h, false)));
        let [bb, hb] = [false, true].map(|h| best(repeats, || run(h, true)));
        println!(
            "| {m} | {k} → {n} | {bf:.3} s ({:.0} GFLOP/s) | {hf:.3} s ({:.0}) | {bb:.3} s ({:.0}) | {hb:.3} s ({:.0}) |",
            rate(bf, 1.0),
            rate(hf, 1.0),
            rate(bb, 3.0),
            rate(hb, 3.0)
        );
    }
}
