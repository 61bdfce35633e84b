//! `dlf-rollout`: run the DLF model on a scene `.npz` with the reference harness's keys, so any
//! scene can be held against `tests/data/dlf/dlf_reference.py run`.

use std::path::PathBuf;

use anyhow::{Context, bail, ensure};
use indicatif::{ProgressBar, ProgressStyle};
use neurofluid_core::device::parse_device;
use neurofluid_core::npz::{NpzReader, NpzWriter};
use neurofluid_core::tensors::{points_tensor, tensor_points};
use neurofluid_dlf::rollout::{count_outside, mean_coordinate, rollout};
use neurofluid_dlf::{DlfConfig, load_dlf};

/// Arguments of `dlf-rollout`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Weights: DLF's `.pt`/`.safetensors` or our `.bpk` checkpoint.
    #[arg(long)]
    pub weights: PathBuf,
    /// Input `.npz` with `pos`, `vel`, `box`, `box_normals` ([N,3]/[M,3] float32) and optionally
    /// `box_lo`, `box_hi` ([3]) for the outside-box statistic.
    #[arg(long)]
    pub input: PathBuf,
    /// Number of network steps (frames of 1/50 s).
    #[arg(long)]
    pub steps: usize,
    /// Output `.npz`: `pos`, `vel` [steps+1, N, 3], `raw_output_step0`,
    /// `num_fluid_neighbors_step0`, `saved_steps`, and `mean_y`, `min_y`, `n_outside_box`.
    #[arg(long)]
    pub output: PathBuf,
    /// Device (cpu, flex, ndarray, wgpu, cuda, cuda:N).
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// The scene is z-up (gravity (0, 0, −9.81)): rotate it into the weights' y-up frame.
    #[arg(long)]
    pub z_up: bool,
}

