//! One DLF step on the CPU (or `--device NAME`, any `--device` name of the trainer): forward, and forward+backward of DLF's loss, at 2k/8k/32k fluid
//! particles (the reference harness's `bench` scenes: a lattice block 5 cm above the floor of a
//! closed box with DLF-density walls, v = (0.3, 0, 0.2), jitter 2 mm). One warm-up, then the
//! median of `--repeats` runs, wall and process CPU time (all threads) with the 1-minute load
//! average; a per-phase breakdown of one forward step at the largest size follows. Per size it
//! also prints the host–device copies of one forward and one forward+backward step
//! (`neurofluid_core::transfer`: reads and uploads, count and bytes, the closing read-back that
//! ends each timed step included).
//!
//! On a GPU the step's geometry is made in slots there (`ConvGeometry::on_device`, as `DlfNet`
//! makes it without viscosity): the pairs by the host's grid and uploaded, or with `--search
//! device` found on the GPU (`neighbour_search = "device"`, `neurofluid_core::device_pairs`); the
//! mapping one kernel (`neurofluid_dlf::device_cells`). The phases then time the pairs and the
//! mapping.
//!
//! `cargo bench --profile dev -p neurofluid-dlf --bench dlf_step -- [--repeats 5] [--sizes 2000 8000 32000] [--device wgpu] [--search device]`
//! (the dev profile builds every dependency at opt-level 3; `cargo bench` alone uses release).

use std::path::{Path, PathBuf};
use std::time::Instant;

use burn::prelude::*;
use neurofluid_core::choice::Choice;
use neurofluid_core::cpu_time::process_cpu_seconds;
use neurofluid_core::device_pairs::{device_pairs, device_pairs_from_host};
use neurofluid_core::device_search::{NeighbourSearch, neighbour_search, set_neighbour_search};
use neurofluid_core::neighbors::NeighborGrid;
use neurofluid_core::transfer::{self, Counts};
use neurofluid_dlf::geometry::{ConvGeometry, build_host_geometry, chunk_slots, search_radius};
use neurofluid_dlf::net::{points_tensor, tensor_points};
use neurofluid_dlf::scene::{block_in_box, dlf_wall_spacing};
use neurofluid_dlf::{DlfConfig, DlfNet, dlf_step_loss, load_dlf};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn time<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let t = Instant::now();
    let out = f();
    (out, t.elapsed().as_secs_f64())
}

/// Median wall and CPU seconds of `repeats` calls.
fn measure(repeats: usize, mut f: impl FnMut()) -> (f64, f64) {
    let mut wall = Vec::new();
    let mut cpu = Vec::new();
    for _ in 0..repeats {
        let c0 = process_cpu_seconds();
        let t = Instant::now();
        f();
        wall.push(t.elapsed().as_secs_f64());
        cpu.push(process_cpu_seconds() - c0);
    }
    (median(wall), median(cpu))
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next().map(str::to_string))
        .unwrap_or_else(|| "?".into())
}

fn sync(t: &Tensor<2>) {
    let _ = transfer::read_data(t.clone());
}

/// The positions after one step and conv1's kernel gradient, on `device` (with autodiff).
fn step_and_gradient(weights: &Path, device: &Device, n: usize) -> (Vec<f32>, Vec<f32>) {
    let net: DlfNet = load_dlf(weights, DlfConfig::default(), device).expect("weights");
    let scene = block_in_box(n, dlf_wall_spacing(), [0.3, 0.0, 0.2], 0.002, 1, 0.05);
    let boundary = net.boundary(&scene.box_points, &scene.box_normals, device);
    let pos = points_tensor(&scene.pos, device);
    let o = net.step(pos.clone(), points_tensor(&scene.vel, device), &boundary);
    let loss = dlf_step_loss(o.pos.clone(), pos + 0.01, &o.num_fluid_neighbors);
    let grads = loss.backward();
    let g = net.conv1.kernel.val().grad(&grads).expect("grad");
    let values = |t: Tensor<2>| {
        transfer::read_data(t)
            .convert::<f32>()
            .try_into_vec::<f32>()
            .unwrap()
    };
    (values(o.pos), values(g.reshape([1, -1])))
}

