//! Joint grounding (spec §4.2): DLF (the transition model) and PhysNeRF (the renderer) trained
//! together from the training view only.
//!
//! Frames are visited in order; at the start of every epoch the state is reset to the known
//! ground-truth state of the first training frame. Each step moves DLF one transition, renders
//! the prediction with the camera of frame t+1 at `rays` random pixels of image t+1, and adds
//! MSE_coarse + MSE_fine + w·L1(outside the box) to the window's loss. Two Adams, each with its
//! own schedule, update PhysNeRF and DLF at the end of every window of `bptt_steps` transitions
//! (1 = the reference's truncated BPTT), after which the carried state is detached.

use std::path::Path;

use anyhow::Context;
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use burn::tensor::activation::relu;
use neurofluid_core::npz::{NpzReader, NpzWriter};
use neurofluid_core::scene::{Aabb, Particles, Role, Scene};
use neurofluid_dlf::{Boundary, DlfNet};
use neurofluid_physnerf::PhysNerf;

use super::run_folder::Run;
use super::views::{
    ViewFrame, load_particles, points_tensor, render_beside_truth, scalar, tensor_points,
};
use super::warmup;
use crate::config::{JointSection, StageKind};
use crate::metrics_log::{MetricsLog, psnr_from_mse};
use crate::sampler::Rng;
use crate::trainer::checkpoint::{self, first_existing};
use crate::trainer::{Cadence, Evaluation, StageState, StepStats, Trainer, guard};

/// Folder of the stage inside the run folder.
pub const STAGE: &str = "joint";

/// The models the joint stage trains.
#[derive(Debug, Clone)]
pub struct Grounded {
    /// PhysNeRF, the renderer.
    pub physnerf: PhysNerf,
    /// The transition model.
    pub dlf: DlfNet,
}

/// Mean over particles and axes of the distance outside the box interior (the reference's
/// boundary L1 penalty, `mean |x − clamp(x, lo, hi)|`).
pub fn boundary_penalty(pos: Tensor<2>, interior: &Aabb) -> Tensor<1> {
    let device = pos.device();
    let lo = Tensor::<1>::from_floats(interior.min, &device).unsqueeze_dim::<2>(0);
    let hi = Tensor::<1>::from_floats(interior.max, &device).unsqueeze_dim::<2>(0);
    let below = relu(lo - pos.clone());
    let above = relu(pos - hi);
    (below + above).mean()
}

/// What the joint stage trains on: the training view at every training frame, the true state of
/// the first training frame, and the box.
#[derive(Debug, Clone)]
pub struct JointData {
    /// The training view at frames 0 … T−1 of the training split.
    pub targets: Vec<ViewFrame>,
    /// The true state at the first training frame (every epoch starts from it).
    pub initial: Particles,
    /// Box particles and their normals.
    pub walls: (Vec<[f32; 3]>, Vec<[f32; 3]>),
    /// The box interior (the boundary penalty's bounds).
    pub interior: Aabb,
}

impl JointData {
    /// Loads the data `cfg` asks for from `scene`.
    pub fn load(scene: &Scene, cfg: &JointSection) -> anyhow::Result<Self> {
        let frames = scene.frames(Role::Train);
        anyhow::ensure!(
            frames.len() >= 2,
            "the training split has {} frame(s); joint training needs at least 2",
            frames.len()
        );
        let view = cfg.view(scene).context("the scene has no training view")?;
        let targets = frames
            .clone()
            .map(|t| ViewFrame::load(scene, Role::Train, &view, t))
            .collect::<anyhow::Result<Vec<_>>>()?;
        let initial = load_particles(scene, Role::Train, frames.start, "first training frame")?;
        let walls = scene.boundary()?;
        Ok(Self {
            targets,
            initial,
            walls: (walls.points, walls.normals),
            interior: scene.manifest().box_interior,
        })
    }

    /// Transitions per epoch.
    pub fn transitions(&self) -> u64 {
        (self.targets.len() - 1) as u64
    }
}

/// The carried particle state (positions, velocities) on the device.
type State = (Tensor<2>, Tensor<2>);

/// DLF and PhysNeRF, their two Adams, the pixel stream and the carried state.
pub struct JointTrainer {
    cfg: JointSection,
    physnerf: PhysNerf,
    dlf: DlfNet,
    opt_physnerf: ModuleOptimizer,
    opt_dlf: ModuleOptimizer,
    rng: Rng,
    data: JointData,
    boundary: Boundary,
    state: State,
    /// The window's loss so far (several transitions with `bptt_steps` > 1).
    pending: Option<Tensor<1>>,
    /// The target frame of the last step (what a preview shows).
    last_target: usize,
}

