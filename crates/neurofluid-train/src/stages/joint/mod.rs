//! Joint grounding (docs/spec/neurofluid.md §4.2): DLF (the transition model) and PhysNeRF (the
//! renderer) trained together from the training view only.
//!
//! Frames are visited in order; at the start of every epoch the state is reset to the known
//! ground-truth state of the first training frame. Each step moves DLF one transition, renders
//! the prediction with the camera of frame t+1 at `rays` random pixels of image t+1, and adds
//! MSE_coarse + MSE_fine + w·L1(outside the box) ([`loss`]) and the particle terms ([`terms`])
//! to the window's loss. Two Adams, each with its own schedule, update PhysNeRF and DLF at the
//! end of every window of `bptt_steps` transitions (1 = the reference's truncated BPTT), after
//! which the carried state is detached ([`windows`]).
//!
//! The image loss is differentiated in two parts, which give the gradients of the one loss by
//! the chain rule: the render of x_{t+1} (a leaf) gives PhysNeRF's gradients and g = ∂L/∂x_{t+1}
//! at once; DLF's come from the surrogate Σ x_{t+1}·g (plus the boundary term and the particle
//! terms), differentiated through the transitions of the window. The split exposes g, which the
//! [`Diagnostics`] compare with the true error at every evaluation.

use std::path::Path;

use anyhow::Context;
use burn::optim::{GradientsAccumulator, GradientsParams};
use burn::prelude::*;
use neurofluid_core::gradients;
use neurofluid_core::npz::{NpzReader, NpzWriter};
use neurofluid_core::scene::Role;
use neurofluid_core::square_sums;
use neurofluid_core::transfer::read_together;
use neurofluid_dlf::{Boundary, DlfNet};
use neurofluid_physnerf::PhysNerf;

use super::run_folder::Run;
use super::views::{points_tensor, render_beside_truth, tensor_points};
use super::warmup;
use crate::config::{Cadenced, JointSection, PhysicsFit};
use crate::optim::{Group, JointDlfGroup, JointPhysNerfGroup, JointPhysicsGroup};
use crate::stage::{Stage, files};
use crate::trainer::checkpoint;
use crate::trainer::{Evaluation, StageState, StepStats, Trainer};
use neurofluid_core::sampler::Rng;
use neurofluid_outputs::metrics_log::{MetricsLog, psnr_from_mse};

mod data;
mod diagnostics;
mod input_noise;
mod loss;
pub mod physics;
pub mod search;
pub mod terms;
mod windows;

pub use data::{JointData, State, training_rollout};
pub use diagnostics::{
    Diagnostics, cosine_of_sums, cosine_sums, held_out_view, psnr_on_frames, psnr_on_truth,
};
pub use loss::{SplitImageLoss, boundary_penalty, dlf_surrogate, split_image_loss, training_rays};
pub use windows::{Updates, updates_after, updates_before};

use input_noise::with_input_noise;
use loss::split_on_device;
use physics::Physics;
use terms::{ParticleTerm, TermContext, Transition};

/// The physical scalars being fitted (`[joint.physics]`) and their Adam.
struct PhysicsFitting {
    fit: PhysicsFit,
    module: Physics,
    opt: Group<JointPhysicsGroup>,
}

/// Folder of the stage inside the run folder.
pub const STAGE: Stage = Stage::Joint;

/// The models the joint stage trains.
#[derive(Debug, Clone)]
pub struct Grounded {
    /// PhysNeRF, the renderer.
    pub physnerf: PhysNerf,
    /// The transition model.
    pub dlf: DlfNet,
}

