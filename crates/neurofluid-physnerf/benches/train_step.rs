//! One PhysNeRF training step (forward + backward, coarse + fine) with 1024 rays, 64 + 128
//! samples and ~10k particles, on the default CPU device or `--device NAME` (any `--device` name
//! of the trainer); prints rays/s and where the time goes.
//!
//! `cargo bench -p neurofluid-physnerf --bench train_step [-- --device wgpu]` (best of 2 steps after a warm-up;
//! the best rather than the median because the machine is shared). Without `--bench` (as under
//! `cargo test --benches`) it runs one 32-ray step as a smoke test. Off the CPU the stage times
//! are host clocks around asynchronous GPU work (the neighbour search is exact: host work, or a
//! kernel that ends with a read-back); the
//! step, the backward and the MLPs alone end with a read-back, so they are exact. It also
//! prints the step's host–device copies (`neurofluid_core::transfer`: reads and uploads, count
//! and bytes, the closing read-back of the particle gradient's sum included). `--split-rows N`
//! sets the rows per block of the dense layers on an accelerator
//! (`neurofluid_core::dense::set_split_rows`; 0: one matmul over every row), `--matmul f16|bf16`
//! their operands (`neurofluid_core::half_matmul`: the tensor cores; f32 by default),
//! `--search device` puts the ball query on the GPU (`neurofluid_core::device_search`; the host
//! by default; the `neighbours` time then includes the kernel and its read-back).
//! The weights are the reference case's test weights (opaque, textured), the particles a
//! 22×22×21 lattice (spacing 0.05, jitter ±0.003, randomly permuted: 10,164 particles), the
//! camera 4 units away (400×400, as in NeuroFluid), the rays 1024 random pixels of the view.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use burn::prelude::*;
use burn::tensor::{DType, Distribution, Float, TensorData};
use neurofluid_core::camera::Camera;
use neurofluid_core::choice::Choice;
use neurofluid_core::cpu_time::process_cpu_seconds;
use neurofluid_core::device_search::{NeighbourSearch, neighbour_search, set_neighbour_search};
use neurofluid_core::half_matmul::{MatmulOperands, matmul_operands, set_matmul_operands};
use neurofluid_core::transfer::{self, Counts, upload};
use neurofluid_physnerf::{PhysNerf, PhysNerfConfig, RayBatch, Timings};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};

fn best(v: Vec<f64>) -> f64 {
    v.into_iter().fold(f64::INFINITY, f64::min)
}

fn secs(d: Duration) -> f64 {
    d.as_secs_f64()
}