impl JointTrainer {
    /// Joint training of `physnerf` (warmed up) and `dlf` (pretrained) on `data`; the pixel
    /// stream follows `seed`.
    pub fn new(
        cfg: &JointSection,
        physnerf: PhysNerf,
        dlf: DlfNet,
        data: JointData,
        seed: u64,
    ) -> Self {
        let device = dlf.device();
        let boundary = dlf.boundary(&data.walls.0, &data.walls.1, &device);
        let state = initial_state(&data, &device);
        Self {
            opt_physnerf: cfg.physnerf_optim.adam(),
            opt_dlf: cfg.dlf_optim.adam(),
            rng: Rng::stream(seed, STAGE),
            cfg: cfg.clone(),
            physnerf,
            dlf,
            data,
            boundary,
            state,
            pending: None,
            last_target: 1,
        }
    }

    /// The grounded models.
    pub fn into_models(self) -> Grounded {
        Grounded {
            physnerf: self.physnerf,
            dlf: self.dlf,
        }
    }
}

fn initial_state(data: &JointData, device: &Device) -> State {
    (
        points_tensor(&data.initial.pos, device),
        points_tensor(&data.initial.vel, device),
    )
}

impl Trainer for JointTrainer {
    fn stage(&self) -> &'static str {
        STAGE
    }

    fn total_steps(&self) -> u64 {
        self.cfg.epochs * self.data.transitions()
    }

    fn step(&mut self, step: u64) -> anyhow::Result<StepStats> {
        let transitions = self.data.transitions();
        let device = self.dlf.device();
        let t = (step % transitions) as usize;
        if t == 0 {
            self.state = initial_state(&self.data, &device);
        }
        let pred = self
            .dlf
            .step(self.state.0.clone(), self.state.1.clone(), &self.boundary);
        let target = &self.data.targets[t + 1];
        self.last_target = t + 1;
        let (w, h) = (target.camera.width, target.camera.height);
        let pixels = self
            .rng
            .sample_pixels(self.cfg.rays, w, h, self.cfg.precrop_at(step))?;
        let (rays, colours) = target.batch(&pixels, &device);
        let jitter: Option<&mut dyn rand::RngCore> = if self.physnerf.config.stratified {
            Some(&mut self.rng)
        } else {
            None
        };
        let out = self.physnerf.render_rays(&pred.pos, &rays, jitter)?;
        let image_loss = self.physnerf.loss(&out, colours);
        let psnr = psnr_from_mse(scalar(&image_loss.fine));
        let loss = image_loss.total
            + boundary_penalty(pred.pos.clone(), &self.data.interior)
                .mul_scalar(self.cfg.boundary_weight);
        self.pending = Some(match self.pending.take() {
            None => loss,
            Some(p) => p + loss,
        });
        self.state = (pred.pos, pred.vel);
        let done = step + 1;
        let window_end = done.is_multiple_of(self.cfg.bptt_steps.max(1) as u64)
            || (t + 1) as u64 == transitions
            || done == self.total_steps();
        let mut stats = StepStats {
            psnr: Some(psnr),
            rays: self.cfg.rays,
            ..StepStats::default()
        };
        if !window_end {
            stats.loss = scalar(self.pending.as_ref().context("no loss")?);
            return Ok(stats);
        }
        let loss = self.pending.take().context("no loss to optimise")?;
        stats.loss = scalar(&loss);
        if !stats.loss.is_finite() {
            return Ok(stats);
        }
        let (lr_p, lr_d) = (
            self.cfg.physnerf_optim.lr_at(step),
            self.cfg.dlf_optim.lr_at(step),
        );
        let (mut norm_p, mut norm_d) = (0.0, 0.0);
        if let Some(mut grads) = guard::backward(loss) {
            let g_physnerf = GradientsParams::from_module(&mut grads, &self.physnerf);
            let g_dlf = GradientsParams::from_module(&mut grads, &self.dlf);
            norm_p = guard::grad_norm(&g_physnerf, &self.physnerf);
            norm_d = guard::grad_norm(&g_dlf, &self.dlf);
            if norm_p.is_finite() && norm_d.is_finite() {
                self.physnerf = self
                    .opt_physnerf
                    .step(lr_p, self.physnerf.clone(), g_physnerf);
                self.dlf = self.opt_dlf.step(lr_d, self.dlf.clone(), g_dlf);
            }
        }
        stats.grad_norms = vec![("physnerf", norm_p), ("dlf", norm_d)];
        // the carried state leaves the graph: truncated backpropagation through time
        self.state = (self.state.0.clone().detach(), self.state.1.clone().detach());
        stats.lr_physnerf = Some(lr_p);
        stats.lr_dlf = Some(lr_d);
        stats.updated = true;
        Ok(stats)
    }

    /// The carried particles must stay finite and near the box: farther than one box size
    /// outside it, the state has exploded (and so will everything trained on it).
    fn check_state(&self) -> Result<(), String> {
        let pos = tensor_points(&self.state.0);
        let b = &self.data.interior;
        let margin: f32 = (0..3).map(|a| b.max[a] - b.min[a]).fold(0.0, f32::max);
        for (i, p) in pos.iter().enumerate() {
            if !p.iter().all(|v| v.is_finite()) {
                return Err(format!("predicted particle {i} is not finite ({p:?})"));
            }
            if (0..3).any(|a| p[a] < b.min[a] - margin || p[a] > b.max[a] + margin) {
                return Err(format!(
                    "predicted particle {i} left the box by more than its size (at {p:?}; the \
                     box interior is {:?}–{:?})",
                    b.min, b.max
                ));
            }
        }
        Ok(())
    }

    /// The training view at the frame just predicted, rendered from the prediction.
    fn evaluate(&mut self, _done: u64) -> anyhow::Result<Option<Evaluation>> {
        let target = &self.data.targets[self.last_target];
        render_beside_truth(&self.physnerf, target, &self.state.0).map(Some)
    }

    fn save(&self, dir: &Path) -> anyhow::Result<StageState> {
        checkpoint::save_module(&self.physnerf, &dir.join("physnerf.bpk"))?;
        checkpoint::save_module(&self.dlf, &dir.join("dlf.bpk"))?;
        checkpoint::save_optimizer(&self.opt_physnerf, &dir.join("optim_physnerf.bpk"))?;
        checkpoint::save_optimizer(&self.opt_dlf, &dir.join("optim_dlf.bpk"))?;
        let mut w = NpzWriter::new();
        w.add_points("pos", &tensor_points(&self.state.0));
        w.add_points("vel", &tensor_points(&self.state.1));
        w.write(dir.join("carried_state.npz"))?;
        Ok(self.rng.to_state())
    }

    fn load(&mut self, dir: &Path, done: u64, state: StageState) -> anyhow::Result<()> {
        let device = self.dlf.device();
        self.physnerf = checkpoint::load_module(
            self.physnerf.clone(),
            &first_existing(dir, &["physnerf.bpk", "renderer.bpk"]),
        )?;
        self.dlf = checkpoint::load_module(self.dlf.clone(), &dir.join("dlf.bpk"))?;
        self.opt_physnerf = checkpoint::load_optimizer(
            self.cfg.physnerf_optim.adam(),
            &self.physnerf,
            &first_existing(dir, &["optim_physnerf.bpk", "optim_renderer.bpk"]),
        )?;
        self.opt_dlf = checkpoint::load_optimizer(
            self.cfg.dlf_optim.adam(),
            &self.dlf,
            &first_existing(dir, &["optim_dlf.bpk", "optim_transition.bpk"]),
        )?;
        self.rng = Rng::from_stage_state(&state, dir)?;
        if !done.is_multiple_of(self.data.transitions()) {
            let mut r = NpzReader::open(dir.join("carried_state.npz"))?;
            self.state = (
                points_tensor(&r.points("pos")?, &device),
                points_tensor(&r.points("vel")?, &device),
            );
        }
        Ok(())
    }
}