/// DLF and PhysNeRF, their two Adams, the pixel stream, the particle terms and the carried state.
pub struct JointTrainer {
    cfg: JointSection,
    physnerf: PhysNerf,
    dlf: DlfNet,
    opt_physnerf: Group<JointPhysNerfGroup>,
    opt_dlf: Group<JointDlfGroup>,
    rng: Rng,
    data: JointData,
    boundary: Boundary,
    state: State,
    /// The carried positions on the host, when the last step read them (the state check uses
    /// them instead of reading the device again).
    state_host: Option<Vec<[f32; 3]>>,
    /// The particle terms (`[joint.terms]`), in the order they run.
    terms: Vec<Box<dyn ParticleTerm>>,
    /// DLF's surrogate loss of the window so far (several transitions with `bptt_steps` > 1).
    pending: Option<Tensor<1>>,
    /// The window's loss so far.
    pending_loss: f64,
    /// Each particle term's value over the window so far, in the order of `terms`.
    pending_terms: Vec<f64>,
    /// PhysNeRF's gradients of the window so far.
    physnerf_grads: GradientsAccumulator<PhysNerf>,
    /// Sum and count of the gradient alignment since the last evaluation.
    alignment: (f64, usize),
    seed: u64,
    /// The target frame of the last step (what a preview shows).
    last_target: usize,
    /// `warmup.held_out`: the warm-up frame's particles on the device (uploaded once).
    held_out_particles: Option<Tensor<2>>,
    /// The physical scalars fitted by the images, where `[joint.physics]` asks.
    physics: Option<PhysicsFitting>,
}

/// DLF's gradients at the end of a window, and whether its weights are held (`[joint.physics]
/// hold_dlf_epochs`: the norm is still checked and logged, the weights take no step).
struct DlfGrads {
    grads: GradientsParams,
    held: bool,
}