/// Runs the rollout and writes the output archive.
pub fn run(args: Args) -> anyhow::Result<()> {
    let device = parse_device(&args.device)?;
    let config = if args.z_up {
        DlfConfig::z_up()
    } else {
        DlfConfig::default()
    };
    let net = load_dlf(&args.weights, config, &device)?;
    let mut input = NpzReader::open(&args.input)?;
    let pos = input.points("pos")?;
    let vel = input.points("vel")?;
    let box_points = input.points("box")?;
    let box_normals = input.points("box_normals")?;
    let file = args.input.display();
    ensure!(!pos.is_empty(), "{file}: array `pos` holds no particles");
    ensure!(
        vel.len() == pos.len(),
        "{file}: array `vel` has {} rows, expected {} (one per row of `pos`)",
        vel.len(),
        pos.len()
    );
    ensure!(
        box_normals.len() == box_points.len(),
        "{file}: array `box_normals` has {} rows, expected {} (one per row of `box`)",
        box_normals.len(),
        box_points.len()
    );
    let corner = |input: &mut NpzReader, name: &str| -> anyhow::Result<Option<[f32; 3]>> {
        if !input.contains(name) {
            return Ok(None);
        }
        let a = input.f32(name)?;
        if a.data.len() != 3 || a.data.iter().any(|v| !v.is_finite()) {
            bail!(
                "{file}: array `{name}` must hold 3 finite values, found shape {:?}",
                a.shape
            );
        }
        Ok(Some([a.data[0], a.data[1], a.data[2]]))
    };
    let lo = corner(&mut input, "box_lo")?;
    let hi = corner(&mut input, "box_hi")?;
    let bounds = match (lo, hi) {
        (Some(lo), Some(hi)) => Some((lo, hi)),
        (None, None) => None,
        _ => bail!("{file}: give both `box_lo` and `box_hi`, or neither"),
    };

    let boundary = net.boundary(&box_points, &box_normals, &device);
    tracing::info!(
        "dlf-rollout: {} fluid and {} box particles, {} steps on {:?}",
        pos.len(),
        box_points.len(),
        args.steps,
        device
    );
    let bar = ProgressBar::new(args.steps as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} steps, {per_sec}, eta {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let traj = rollout(&net, &pos, &vel, &boundary, args.steps, |_| bar.inc(1));
    bar.finish_and_clear();

    let n = pos.len();
    let states = traj.pos.len();
    let flat = |v: &Vec<Vec<[f32; 3]>>| -> Vec<f32> {
        v.iter().flat_map(|s| s.iter().flatten().copied()).collect()
    };
    let mut out = NpzWriter::new();
    out.add_f32("pos", &[states, n, 3], &flat(&traj.pos));
    out.add_f32("vel", &[states, n, 3], &flat(&traj.vel));
    let steps: Vec<i32> = (0..states as i32).collect();
    out.add_i32("saved_steps", &[states], &steps);
    if args.steps > 0 {
        // The first step again, with its trace: the rollout keeps only the states.
        let (step0, trace) = net.step_traced(
            points_tensor(&pos, &device),
            points_tensor(&vel, &device),
            &boundary,
        );
        let raw = tensor_points(&trace.raw_output);
        out.add_f32("raw_output_step0", &[n, 3], raw.as_flattened());
        let nfn: Vec<i32> = step0
            .num_fluid_neighbors
            .iter()
            .map(|&c| c as i32)
            .collect();
        out.add_i32("num_fluid_neighbors_step0", &[n], &nfn);
    }
    let mean_y: Vec<f32> = traj.pos.iter().map(|p| mean_coordinate(p, 1)).collect();
    let min_y: Vec<f32> = traj
        .pos
        .iter()
        .map(|p| p.iter().map(|q| q[1]).fold(f32::INFINITY, f32::min))
        .collect();
    out.add_f32("mean_y", &[states], &mean_y);
    out.add_f32("min_y", &[states], &min_y);
    if let Some((lo, hi)) = bounds {
        let outside: Vec<i32> = traj
            .pos
            .iter()
            .map(|p| count_outside(p, lo, hi) as i32)
            .collect();
        tracing::info!(
            "particles outside the box after the last step: {}",
            outside.last().copied().unwrap_or(0)
        );
        out.add_i32("n_outside_box", &[states], &outside);
    }
    out.write(&args.output)
        .with_context(|| format!("writing {}", args.output.display()))?;
    tracing::info!(
        "mean y: {:.4} -> {:.4}; wrote {}",
        mean_y[0],
        mean_y[states - 1],
        args.output.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn repo(rel: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../..")
            .join(rel)
    }

    /// The command reproduces the stored Open3D case (5 steps of the cube drop).
    #[test]
    fn reproduces_the_stored_cubedrop_case() {
        let out = std::env::temp_dir().join(format!("nf_dlf_rollout_{}.npz", std::process::id()));
        run(Args {
            weights: repo("assets/dlf_pretrained/pretrained_model_weights.safetensors"),
            input: repo("tests/data/dlf/cubedrop2197_dlfwall_in.npz"),
            steps: 5,
            output: out.clone(),
            device: "cpu".into(),
            z_up: false,
        })
        .unwrap();
        let mut ours = NpzReader::open(&out).unwrap();
        let mut reference =
            NpzReader::open(repo("tests/data/dlf/cubedrop2197_dlfwall_out_open3d.npz")).unwrap();
        for key in ["pos", "vel", "raw_output_step0", "mean_y"] {
            let a = ours.f32(key).unwrap();
            let b = reference.f32(key).unwrap();
            assert_eq!(a.shape, b.shape, "{key}");
            let scale = b.data.iter().fold(0f32, |m, v| m.max(v.abs()));
            let diff = a
                .data
                .iter()
                .zip(&b.data)
                .fold(0f32, |m, (x, y)| m.max((x - y).abs()));
            assert!(diff <= 2e-5 * scale, "{key}: {diff} (scale {scale})");
        }
        for key in ["num_fluid_neighbors_step0", "n_outside_box"] {
            assert_eq!(ours.i64(key).unwrap(), reference.i64(key).unwrap(), "{key}");
        }
        std::fs::remove_file(out).unwrap();
    }

    /// Bad input names the file and the array.
    #[test]
    fn missing_array_is_named() {
        let dir = std::env::temp_dir().join(format!("nf_dlf_bad_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let input = dir.join("bad.npz");
        let mut w = NpzWriter::new();
        w.add_f32("pos", &[2, 3], &[0.0; 6]);
        w.add_f32("vel", &[2, 3], &[0.0; 6]);
        w.write(&input).unwrap();
        let err = run(Args {
            weights: repo("assets/dlf_pretrained/pretrained_model_weights.pt"),
            input: input.clone(),
            steps: 1,
            output: dir.join("out.npz"),
            device: "cpu".into(),
            z_up: false,
        })
        .unwrap_err()
        .to_string();
        assert!(err.contains("bad.npz") && err.contains("box"), "{err}");
        std::fs::remove_dir_all(dir).unwrap();
    }
}