/// Runs (or resumes) the joint stage of `run` with the CLI's sinks and returns the models.
pub fn run(run: &Run, log: &mut MetricsLog) -> anyhow::Result<Grounded> {
    run_until(run, log, None)
}

/// Runs (or resumes) the joint stage up to step `stop` (all of it for `None`), checkpointing
/// there (with the carried particle state when `stop` falls inside an epoch).
pub fn run_until(run: &Run, log: &mut MetricsLog, stop: Option<u64>) -> anyhow::Result<Grounded> {
    let cfg = &run.exp.joint;
    let mut data = JointData::load(&run.scene, cfg)?;
    let first = run.scene.frames(Role::Train).start;
    data.initial =
        super::initial::starting_particles(run, Role::Train, first, "first training frame")?;
    tracing::info!(
        epochs = cfg.epochs,
        transitions = data.transitions(),
        bptt_steps = cfg.bptt_steps,
        "joint grounding"
    );
    let physnerf = warmup::load_trained(run)?;
    let dlf = run.load_dlf(&run.exp.dlf.weights)?;
    let mut trainer = JointTrainer::new(cfg, physnerf, dlf, data, run.exp.seed);
    let cadence = Cadence {
        log_every: cfg.log_every,
        evaluate_every: cfg.preview_every,
        checkpoint_every: cfg.ckpt_every,
    };
    super::drive(run, log, &mut trainer, StageKind::Joint, cadence, stop)?;
    Ok(trainer.into_models())
}

/// The models of a finished joint stage (its last checkpoint).
pub fn load_trained(run: &Run) -> anyhow::Result<Grounded> {
    let stage_dir = run.stage_dir(STAGE);
    let ckpt = checkpoint::latest(&stage_dir).with_context(|| {
        format!(
            "no joint checkpoint in {}: run the `joint` stage first",
            stage_dir.display()
        )
    })?;
    let physnerf = PhysNerf::new(run.physnerf_config(), &run.device)?;
    let physnerf = checkpoint::load_module(
        physnerf,
        &first_existing(&ckpt, &["physnerf.bpk", "renderer.bpk"]),
    )?;
    let dlf = run.load_dlf(&run.exp.dlf.weights)?;
    let dlf = checkpoint::load_module(dlf, &ckpt.join("dlf.bpk"))?;
    Ok(Grounded { physnerf, dlf })
}