/// The gradients at the end of a window and their square sums, to be read with the step's values.
#[derive(Default)]
struct WindowGrads {
    /// PhysNeRF's, at the end of every window.
    physnerf: Option<GradientsParams>,
    /// DLF's, at the end of every `dlf_every`-th window.
    dlf: Option<GradientsParams>,
    /// The physical scalars', with DLF's.
    physics: Option<GradientsParams>,
    /// The square sums, PhysNeRF's then DLF's.
    sums: Vec<Tensor<1>>,
    /// How many values PhysNeRF's square sums read as.
    n_physnerf: usize,
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
    ) -> anyhow::Result<Self> {
        let device = dlf.device();
        let boundary = dlf.boundary(&data.walls.0, &data.walls.1, &device);
        let state = data.initial_state(&device);
        // `dlf` is the pretrained model here (a resumed run loads its own weights later)
        let terms = cfg.terms.build(&TermContext {
            pretrained: &dlf,
            radius: data.radius,
            truth: data.truth.as_deref(),
            transitions: data.transitions(),
            particles: data.initial.pos.len(),
        })?;
        let held_out_particles = data
            .held_out
            .as_ref()
            .map(|(_, p)| points_tensor(p, &device));
        let physics = cfg.physics.as_ref().map(|fit| PhysicsFitting {
            fit: fit.clone(),
            module: Physics::of_rules(&dlf.config.rules, &device),
            opt: fit.optim.group(),
        });
        Ok(Self {
            opt_physnerf: cfg.physnerf_optim.group(),
            opt_dlf: cfg.dlf_optim.group(),
            rng: Rng::stream(seed, STAGE.folder()),
            cfg: cfg.clone(),
            physnerf,
            dlf,
            data,
            boundary,
            state,
            state_host: None,
            pending_terms: vec![0.0; terms.len()],
            terms,
            pending: None,
            pending_loss: 0.0,
            physnerf_grads: GradientsAccumulator::new(),
            alignment: (0.0, 0),
            seed,
            last_target: 1,
            held_out_particles,
            physics,
        })
    }

    /// The grounded models (DLF's rules holding the physical scalars fitted, if any).
    pub fn into_models(self) -> Grounded {
        let dlf = self.stepping_dlf();
        let rules = dlf.config.rules;
        if self.physics.is_some() {
            tracing::info!(
                gravity_scale = rules.gravity_scale,
                viscosity = rules.viscosity,
                dissipation = rules.dissipation,
                "the physical scalars fitted by the images"
            );
        }
        Grounded {
            physnerf: self.physnerf,
            dlf,
        }
    }

    /// With `[joint.physics.search]`, the fitted scalars set to the grid's point of least
    /// loss ([`search`]), every point logged; nothing without it.
    pub fn search_physics(&mut self, log: &mut MetricsLog) -> anyhow::Result<()> {
        let Some(p) = &self.physics else {
            return Ok(());
        };
        let Some(grid) = &p.fit.search else {
            return Ok(());
        };
        let dlf = self.stepping_dlf();
        let (tried, truth) = search::search(
            &self.physnerf,
            &dlf,
            &self.data,
            grid,
            self.cfg.rays,
            self.seed,
        )?;
        for (k, t) in tried.iter().enumerate() {
            log.append(&search::row(k, t))?;
        }
        let best = search::best(&tried)
            .context("joint.physics.search: no point of the grid gave a finite score")?;
        if let Some(loss) = truth {
            log.append(&search::truth_row(loss))?;
        }
        tracing::info!(
            gravity_scale = best.point[0],
            viscosity = best.point[1],
            dissipation = best.point[2],
            loss = best.loss,
            truth = truth
                .map(|t| format!("{t:.5}"))
                .unwrap_or_else(|| "no true particles".into()),
            points = tried.len(),
            "the search's start for the physical scalars (truth: the true particles' score)"
        );
        let rules = neurofluid_dlf::physics::rules_with(dlf.config.rules, best.point);
        if let Some(p) = &mut self.physics {
            p.module = Physics::of_rules(&rules, &dlf.device());
        }
        Ok(())
    }

    /// DLF as it steps now: its weights, its rules holding the physical scalars fitted so far.
    fn stepping_dlf(&self) -> DlfNet {
        match &self.physics {
            Some(p) => with_fitted(self.dlf.clone(), &p.module),
            None => self.dlf.clone(),
        }
    }

    /// The image loss of iteration `step` at training frame `frame`, rendered from the
    /// prediction `pred` (`host`: its values), PhysNeRF's gradients of it accumulated.
    fn image_loss(
        &mut self,
        step: u64,
        frame: usize,
        pred: &Tensor<2>,
        host: &[[f32; 3]],
    ) -> anyhow::Result<loss::SplitOnDevice> {
        let device = pred.device();
        let (cfg, data) = (&self.cfg, &self.data);
        let (rays, colours) = training_rays(cfg, data, &mut self.rng, step, frame, host, &device)?;
        let jitter = warmup::jitter(&self.physnerf, &mut self.rng);
        let mut image = split_on_device(&self.physnerf, pred, Some(host), &rays, colours, jitter)?;
        if let Some(g) = image.physnerf_grads.take() {
            self.physnerf_grads.accumulate(&self.physnerf, g);
        }
        Ok(image)
    }

    /// Adds the gradient alignment's cosine from its three sums (none where the truth is not
    /// known).
    fn add_alignment(&mut self, sums: Vec<f64>) {
        if let Ok(sums) = <[f64; 3]>::try_from(sums)
            && let Some(c) = cosine_of_sums(sums)
        {
            self.alignment.0 += c;
            self.alignment.1 += 1;
        }
    }

    /// The step's values read back (`[fine, image, boundary, extra, terms…]`) added to the
    /// window's, and the window's statistics so far.
    fn window_so_far(&mut self, values: &[f64]) -> StepStats {
        let (fine, image, boundary, extra) = (values[0], values[1], values[2], values[3]);
        self.pending_loss += image + boundary + extra;
        for (pending, v) in self.pending_terms.iter_mut().zip(&values[4..]) {
            *pending += v;
        }
        let names = self.terms.iter().map(|t| t.name());
        StepStats {
            psnr: Some(psnr_from_mse(fine)),
            rays: self.cfg.rays,
            loss: self.pending_loss,
            losses: names.zip(self.pending_terms.iter().copied()).collect(),
            ..StepStats::default()
        }
    }

    /// The particle terms of the transition `step`: DLF's `surrogate` with them added, their
    /// detached sum (to be read with the step's values) and each one's detached value.
    fn add_terms(
        &self,
        step: &Transition,
        mut surrogate: Tensor<1>,
        boundary: &Tensor<1>,
    ) -> (Tensor<1>, Tensor<1>, Vec<Tensor<1>>) {
        let mut extra = boundary.clone().mul_scalar(0.0);
        let mut values = Vec::with_capacity(self.terms.len());
        for term in &self.terms {
            let loss = term.loss(step);
            values.push(loss.clone().detach());
            extra = extra + loss.clone().detach();
            surrogate = surrogate + loss;
        }
        (surrogate, extra, values)
    }

    /// At the end of a window, PhysNeRF's gradients of it and, when DLF steps too, DLF's from
    /// the window's surrogate; both with their square sums.
    fn window_gradients(&mut self, updates: Updates) -> anyhow::Result<WindowGrads> {
        let mut out = WindowGrads::default();
        if !updates.physnerf {
            return Ok(out);
        }
        let g = self.physnerf_grads.grads();
        let sums = gradients::grad_square_sums(&g, &self.physnerf);
        out.n_physnerf = square_sums::count(&sums);
        out.sums.extend(sums);
        out.physnerf = Some(g);
        if updates.dlf {
            let surrogate = self.pending.take().context("no loss to optimise")?;
            let g = match gradients::backward(surrogate) {
                Some(mut grads) => {
                    if let Some(p) = &self.physics {
                        out.physics = Some(GradientsParams::from_module(&mut grads, &p.module));
                    }
                    GradientsParams::from_module(&mut grads, &self.dlf)
                }
                None => GradientsParams::new(),
            };
            out.sums.extend(gradients::grad_square_sums(&g, &self.dlf));
            out.dlf = Some(g);
        }
        Ok(out)
    }

    /// Whether DLF's weights are held at 0-based iteration `step` (`[joint.physics]
    /// hold_dlf_epochs`).
    fn dlf_held(&self, step: u64) -> bool {
        self.physics
            .as_ref()
            .is_some_and(|p| step / self.data.transitions() < p.fit.hold_dlf_epochs)
    }

    /// Steps both Adams with the window's gradients, unless a norm (from the square sums `sums`)
    /// is not finite (the guard stops the run on it), and records the norms and rates in `stats`.
    fn update(
        &mut self,
        physnerf: GradientsParams,
        dlf: Option<DlfGrads>,
        physics: Option<GradientsParams>,
        sums: &[f64],
        n_physnerf: usize,
        stats: &mut StepStats,
    ) {
        let (lr_p, lr_d) = (self.opt_physnerf.lr(), self.opt_dlf.lr());
        let lr_physics = self.physics.as_ref().map(|p| p.opt.lr());
        let mut fitted = None;
        let norm_p = gradients::norm_of(&sums[..n_physnerf]);
        let norm_d = dlf
            .as_ref()
            .map(|_| gradients::norm_of(&sums[n_physnerf..]));
        if norm_p.is_finite() && norm_d.is_none_or(f64::is_finite) {
            self.physnerf = self.opt_physnerf.step(self.physnerf.clone(), physnerf);
            if let Some(DlfGrads { grads, held: false }) = dlf {
                self.dlf = self.opt_dlf.step(self.dlf.clone(), grads);
            }
            if let (Some(p), Some(g)) = (&mut self.physics, physics) {
                let values;
                (p.module, values) = p.opt.step(p.module.clone(), g).clamped();
                fitted = Some(values);
            }
        }
        // a point to log, evaluate and checkpoint at: nothing pending in either group (between
        // DLF's steps, PhysNeRF's norm is still checked for divergence)
        stats.grad_norms = vec![("physnerf", norm_p)];
        if let Some(norm_d) = norm_d {
            stats.grad_norms.push(("dlf", norm_d));
            stats.lrs = vec![("physnerf", lr_p), ("dlf", lr_d)];
            stats.updated = true;
            if let (Some(lr), Some(values)) = (lr_physics, fitted) {
                stats.lrs.push(("physics", lr));
                stats
                    .scalars
                    .extend(physics::COLUMNS.into_iter().zip(values));
            }
        }
    }
}

