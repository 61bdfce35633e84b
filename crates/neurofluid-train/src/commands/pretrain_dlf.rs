//! `pretrain-dlf`: supervised (pre)training or fine-tuning (the paper's DLF†) of the DLF model on
//! DLF `.msgpack.zst` records or a scene's particle sequence, with DLF's loss, rotations, schedule and validation errors.

use std::path::{Path, PathBuf};

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use neurofluid_core::device::parse_device;
use neurofluid_core::scene::{MANIFEST_FILE, Role, Scene, UpAxis};
use neurofluid_dlf::train::{
    PretrainConfig, TrainEvent, TrainingSequence, load_record_dir, pretrain,
};
use neurofluid_dlf::{DlfConfig, DlfNet, load_dlf, save_checkpoint};

/// Arguments of `pretrain-dlf`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Training data: a folder of DLF records (`*.msgpack.zst`, one sequence per file) or a
    /// scene folder (generated or released layout; its test sequence is used).
    #[arg(long)]
    pub data: PathBuf,
    /// Validation data (a records folder or a scene folder).
    #[arg(long)]
    pub val: Option<PathBuf>,
    /// Start from these weights (`.pt`, `.safetensors`, `.bpk`): fine-tuning. Default: random init.
    #[arg(long)]
    pub init: Option<PathBuf>,
    /// Output checkpoint (burnpack `.bpk`); also written after every validation.
    #[arg(long)]
    pub output: PathBuf,
    /// Optimiser steps (DLF: 50000).
    #[arg(long, default_value_t = 50_000)]
    pub iterations: usize,
    /// Samples per step (DLF: 16).
    #[arg(long, default_value_t = 16)]
    pub batch_size: usize,
    /// Base learning rate (DLF: 1e-3; the piecewise decay is applied on top).
    #[arg(long, default_value_t = 1e-3)]
    pub lr: f64,
    /// Validate (and checkpoint) every this many steps.
    #[arg(long, default_value_t = 1000)]
    pub validate_every: usize,
    /// Frame skip of the validation errors.
    #[arg(long, default_value_t = 20)]
    pub frame_skip: usize,
    /// Turn off the random rotation about the gravity axis (DLF's dambreak setting).
    #[arg(long)]
    pub no_rotation: bool,
    /// Seed of sample order, rotations and initialisation.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Device (cpu, flex, ndarray, wgpu, cuda, cuda:N).
    #[arg(long, default_value = "cpu")]
    pub device: String,
}

/// The sequences of a records folder (y-up, DLF's frame) or of a scene folder (its up axis).
fn load_sequences(path: &Path) -> anyhow::Result<(Vec<TrainingSequence>, UpAxis)> {
    if !path.join(MANIFEST_FILE).is_file() && !path.join("view_1").is_dir() {
        return Ok((load_record_dir(path)?, UpAxis::Y));
    }
    let scene =
        Scene::open(path).with_context(|| format!("opening the scene {}", path.display()))?;
    let frames = scene.particle_sequence(Role::Test)?;
    let walls = scene.boundary()?;
    let name = scene.manifest().name.clone();
    let sequence = TrainingSequence::new(
        name,
        frames.iter().map(|f| f.pos.clone()).collect(),
        frames.iter().map(|f| f.vel.clone()).collect(),
        walls.points,
        walls.normals,
    )?;
    Ok((vec![sequence], scene.up_axis()))
}

/// Runs the training.
pub fn run(args: Args) -> anyhow::Result<()> {
    let device = parse_device(&args.device)?.autodiff();
    device.seed(args.seed);
    let (train, up) = load_sequences(&args.data)?;
    let val = match &args.val {
        Some(dir) => load_sequences(dir)?.0,
        None => Vec::new(),
    };
    let config = match up {
        UpAxis::Z => DlfConfig::z_up(),
        UpAxis::Y => DlfConfig::default(),
    };
    let net: DlfNet = match &args.init {
        Some(path) => load_dlf(path, config, &device)?,
        None => DlfNet::new(config, &device),
    };
    let train_config = PretrainConfig {
        iterations: args.iterations,
        batch_size: args.batch_size,
        base_lr: args.lr,
        random_rotation: !args.no_rotation,
        validate_every: args.validate_every,
        frame_skip: args.frame_skip,
        seed: args.seed,
        ..PretrainConfig::default()
    };
    tracing::info!(
        "pretrain-dlf: {} training and {} validation sequences, {} steps of batch {}",
        train.len(),
        val.len(),
        args.iterations,
        args.batch_size
    );
    let bar = ProgressBar::new(args.iterations as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} steps, loss {msg}, eta {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut save_error = None;
    let net = pretrain(net, &train, &val, &train_config, |event, net| match event {
        TrainEvent::Step { loss, .. } => {
            bar.set_message(format!("{loss:.4}"));
            bar.inc(1);
        }
        TrainEvent::Validation { step, metrics } => {
            bar.println(format!(
                "step {step}: err_n1 {:.6} err_n2 {:.6} whole_seq_err {:.5}",
                metrics.err_n1, metrics.err_n2, metrics.whole_seq_err
            ));
            if *step > 0
                && let Err(e) = save_checkpoint(net, &args.output)
            {
                save_error = Some(e);
            }
        }
    })?;
    bar.finish_and_clear();
    if let Some(e) = save_error {
        return Err(e).context("saving a checkpoint during training");
    }
    save_checkpoint(&net, &args.output)?;
    tracing::info!("wrote {}", args.output.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use neurofluid_dlf::records::{RecordFrame, write_record};
    use neurofluid_dlf::rollout::rollout;
    use neurofluid_dlf::scene::{block_in_box, dlf_wall_spacing};

    /// Fine-tuning on a record made by the pretrained model runs and writes a loadable checkpoint.
    #[test]
    fn fine_tunes_on_a_record_folder() {
        let weights = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../assets/dlf_pretrained/pretrained_model_weights.pt");
        let device = neurofluid_core::device::cpu();
        let net = load_dlf(&weights, DlfConfig::default(), &device).unwrap();
        let s = block_in_box(125, dlf_wall_spacing(), [0.1, 0.0, 0.0], 0.002, 4, 0.02);
        let boundary = net.boundary(&s.box_points, &s.box_normals, &device);
        let traj = rollout(&net, &s.pos, &s.vel, &boundary, 3, |_| {});
        let frames: Vec<RecordFrame> = (0..4)
            .map(|f| RecordFrame {
                pos: traj.pos[f].clone(),
                vel: traj.vel[f].clone(),
                box_points: (f == 0).then(|| s.box_points.clone()),
                box_normals: (f == 0).then(|| s.box_normals.clone()),
                ..RecordFrame::default()
            })
            .collect();
        let dir = std::env::temp_dir().join(format!("nf_pretrain_dlf_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        write_record(&dir.join("sim_0001_00.msgpack.zst"), &frames, 3).unwrap();
        let output = dir.join("ft.bpk");
        run(Args {
            data: dir.clone(),
            val: Some(dir.clone()),
            init: Some(weights),
            output: output.clone(),
            iterations: 2,
            batch_size: 1,
            lr: 1e-5,
            validate_every: 1,
            frame_skip: 1,
            no_rotation: false,
            seed: 1,
            device: "cpu".into(),
        })
        .unwrap();
        load_dlf(&output, DlfConfig::default(), &device).unwrap();
        std::fs::remove_dir_all(dir).unwrap();
    }
}
