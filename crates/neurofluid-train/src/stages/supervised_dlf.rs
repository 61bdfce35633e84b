//! Supervised DLF training (docs/spec/dlf.md §5; the paper's DLF† when started from weights): each
//! step averages DLF's 2-step unrolled loss over a batch of random windows, each rotated by a
//! random angle about the gravity axis, and takes one Adam step (ε = 1e-6) on DLF's piecewise
//! schedule. Its evaluation is DLF's validation errors.

use std::path::Path;

use burn::optim::{GradientsAccumulator, GradientsParams};
use burn::prelude::*;
use neurofluid_core::gradients;
use neurofluid_core::lr_schedule::Schedule;
use neurofluid_dlf::DlfNet;
use neurofluid_dlf::loss::LOSS_SCALE;
use neurofluid_dlf::train::{
    TrainingSequence, lr_schedule_per_update, rotation_about, supervised_loss, validate,
};
use rand::Rng as _;
use serde::Serialize;

use crate::optim::{Group, OptimConfig, OptimDefaults};
use crate::stage::{Stage, files};
use crate::trainer::checkpoint;
use crate::trainer::{Evaluation, StageState, StepStats, Trainer};
use neurofluid_core::sampler::Rng;

/// Folder of the stage.
pub const STAGE: Stage = Stage::PretrainDlf;

/// Settings of supervised training; the command-line flags of `pretrain-dlf`, with DLF's
/// published settings as defaults.
#[derive(Debug, Clone, PartialEq, Serialize, clap::Args)]
pub struct SupervisedConfig {
    /// Optimiser steps (DLF: 50000).
    #[arg(long, default_value_t = SupervisedConfig::DLF.iterations, value_parser = clap::value_parser!(u64).range(1..))]
    pub iterations: u64,
    /// Samples per step (DLF: 16).
    #[arg(long, default_value_t = SupervisedConfig::DLF.batch_size, value_parser = clap::value_parser!(u64).range(1..))]
    pub batch_size: u64,
    /// Base learning rate (DLF: 1e-3; the piecewise decay is applied on top).
    #[arg(long, default_value_t = SupervisedConfig::DLF.lr, value_parser = positive_finite)]
    pub lr: f64,
    /// Validate and checkpoint every this many steps (at least 1; a checkpoint is also written
    /// after the last step).
    #[arg(long, default_value_t = SupervisedConfig::DLF.validate_every, value_parser = clap::value_parser!(u64).range(1..))]
    pub validate_every: u64,
    /// Frame skip of the validation errors (DLF training: 20, `evaluate_network.py`: 5).
    #[arg(long, default_value_t = SupervisedConfig::DLF.frame_skip, value_parser = at_least_one)]
    pub frame_skip: usize,
    /// Turn off the random rotation about the gravity axis (DLF's dambreak setting).
    #[arg(long)]
    pub no_rotation: bool,
    /// Start each window from the backward-difference velocity (x_t − x_{t−1})/dt, the
    /// velocity DLF's rollouts carry, instead of the stored one (DLF's training); the first
    /// frame, which has none, is dropped.
    #[arg(long)]
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub backward_velocities: bool,
    /// Seed of sample order, rotations and initialisation.
    #[arg(long, default_value_t = SupervisedConfig::DLF.seed)]
    pub seed: u64,
}

/// A learning rate: a finite number > 0.
fn positive_finite(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        Ok(v) => Err(format!("expected a finite learning rate > 0, got {v}")),
        Err(e) => Err(format!("expected a number: {e}")),
    }
}

/// A count of at least 1.
fn at_least_one(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(v) if v >= 1 => Ok(v),
        Ok(v) => Err(format!("expected at least 1, got {v}")),
        Err(e) => Err(format!("expected a whole number: {e}")),
    }
}

/// DLF's own optimiser group: Adam with ε = 1e-6 (the schedule depends on the run length).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SupervisedDlfGroup;
impl OptimDefaults for SupervisedDlfGroup {
    const LR: f64 = 1e-3;
    const EPSILON: f64 = 1e-6;
    fn schedule() -> Schedule {
        lr_schedule_per_update(50_000)
    }
}

impl SupervisedConfig {
    /// DLF's published training: the flags' defaults.
    pub const DLF: Self = Self {
        iterations: 50_000,
        batch_size: 16,
        lr: 1e-3,
        validate_every: 1000,
        frame_skip: 20,
        no_rotation: false,
        backward_velocities: false,
        seed: 0,
    };