fn main() {
    neurofluid_core::malloc::keep_freed_memory();
    println!(
        "allocator: {}",
        neurofluid_core::malloc::allocator_setting()
    );
    let full = std::env::args().any(|a| a == "--bench");
    let n_rays: usize = if full { 1024 } else { 32 };
    let repeats = if full { 3 } else { 2 };
    let args: Vec<String> = std::env::args().collect();
    let device_name = args
        .iter()
        .position(|a| a == "--device")
        .and_then(|i| args.get(i + 1))
        .map_or("cpu", String::as_str);
    let device = match neurofluid_core::device::parse_device(device_name) {
        Ok(d) => d.autodiff(),
        Err(e) => {
            eprintln!("--device: {e}");
            std::process::exit(2);
        }
    };
    if let Some(rows) = args
        .iter()
        .position(|a| a == "--split-rows")
        .and_then(|i| args.get(i + 1))
    {
        match rows.parse() {
            Ok(r) => neurofluid_core::dense::set_split_rows(r),
            Err(_) => {
                eprintln!("--split-rows: expected a row count, got {rows}");
                std::process::exit(2);
            }
        }
    }
    if let Some(name) = args
        .iter()
        .position(|a| a == "--matmul")
        .and_then(|i| args.get(i + 1))
    {
        match MatmulOperands::parse(name) {
            Ok(m) if m.half().is_some_and(|h| !device.supports_dtype(h)) => {
                println!("--matmul {name}: the device has no {name} type; nothing measured");
                return;
            }
            Ok(m) => set_matmul_operands(m),
            Err(e) => {
                eprintln!("--matmul: {e}");
                std::process::exit(2);
            }
        }
    }
    if let Some(place) = args
        .iter()
        .position(|a| a == "--search")
        .and_then(|i| args.get(i + 1))
    {
        match NeighbourSearch::parse(place) {
            Ok(p) => set_neighbour_search(p),
            Err(e) => {
                eprintln!("--search: {e}");
                std::process::exit(2);
            }
        }
    }
    println!(
        "dense layers on an accelerator: {} rows per block, {} operands; ball query on the {}",
        neurofluid_core::dense::split_rows(),
        matmul_operands().name(),
        neighbour_search().name()
    );
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let mut particles = Vec::new();
    for i in 0..22 {
        for j in 0..22 {
            for k in 0..21 {
                let c = [i as f32 - 10.5, j as f32 - 10.5, k as f32 - 10.0];
                particles.push(c.map(|v| v * 0.05 + rng.random_range(-0.003..0.003)));
            }
        }
    }
    particles.shuffle(&mut rng);
    let n = particles.len();
    let config = PhysNerfConfig {
        near: 3.0,
        far: 5.0,
        ..PhysNerfConfig::default()
    };
    let weights = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data/physnerf/physnerf_cube2197_weights.safetensors");
    let model = PhysNerf::from_nerf_pl(&weights, config, &device, DType::F32).expect("weights");
    let camera = Camera::look_at(
        400,
        400,
        0.36,
        [-2.0, -3.0, 1.9],
        [0.0, 0.0, 0.0],
        [0.0, 0.0, 1.0],
    );
    let pixels: Vec<u32> = (0..n_rays)
        .map(|_| rng.random_range(0..400 * 400))
        .collect();
    let rays = RayBatch::from(&camera.rays(&pixels));
    let flat: Vec<f32> = particles.iter().flatten().copied().collect();
    let target = Tensor::<2>::random([n_rays, 3], Distribution::Uniform(0.0, 1.0), &device);

    let mut steps = Vec::new();
    let mut step_cpu = Vec::new();
    let mut backs = Vec::new();
    let mut stage = Vec::<Timings>::new();
    let mut evaluated = (0, 0);
    let mut copies = Counts::default();
    for it in 0..repeats {
        let p =
            upload::<2, Float, _>(TensorData::new(flat.clone(), [n, 3]), &device).require_grad();
        let before = transfer::counts();
        let c0 = process_cpu_seconds();
        let t0 = Instant::now();
        let out = model.render_rays(&p, &rays, None).expect("render");
        let loss = model.loss(&out, target.clone());
        let t1 = Instant::now();
        let grads = loss.total.backward();
        let g = p.grad(&grads).expect("particle gradient");
        let _ = transfer::read_scalar(g.sum());
        let t2 = Instant::now();
        copies = transfer::counts().since(before);
        evaluated = (
            out.coarse.evaluated,
            out.fine.as_ref().map_or(0, |f| f.evaluated),
        );
        if it > 0 {
            step_cpu.push(process_cpu_seconds() - c0);
            steps.push(secs(t2 - t0));
            backs.push(secs(t2 - t1));
            stage.push(out.timings);
        }
    }
    let step = best(steps);
    let cpu = best(step_cpu);
    let back = best(backs);
    let pick = |f: fn(&Timings) -> Duration| best(stage.iter().map(|t| secs(f(t))).collect());
    let (nb, enc, mlp, comp) = (
        pick(|t| t.neighbors),
        pick(|t| t.encoding),
        pick(|t| t.mlp),
        pick(|t| t.composite),
    );

    // the MLPs alone, forward + backward, on as many rows as the step evaluated
    let mlp_fb = {
        let mut v = Vec::new();
        for it in 0..repeats {
            let t0 = Instant::now();
            let mut total = Tensor::<1>::zeros([1], &device);
            let mut inputs = Vec::new();
            for (net, rows) in [(&model.coarse, evaluated.0), (&model.fine, evaluated.1)] {
                let ex =
                    Tensor::<2>::random([rows, 198], Distribution::Uniform(-1.0, 1.0), &device)
                        .require_grad();
                let ed = Tensor::<2>::random([rows, 54], Distribution::Uniform(-1.0, 1.0), &device);
                let (rgb, sigma) = net.forward(ex.clone(), ed);
                total = total + rgb.sum() + sigma.sum();
                inputs.push(ex);
            }
            let grads = total.backward();
            for ex in inputs {
                let g = ex.grad(&grads).expect("input gradient");
                let _ = transfer::read_scalar(g.sum());
            }
            if it > 0 {
                v.push(secs(t0.elapsed()));
            }
        }
        best(v)
    };
    let fwd = nb + enc + mlp + comp;
    let pct = |x: f64, of: f64| 100.0 * x / of;
    println!(
        "PhysNeRF training step on {device_name}: {} rays, 64 + 128 samples, {n} particles",
        rays.len()
    );
    println!(
        "  samples through the MLPs: coarse {} of {} gated, fine {} of {} gated",
        evaluated.0,
        n_rays * 64,
        evaluated.1,
        n_rays * 192
    );
    println!(
        "  step (forward + backward): {step:.3} s ({cpu:.2} CPU-s)  →  {:.0} rays/s",
        n_rays as f64 / step
    );
    println!(
        "  forward {fwd:.3} s: neighbour search {nb:.3} s ({:.0} %), gather + features + encoding {enc:.3} s ({:.0} %), MLP {mlp:.3} s ({:.0} %), compositing + sampling {comp:.3} s ({:.0} %)",
        pct(nb, fwd),
        pct(enc, fwd),
        pct(mlp, fwd),
        pct(comp, fwd)
    );
    println!("  backward {back:.3} s");
    println!("  host–device copies per step: {}", copies.describe());
    println!(
        "  MLPs alone (forward + backward on the same rows): {mlp_fb:.3} s = {:.0} % of the step; everything else (neighbour search, features, encodings, compositing, sampling and their backward): {:.3} s = {:.0} %",
        pct(mlp_fb, step),
        step - mlp_fb,
        pct(step - mlp_fb, step)
    );
}