impl Trainer for JointTrainer {
    fn stage(&self) -> &'static str {
        STAGE.folder()
    }

    fn total_steps(&self) -> u64 {
        self.cfg.epochs * self.data.transitions()
    }

    fn step(&mut self, step: u64) -> anyhow::Result<StepStats> {
        let transitions = self.data.transitions();
        let t = (step % transitions) as usize;
        if t == 0 {
            self.state = self.data.initial_state(&self.dlf.device());
        }
        let v = with_input_noise(self.state.1.clone(), self.cfg.input_noise, self.seed, step);
        let input = (self.state.0.clone(), v);
        let (x, v) = input.clone();
        let (pred, physics) = match &self.physics {
            Some(p) => {
                let values = p.module.step_values(&p.fit);
                let used = values.detached();
                let dlf = self.dlf.clone().with_physics(Some(values));
                (dlf.step(x, v, &self.boundary), Some(used))
            }
            None => (self.dlf.step(x, v, &self.boundary), None),
        };
        // the prediction on the host, read once: the rays, the renderer's neighbour search, the
        // alignment and the state check all use it
        let pred_host = tensor_points(&pred.pos);
        self.last_target = t + 1;
        let image = self.image_loss(step, t + 1, &pred.pos, &pred_host)?;
        let boundary = boundary_penalty(pred.pos.clone(), &self.data.interior)
            .mul_scalar(self.cfg.boundary_weight);
        let surrogate = dlf_surrogate(&pred.pos, image.dx.clone()) + boundary.clone();
        let after = (pred.pos, pred.vel);
        let step_terms = Transition {
            before: &input,
            after: &after,
            frame: t + 1,
            walls: &self.boundary,
            physics: physics.as_ref(),
        };
        let (surrogate, extra, terms) = self.add_terms(&step_terms, surrogate, &boundary);
        let alignment = image
            .dx
            .and_then(|g| self.alignment_sums(t + 1, &pred_host, g));
        self.pending = Some(match self.pending.take() {
            None => surrogate,
            Some(p) => p + surrogate,
        });
        self.state = after;
        self.state_host = Some(pred_host);
        // at the end of a window the gradients too, so that the step reads its values back once
        // (a non-finite loss is not used to update: the guard stops the run on it)
        let updates = updates_after(&self.cfg, transitions, self.total_steps(), step);
        let grads = self.window_gradients(updates)?;
        let (n_terms, n_alignment) = (terms.len(), alignment.as_ref().map_or(0, |a| a.len()));
        let mut parts = vec![image.fine, image.total, boundary, extra];
        parts.extend(terms.into_iter().chain(grads.sums));
        parts.extend(alignment.into_iter().flatten());
        let mut values = read_together(parts)?;
        self.add_alignment(values.split_off(values.len() - n_alignment));
        let sums = values.split_off(4 + n_terms);
        let mut stats = self.window_so_far(&values);
        let Some(g_physnerf) = grads.physnerf else {
            return Ok(stats);
        };
        self.pending_loss = 0.0;
        self.pending_terms.fill(0.0);
        if !stats.loss.is_finite() {
            return Ok(stats);
        }
        self.update(
            g_physnerf,
            grads.dlf.map(|grads| DlfGrads {
                grads,
                held: self.dlf_held(step),
            }),
            grads.physics,
            &sums,
            grads.n_physnerf,
            &mut stats,
        );
        // the carried state leaves the graph: truncated backpropagation through time (DLF's
        // pending surrogate keeps the graphs of its transitions until its own step)
        self.state = (self.state.0.clone().detach(), self.state.1.clone().detach());
        Ok(stats)
    }

    /// The carried particles must stay finite and near the box: farther than one box size
    /// outside it, the state has exploded (and so will everything trained on it).
    fn check_state(&self) -> Result<(), String> {
        let read;
        let pos = match &self.state_host {
            Some(host) => host,
            None => {
                read = tensor_points(&self.state.0);
                &read
            }
        };
        let b = &self.data.interior;
        let margin: f32 = (0..3).map(|a| b.max[a] - b.min[a]).fold(0.0, f32::max);
        for (i, p) in pos.iter().enumerate() {
            if !p.iter().all(|v| v.is_finite()) {
                return Err(format!("predicted particle {i} is not finite ({p:?})"));
            }
            if !b.within(*p, margin) {
                return Err(format!(
                    "predicted particle {i} left the box by more than its size (at {p:?}; the \
                     box interior is {:?}–{:?})",
                    b.min, b.max
                ));
            }
        }
        Ok(())
    }

    /// The training view at the frame just predicted, rendered from the prediction, and the
    /// [`Diagnostics`].
    fn evaluate(&mut self, _done: u64) -> anyhow::Result<Option<Evaluation>> {
        let target = self.data.target(self.last_target);
        let mut evaluation = render_beside_truth(&self.physnerf, target, &self.state.0)?;
        evaluation.scores = self.diagnostics()?.scores();
        Ok(Some(evaluation))
    }

    fn save(&self, dir: &Path) -> anyhow::Result<StageState> {
        checkpoint::save_module(&self.physnerf, &files::PHYSNERF.save_path(dir))?;
        checkpoint::save_module(&self.dlf, &files::DLF.save_path(dir))?;
        let mut own = self.rng.to_state();
        let adam = files::JOINT_PHYSNERF_ADAM.save_path(dir);
        checkpoint::save_group(&self.opt_physnerf, &adam, "physnerf", &mut own)?;
        let adam = files::JOINT_DLF_ADAM.save_path(dir);
        checkpoint::save_group(&self.opt_dlf, &adam, "dlf", &mut own)?;
        if let Some(p) = &self.physics {
            checkpoint::save_module(&p.module, &files::JOINT_PHYSICS.save_path(dir))?;
            let adam = files::JOINT_PHYSICS_ADAM.save_path(dir);
            checkpoint::save_group(&p.opt, &adam, "physics", &mut own)?;
        }
        let mut w = NpzWriter::new();
        w.add_points("pos", &tensor_points(&self.state.0));
        w.add_points("vel", &tensor_points(&self.state.1));
        w.write(dir.join("carried_state.npz"))?;
        Ok(own)
    }

    fn load(&mut self, dir: &Path, done: u64, state: StageState) -> anyhow::Result<()> {
        let device = self.dlf.device();
        self.physnerf =
            checkpoint::load_module(self.physnerf.clone(), &files::PHYSNERF.load_path(dir))?;
        self.dlf = checkpoint::load_module(self.dlf.clone(), &files::DLF.load_path(dir))?;
        let implied = updates_before(&self.cfg, self.data.transitions(), self.total_steps(), done);
        let adam = files::JOINT_PHYSNERF_ADAM.load_path(dir);
        let (p, d) = (&mut self.opt_physnerf, &mut self.opt_dlf);
        checkpoint::load_group(p, &self.physnerf, &adam, "physnerf", &state, || implied.0)?;
        let adam = files::JOINT_DLF_ADAM.load_path(dir);
        checkpoint::load_group(d, &self.dlf, &adam, "dlf", &state, || implied.1)?;
        if let Some(p) = &mut self.physics {
            let path = files::JOINT_PHYSICS.load_path(dir);
            p.module = checkpoint::load_module(p.module.clone(), &path)?;
            let adam = files::JOINT_PHYSICS_ADAM.load_path(dir);
            // the scalars step with DLF
            checkpoint::load_group(&mut p.opt, &p.module, &adam, "physics", &state, || {
                implied.1
            })?;
        }
        self.rng = Rng::from_stage_state(&state, dir)?;
        if !done.is_multiple_of(self.data.transitions()) {
            let mut r = NpzReader::open(dir.join("carried_state.npz"))?;
            self.state = (
                points_tensor(&r.points("pos")?, &device),
                points_tensor(&r.points("vel")?, &device),
            );
            self.state_host = None;
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
    data.held_out = held_out_view(run)?;
    let dlf = run.load_dlf(&run.exp.dlf.weights)?;
    let mut trainer = JointTrainer::new(cfg, physnerf, dlf, data, run.exp.seed)?;
    // a fresh stage searches; a resumed one holds the scalars of its checkpoint
    if checkpoint::latest(&run.stage_dir(STAGE)).is_none() {
        trainer.search_physics(log)?;
    }
    super::drive::drive(run, log, &mut trainer, STAGE, cfg.cadence(), stop)?;
    Ok(trainer.into_models())
}

/// The models of a finished joint stage (its last checkpoint).
pub fn load_trained(run: &Run) -> anyhow::Result<Grounded> {
    let ckpt = run.latest_checkpoint(STAGE)?;
    let physnerf = PhysNerf::new(run.physnerf_config(), &run.device)?;
    let physnerf = checkpoint::load_module(physnerf, &files::PHYSNERF.load_path(&ckpt))?;
    let dlf = run.load_dlf(&run.exp.dlf.weights)?;
    let mut dlf = checkpoint::load_module(dlf, &files::DLF.load_path(&ckpt))?;
    if run.exp.joint.physics.is_some() {
        let physics = Physics::of_rules(&dlf.config.rules, &run.device);
        let physics = checkpoint::load_module(physics, &files::JOINT_PHYSICS.load_path(&ckpt))?;
        dlf = with_fitted(dlf, &physics);
    }
    Ok(Grounded { physnerf, dlf })
}

/// `dlf` whose rules hold the physical scalars of `physics` (a grounded DLF's, for every later
/// rollout).
fn with_fitted(dlf: DlfNet, physics: &Physics) -> DlfNet {
    let mut config = dlf.config;
    config.rules = physics.into_rules(config.rules);
    dlf.with_config(config)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn value(t: Tensor<1>) -> f64 {
        f64::from(t.into_scalar::<f32>())
    }

    fn rows(v: &[[f32; 3]]) -> Tensor<2> {
        points_tensor(v, &neurofluid_core::device::cpu().autodiff())
    }

    /// The device's cosine sums against the cosine summed in f64 on the host, for an
    /// anti-parallel pair (−1) and without a norm (`None`).
    #[test]
    fn the_cosine_from_device_sums_is_the_hosts() {
        let a: Vec<[f32; 3]> = (0..2000)
            .map(|i| {
                let x = i as f32;
                [(0.37 * x).sin(), (1.3 * x).cos() * 1e-6, 0.01 * x.sqrt()]
            })
            .collect();
        let b: Vec<[f32; 3]> = (0..2000)
            .map(|i| {
                let x = i as f32;
                [
                    (0.11 * x).cos(),
                    (0.7 * x).sin() - 0.2,
                    (0.05 * x).sin() * 3.0,
                ]
            })
            .collect();
        let sums = |a: &[[f32; 3]], b: &[[f32; 3]]| {
            std::array::from_fn(|k| value(cosine_sums(rows(a), rows(b))[k].clone()))
        };
        let (mut ab, mut aa, mut bb) = (0.0f64, 0.0f64, 0.0f64);
        for (p, q) in a.iter().zip(&b) {
            for k in 0..3 {
                let (x, y) = (f64::from(p[k]), f64::from(q[k]));
                (ab, aa, bb) = (ab + x * y, aa + x * x, bb + y * y);
            }
        }
        let want = ab / (aa.sqrt() * bb.sqrt());
        let got = cosine_of_sums(sums(&a, &b)).unwrap();
        assert!((got - want).abs() < 1e-6, "{got} against {want}");
        let neg: Vec<[f32; 3]> = a.iter().map(|v| v.map(|c| -2.0 * c)).collect();
        let anti = cosine_of_sums(sums(&a, &neg)).unwrap();
        assert!((anti + 1.0).abs() < 1e-6, "{anti}");
        assert_eq!(cosine_of_sums(sums(&a, &vec![[0.0; 3]; 2000])), None);
    }
}