    /// The optimiser group: this learning rate on DLF's schedule for this run length.
    pub fn optim(&self) -> OptimConfig<SupervisedDlfGroup> {
        let mut optim = OptimConfig::default();
        optim.lr = self.lr;
        optim.schedule = lr_schedule_per_update(self.iterations);
        optim
    }
}

/// DLF, its Adam and the sample stream, trained on ground-truth sequences.
pub struct SupervisedDlfTrainer {
    cfg: SupervisedConfig,
    net: DlfNet,
    opt: Group<SupervisedDlfGroup>,
    rng: Rng,
    train: Vec<TrainingSequence>,
    val: Vec<TrainingSequence>,
    /// (sequence, first frame) of every usable 3-frame window.
    samples: Vec<(usize, usize)>,
}

impl SupervisedDlfTrainer {
    /// Training of `net` (on an autodiff device) on `train`, validated on `val`. Under walls
    /// (`DlfConfig::container`) the samples are not rotated: the walls are the scene's
    /// axis-aligned box, which does not turn with a rotated sample.
    pub fn new(
        cfg: &SupervisedConfig,
        net: DlfNet,
        train: Vec<TrainingSequence>,
        val: Vec<TrainingSequence>,
    ) -> anyhow::Result<Self> {
        let train: Vec<TrainingSequence> = if cfg.backward_velocities {
            let dt = net.config.dt;
            train
                .into_iter()
                .map(|s| s.with_backward_velocities(dt))
                .collect()
        } else {
            train
        };
        let samples: Vec<(usize, usize)> = train
            .iter()
            .enumerate()
            .flat_map(|(s, seq)| seq.windows().into_iter().map(move |t| (s, t)))
            .collect();
        anyhow::ensure!(
            !samples.is_empty(),
            "the training data holds no window of 3 consecutive frames with a constant \
             particle count"
        );
        anyhow::ensure!(
            cfg.batch_size <= samples.len() as u64,
            "--batch-size {} is larger than the {} training windows the data holds; expected \
             at most {}",
            cfg.batch_size,
            samples.len(),
            samples.len()
        );
        let mut cfg = cfg.clone();
        if net.config.container.is_some() && !cfg.no_rotation {
            tracing::info!(
                "the walls are the scene's axis-aligned box, which does not turn: the training \
                 samples are not rotated about the gravity axis"
            );
            cfg.no_rotation = true;
        }
        Ok(Self {
            opt: cfg.optim().group(),
            rng: Rng::stream(cfg.seed, STAGE.folder()),
            cfg,
            net,
            train,
            val,
            samples,
        })
    }

    /// The trained DLF.
    pub fn into_dlf(self) -> DlfNet {
        self.net
    }
}