/// How far this device's step and gradient are from the CPU's (flex) on the same scene: the
/// largest difference over the largest magnitude.
fn check_against_cpu(weights: &Path, device: &Device, n: usize) -> String {
    let (pos, grad) = step_and_gradient(weights, device, n);
    let (pos_cpu, grad_cpu) =
        step_and_gradient(weights, &neurofluid_core::device::cpu().autodiff(), n);
    let rel = |a: &[f32], b: &[f32]| {
        let scale = b.iter().fold(1e-30f32, |m, v| m.max(v.abs()));
        a.iter().zip(b).fold(0f32, |m, (x, y)| m.max((x - y).abs())) / scale
    };
    format!(
        "check against the CPU at N = {n}: positions after one step differ by {:.2e}, conv1's \
         kernel gradient by {:.2e} (largest difference over largest magnitude)",
        rel(&pos, &pos_cpu),
        rel(&grad, &grad_cpu)
    )
}

/// The host–device copies of one call of `f`.
fn copies_of<T>(f: impl FnOnce() -> T) -> Counts {
    let before = transfer::counts();
    let _ = f();
    transfer::counts().since(before)
}

fn main() {
    neurofluid_core::malloc::keep_freed_memory();
    println!(
        "allocator: {}",
        neurofluid_core::malloc::allocator_setting()
    );
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut repeats = 5usize;
    let mut sizes = vec![2000usize, 8000, 32000];
    let mut device_name = "cpu".to_string();
    let mut i = 0;
    while i < args.len() {
        match args[i].as_str() {
            "--repeats" => {
                repeats = args[i + 1].parse().expect("--repeats N");
                i += 2;
            }
            "--sizes" => {
                sizes.clear();
                i += 1;
                while i < args.len() && !args[i].starts_with("--") {
                    sizes.push(args[i].parse().expect("size"));
                    i += 1;
                }
            }
            "--device" => {
                device_name = args.get(i + 1).cloned().unwrap_or_default();
                i += 2;
            }
            "--search" => {
                let place = args.get(i + 1).cloned().unwrap_or_default();
                match NeighbourSearch::parse(&place) {
                    Ok(p) => set_neighbour_search(p),
                    Err(e) => {
                        eprintln!("--search: {e}");
                        std::process::exit(2);
                    }
                }
                i += 2;
            }
            _ => i += 1, // cargo's own flags (--bench)
        }
    }
    let weights = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../assets/dlf_pretrained/pretrained_model_weights.pt");
    let device = match neurofluid_core::device::parse_device(&device_name) {
        Ok(d) => d,
        Err(e) => {
            eprintln!("--device: {e}");
            std::process::exit(2);
        }
    };
    println!(
        "device: {device_name}; pairs searched on the {}",
        neighbour_search().name()
    );
    let ad = device.clone().autodiff();
    let net = load_dlf(&weights, DlfConfig::default(), &device).expect("weights");
    let net_ad: DlfNet = load_dlf(&weights, DlfConfig::default(), &ad).expect("weights");
    println!(
        "| N fluid | N wall | neighbours | forward wall s | forward cpu s | fwd+bwd wall s | fwd+bwd cpu s | load avg |\n| --- | --- | --- | --- | --- | --- | --- | --- |"
    );
    let mut copies = Vec::new();
    for &n in &sizes {
        let scene = block_in_box(n, dlf_wall_spacing(), [0.3, 0.0, 0.2], 0.002, 1, 0.05);
        let boundary = net.boundary(&scene.box_points, &scene.box_normals, &device);
        let boundary_ad = net_ad.boundary(&scene.box_points, &scene.box_normals, &ad);
        let pos = points_tensor(&scene.pos, &device);
        let vel = points_tensor(&scene.vel, &device);
        let fwd = || {
            let o = net.step(pos.clone(), vel.clone(), &boundary);
            sync(&o.pos);
            o.num_fluid_neighbors
        };
        let counts = fwd();
        let mean_nb = counts.iter().map(|&c| c as f64).sum::<f64>() / n as f64;
        let (tf, cf) = measure(repeats, || {
            fwd();
        });
        let pos_ad = points_tensor(&scene.pos, &ad);
        let vel_ad = points_tensor(&scene.vel, &ad);
        let target = pos_ad.clone() + 0.01;
        let fwd_bwd = || {
            let o = net_ad.step(pos_ad.clone(), vel_ad.clone(), &boundary_ad);
            let loss = dlf_step_loss(o.pos, target.clone(), &o.num_fluid_neighbors);
            let grads = loss.backward();
            let g = net_ad.conv1.kernel.val().grad(&grads).expect("grad");
            let _ = transfer::read_data(g);
        };
        fwd_bwd();
        let (tb, cb) = measure(repeats, fwd_bwd);
        copies.push((n, copies_of(fwd), copies_of(fwd_bwd)));
        println!(
            "| {n} | {} | {mean_nb:.1} | {tf:.3} | {cf:.2} | {tb:.3} | {cb:.2} | {} |",
            scene.box_points.len(),
            load_average()
        );
    }
    println!("\nhost–device copies per step:");
    for (n, f, fb) in copies {
        println!(
            "  N = {n}: forward {}; forward+backward {}",
            f.describe(),
            fb.describe()
        );
    }
    // Where the time of one forward step goes (largest size).
    let n = *sizes.last().expect("a size");
    let scene = block_in_box(n, dlf_wall_spacing(), [0.3, 0.0, 0.2], 0.002, 1, 0.05);
    let boundary = net.boundary(&scene.box_points, &scene.box_normals, &device);
    let pos = points_tensor(&scene.pos, &device);
    let x = tensor_points(&pos);
    let (fluid, solid) = if !neurofluid_core::device::is_host(&device) {
        // as a GPU step makes them (`DlfNet`, without viscosity): the pairs, then the mapping of
        // every chunk, each closed by a read of one value
        let (r, slots) = (search_radius(0.225), chunk_slots(&device));
        let on_gpu = neighbour_search() == NeighbourSearch::Device;
        let search = |points: &[[f32; 3]], symmetric: bool| {
            if on_gpu {
                device_pairs(&device, points, &x, r, true, symmetric, slots)
            } else {
                let pairs = NeighborGrid::new(points, r).pairs(&x, r, true);
                device_pairs_from_host(&device, &pairs, points.len(), symmetric, slots)
            }
            .expect("a GPU device")
            .expect("the pairs in slots")
        };
        let (pairs, t_search) = time(|| search(&x, true));
        let pairs_b = search(&boundary.points, false);
        let (fluid, t_map) = time(|| {
            let g = ConvGeometry::on_device(pairs, pos.clone(), pos.clone(), 0.225);
            for ch in g.chunks() {
                sync(&ch.cell_weights.clone().slice([0..1, 0..1]));
            }
            g
        });
        println!(
            "\nphases at N = {n}: fluid pairs {} {t_search:.3} s ({} pairs, {} chunks), their mapping {t_map:.3} s",
            if on_gpu {
                "found on the GPU"
            } else {
                "found on the host, uploaded in slots"
            },
            fluid.num_pairs(),
            fluid.chunks().len()
        );
        let solid =
            ConvGeometry::on_device(pairs_b, boundary.points_tensor.clone(), pos.clone(), 0.225);
        (fluid, solid)
    } else {
        let (fluid, t_geo) = time(|| build_host_geometry(&x, &x, 0.225, true, None));
        let (solid, t_geo_b) =
            time(|| build_host_geometry(&boundary.points, &x, 0.225, true, None));
        let (fluid, t_up) = time(|| ConvGeometry::new(fluid, None, &device));
        let solid = ConvGeometry::new(solid, None, &device);
        println!(
            "\nphases at N = {n}: fluid geometry {t_geo:.3} s ({} pairs), box geometry {t_geo_b:.3} s, upload {t_up:.3} s",
            fluid.num_pairs()
        );
        (fluid, solid)
    };
    let feats = |c: usize| {
        Tensor::<2>::random(
            [n, c],
            burn::tensor::Distribution::Normal(0.0, 1.0),
            &device,
        )
    };
    for (name, conv, geo, input) in [
        (
            "conv0_obstacle",
            &net.conv0_obstacle,
            &solid,
            boundary.normals.clone(),
        ),
        ("conv0_fluid", &net.conv0_fluid, &fluid, feats(4)),
        ("conv1", &net.conv1, &fluid, feats(96)),
        ("conv2", &net.conv2, &fluid, feats(64)),
        ("conv3", &net.conv3, &fluid, feats(64)),
    ] {
        let run = || sync(&conv.forward(input.clone(), geo));
        run();
        let t = median((0..repeats).map(|_| time(run).1).collect());
        println!("  {name}: {t:.3} s");
    }
    if !neurofluid_core::device::is_host(&device) {
        println!("\n{}", check_against_cpu(&weights, &ad, sizes[0]));
    }
}