impl Trainer for SupervisedDlfTrainer {
    fn stage(&self) -> &'static str {
        STAGE.folder()
    }

    fn total_steps(&self) -> u64 {
        self.cfg.iterations
    }

    fn step(&mut self, _step: u64) -> anyhow::Result<StepStats> {
        let lr = self.opt.lr();
        let batch = self.cfg.batch_size.max(1);
        let gravity = self.net.config.gravity;
        let mut accum = GradientsAccumulator::<DlfNet>::new();
        let mut losses = Vec::new();
        for _ in 0..batch {
            let (s, t) = self.samples[self.rng.below(self.samples.len() as u64) as usize];
            let rot = (!self.cfg.no_rotation).then(|| {
                rotation_about(gravity, self.rng.random_range(0.0..std::f32::consts::TAU))
            });
            let loss =
                supervised_loss(&self.net, &self.train[s], t, rot) * (LOSS_SCALE / batch as f32);
            losses.push(loss.clone());
            let grads = GradientsParams::from_grads(loss.backward(), &self.net);
            accum.accumulate(&self.net, grads);
        }
        let grads = accum.grads();
        // one read: the samples' losses and the gradients' squares
        let n = losses.len();
        let mut parts = losses;
        parts.extend(gradients::grad_square_sums(&grads, &self.net));
        let values = neurofluid_core::transfer::read_together(parts)?;
        let batch_loss = values[..n].iter().fold(0.0, |sum, v| sum + v);
        let grad_norm = gradients::norm_of(&values[n..]);
        if batch_loss.is_finite() && grad_norm.is_finite() {
            self.net = self.opt.step(self.net.clone(), grads);
        }
        Ok(StepStats {
            loss: batch_loss,
            lrs: vec![("dlf", lr)],
            grad_norms: vec![("dlf", grad_norm)],
            updated: true,
            ..StepStats::default()
        })
    }

    fn evaluate(&mut self, _done: u64) -> anyhow::Result<Option<Evaluation>> {
        if self.val.is_empty() {
            return Ok(None);
        }
        let m = validate(&self.net.valid(), &self.val, self.cfg.frame_skip);
        Ok(Some(Evaluation {
            scores: vec![
                ("err_n1", m.err_n1),
                ("err_n2", m.err_n2),
                ("whole_seq_err", m.whole_seq_err),
            ],
            ..Evaluation::default()
        }))
    }

    fn save(&self, dir: &Path) -> anyhow::Result<StageState> {
        checkpoint::save_module(&self.net, &files::DLF.save_path(dir))?;
        let mut state = self.rng.to_state();
        let adam = files::SUPERVISED_DLF_ADAM.save_path(dir);
        checkpoint::save_group(&self.opt, &adam, "dlf", &mut state)?;
        Ok(state)
    }

    fn load(&mut self, dir: &Path, done: u64, state: StageState) -> anyhow::Result<()> {
        self.net = checkpoint::load_module(self.net.clone(), &files::DLF.load_path(dir))?;
        let adam = files::SUPERVISED_DLF_ADAM.load_path(dir);
        // every step updates
        checkpoint::load_group(&mut self.opt, &self.net, &adam, "dlf", &state, || done)?;
        self.rng = Rng::from_stage_state(&state, dir)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use neurofluid_core::scene::Aabb;
    use neurofluid_dlf::rollout::rollout;
    use neurofluid_dlf::scene::{block_in_box, dlf_wall_spacing};
    use neurofluid_dlf::{DlfConfig, load_dlf};

    /// `pretrain-dlf` without flags trains as DLF did.
    #[test]
    fn the_flags_default_to_dlfs_training() {
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            train: SupervisedConfig,
        }
        use clap::Parser;
        assert_eq!(
            Cli::parse_from(["pretrain-dlf"]).train,
            SupervisedConfig::DLF
        );
        let bv = Cli::parse_from(["pretrain-dlf", "--backward-velocities", "--lr", "1e-4"]);
        assert!(bv.train.backward_velocities && bv.train.lr == 1e-4);
    }

    /// The first step's loss of a trainer on one 3-frame window, whose only randomness is then
    /// the rotation of the sample.
    fn first_loss(container: Option<Aabb>, seed: u64) -> f64 {
        let weights = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../assets/dlf_pretrained/pretrained_model_weights.pt");
        let cpu = neurofluid_core::device::cpu();
        let config = DlfConfig {
            container,
            ..DlfConfig::default()
        };
        let s = block_in_box(125, dlf_wall_spacing(), [0.3, 0.0, 0.1], 0.002, 4, 0.05);
        let traj = {
            let net = load_dlf(&weights, DlfConfig::default(), &cpu).unwrap();
            let boundary = net.boundary(&s.box_points, &s.box_normals, &cpu);
            rollout(&net, &s.pos, &s.vel, &boundary, 2, |_| {})
        };
        let net = load_dlf(&weights, config, &cpu.autodiff()).unwrap();
        let seq = TrainingSequence::new(
            "block",
            traj.pos.clone(),
            traj.vel.clone(),
            s.box_points.clone(),
            s.box_normals.clone(),
        )
        .unwrap();
        let cfg = SupervisedConfig {
            iterations: 1,
            batch_size: 1,
            lr: 1e-5,
            validate_every: 1,
            frame_skip: 1,
            seed,
            ..SupervisedConfig::DLF
        };
        let mut trainer = SupervisedDlfTrainer::new(&cfg, net, vec![seq], Vec::new()).unwrap();
        trainer.step(0).unwrap().loss
    }

    /// Under walls the sample is not rotated (the seed, which draws the angle, changes
    /// nothing); without them it is (DLF's convolutions are not rotation invariant, so the
    /// angle changes the loss: the control).
    #[test]
    fn samples_under_walls_are_not_rotated() {
        let walls = Some(Aabb {
            min: [-0.5, 0.0, -0.5],
            max: [0.5, 1.0, 0.5],
        });
        let (a, b) = (first_loss(walls, 1), first_loss(walls, 2));
        assert_eq!(a, b, "under walls the loss must not depend on a rotation");
        let (c, d) = (first_loss(None, 1), first_loss(None, 2));
        assert!(
            (c - d).abs() > 1e-6 * c.abs(),
            "without walls the rotation changes the loss: {c} {d}"
        );
    }
}
