//! The renderer refit (`refit.enabled`, an option; the paper renders its novel views with the
//! PhysNeRF trained jointly with DLF). After grounding, a second PhysNeRF (`[physnerf]` with
//! `refit.positions`) is warmed up on frame 0 exactly as the warm-up stage says (`[warmup]`), then
//! trained on the joint stage's images as the joint stage trains its renderer (`joint.rays`,
//! `joint.foreground_rays`, `joint.precrop_iters`, `joint.physnerf_optim`, `joint.epochs` over the
//! transitions), with two differences: DLF is frozen, so every frame's particles are the grounded
//! DLF's rollout from the first training frame's true state, and the renderer is updated after
//! every transition (`joint.physnerf_optim`'s schedule counts these updates, `bptt_steps` times
//! as many as the joint stage's renderer takes). The evaluation then renders NeuroFluid's views,
//! and the renderer on the true particles, with it; d and d′ are the joint stage's. It is fitted
//! to the grounded DLF as trained: with `diagnostics.weight_interpolation` below 1 the evaluation rolls
//! out another DLF than the one it was fitted to. Made from the stages before it alone, it starts
//! over when its settings changed ([`start_over_if_stale`]).
//!
//! With `refit.replay_rays` each fit step also replays the warm-up stage's renderer's renders of
//! the warm-up frame from all round the fluid ([`super::orbit`]), so that fitting one view does
//! not move the colour drawn from the others; with `warmup.held_out` the refit logs
//! `psnr_held_out` as the joint stage does.
//!
//! Why: a renderer that moves with its particles (`positions = "relative"`) carries over from the
//! warm-up's frame to the others better than the paper's, but trained during grounding it moved
//! DLF less (docs/notebook/benchmarks-history.md, "a renderer that moves with its particles"). Fitted afterwards, it
//! cannot change the dynamics.

use std::path::Path;

use anyhow::Context;
use burn::tensor::Tensor;
use neurofluid_core::scene::Role;
use neurofluid_dlf::DlfNet;
use neurofluid_physnerf::PhysNerf;

use super::joint::{self, JointData, psnr_on_truth, training_rays};
use super::run_folder::Run;
use super::views::{points_tensor, render_beside_truth};
use super::warmup::{self, WarmupData, WarmupTrainer, renderer_update};
use crate::config::{Cadenced, JointSection, WarmupSection};
use crate::optim::{Group, JointPhysNerfGroup};
use crate::stage::{Stage, files};
use crate::trainer::checkpoint;
use crate::trainer::{Evaluation, StageState, StepStats, Trainer};
use neurofluid_core::sampler::Rng;
use neurofluid_outputs::metrics_log::MetricsLog;

/// Folder of the stage inside the run folder.
pub const STAGE: Stage = Stage::Refit;

/// The name of the refit's PhysNeRF group in its checkpoints and logs.
const GROUP: &str = "physnerf";

/// The second phase: the renderer on the grounded rollout.
struct FitPhase {
    physnerf: PhysNerf,
    opt: Group<JointPhysNerfGroup>,
    rng: Rng,
}

/// The refit: its warm-up (a [`WarmupTrainer`] of the second renderer), then its fit to the
/// grounded rollout.
pub struct RefitTrainer {
    warmup_iters: u64,
    /// The warm-up's own preview cadence (its held-out pictures during the warm-up phase).
    warmup_previews: u64,
    joint: JointSection,
    warmup: WarmupTrainer,
    fit: Option<FitPhase>,
    data: JointData,
    /// The grounded DLF's rollout over the training frames (index 0: the true first state).
    rollout: Vec<Vec<[f32; 3]>>,
    /// `refit.replay_rays` > 0: what every fit step replays.
    replay: Option<Replay>,
    /// `warmup.held_out`: the warm-up frame's particles on the device (uploaded once).
    held_out_particles: Option<Tensor<2>>,
    seed: u64,
}

/// The warm-up renderer's orbit that each fit step replays rays of (`refit.replay_rays`).
struct Replay {
    /// The orbit's views and the warm-up frame's particles.
    orbit: WarmupData,
    /// Those particles on the device (uploaded once).
    particles: Tensor<2>,
    /// Rays per fit step.
    rays: usize,
}

/// What a refit fits to: the warm-up's images, the joint stage's images with the grounded
/// rollout's particles, and the orbit replayed beside them.
pub struct RefitInputs {
    /// The warm-up's views and particles (the refit's first phase).
    pub warmup_data: WarmupData,
    /// The joint stage's images.
    pub data: JointData,
    /// The grounded rollout over the training frames (index 0: the first state).
    pub rollout: Vec<Vec<[f32; 3]>>,
    /// An orbit's views and the rays of them replayed at every fit step (none without it).
    pub replay: Option<(WarmupData, usize)>,
}

impl RefitTrainer {
    /// A refit of the fresh renderer `physnerf` to `inputs`: its warm-up as `warmup` says, then
    /// the joint stage's images with the rollout's particles, at `joint`'s rays and rates.
    pub fn new(
        warmup: &WarmupSection,
        joint: &JointSection,
        physnerf: PhysNerf,
        inputs: RefitInputs,
        seed: u64,
    ) -> anyhow::Result<Self> {
        let RefitInputs {
            warmup_data,
            data,
            rollout,
            replay,
        } = inputs;
        anyhow::ensure!(
            rollout.len() == data.views[0].len(),
            "the grounded rollout has {} states for {} training frames",
            rollout.len(),
            data.views[0].len()
        );
        let device = physnerf.device();
        let replay = replay.map(|(orbit, rays)| Replay {
            particles: points_tensor(&orbit.particles, &device),
            orbit,
            rays,
        });
        let held_out_particles = data
            .held_out
            .as_ref()
            .map(|(_, particles)| points_tensor(particles, &device));
        Ok(Self {
            warmup_iters: warmup.iters,
            warmup_previews: warmup.preview_every,
            joint: joint.clone(),
            warmup: WarmupTrainer::new(warmup, physnerf, warmup_data, seed),
            fit: None,
            data,
            rollout,
            replay,
            held_out_particles,
            seed,
        })
    }

    /// The renderer now.
    pub fn physnerf(&self) -> &PhysNerf {
        match &self.fit {
            Some(fit) => &fit.physnerf,
            None => self.warmup.physnerf(),
        }
    }

    /// The second phase, begun from the warm-up's renderer when it has not begun yet.
    fn fit_phase(&mut self) -> &mut FitPhase {
        let (warmup, joint, seed) = (&self.warmup, &self.joint, self.seed);
        self.fit.get_or_insert_with(|| FitPhase {
            physnerf: warmup.physnerf().clone(),
            opt: joint.physnerf_optim.group(),
            rng: Rng::stream(seed, STAGE.folder()),
        })
    }

    fn fit_step(&mut self, step: u64) -> anyhow::Result<StepStats> {
        let i = step - self.warmup_iters;
        let t = (i % self.data.transitions()) as usize + 1;
        let (cfg, data, rollout) = (&self.joint, &self.data, &self.rollout);
        let fit = self
            .fit
            .as_mut()
            .context("the fit phase begins in `step`")?;
        let device = fit.physnerf.device();
        let particles = &rollout[t];
        let (rays, colours) = training_rays(cfg, data, &mut fit.rng, i, t, particles, &device)?;
        let jitter = super::warmup::jitter(&fit.physnerf, &mut fit.rng);
        let positions = points_tensor(particles, &device);
        let out = fit
            .physnerf
            .render_rays_with_host(&positions, particles, &rays, jitter)?;
        let loss = fit.physnerf.loss(&out, colours);
        let mut total = loss.total;
        if let Some(r) = &self.replay {
            let replayed = replay_loss(
                &fit.physnerf,
                &r.orbit,
                &r.particles,
                r.rays,
                &mut fit.rng,
                i,
            )?;
            total = total + replayed;
        }
        let lr = fit.opt.lr();
        let update = renderer_update(&fit.physnerf, &mut fit.opt, vec![loss.fine], total)?;
        if let Some(updated) = update.physnerf {
            fit.physnerf = updated;
        }
        Ok(StepStats {
            loss: update.loss,
            psnr: Some(update.psnr),
            rays: cfg.rays,
            lrs: vec![(GROUP, lr)],
            grad_norms: vec![(GROUP, update.grad_norm)],
            updated: true,
            ..StepStats::default()
        })
    }
}

impl Trainer for RefitTrainer {
    fn stage(&self) -> &'static str {
        STAGE.folder()
    }

    fn total_steps(&self) -> u64 {
        self.warmup_iters + self.joint.epochs * self.data.transitions()
    }

    fn step(&mut self, step: u64) -> anyhow::Result<StepStats> {
        if step < self.warmup_iters {
            return self.warmup.step(step);
        }
        self.fit_phase();
        self.fit_step(step)
    }

    fn evaluate(&mut self, done: u64) -> anyhow::Result<Option<Evaluation>> {
        let mut evaluation = if done <= self.warmup_iters {
            // the warm-up phase: the warm-up's held-out picture of frame 0, at the warm-up
            // stage's own cadence (a whole image is many renders of the fit's rays)
            let due = self.warmup_previews > 0 && done.is_multiple_of(self.warmup_previews);
            match due
                .then(|| self.warmup.evaluate(done))
                .transpose()?
                .flatten()
            {
                Some(e) => e,
                None => return Ok(None),
            }
        } else {
            // the fit: the training view of the frame fitted last, from the grounded rollout
            let t = ((done - self.warmup_iters - 1) % self.data.transitions()) as usize + 1;
            let particles = points_tensor(&self.rollout[t], &self.physnerf().device());
            render_beside_truth(self.physnerf(), self.data.target(t), &particles)?
        };
        let psnr_true = psnr_on_truth(self.physnerf(), &self.data, self.joint.rays, self.seed)?;
        evaluation
            .scores
            .extend(psnr_true.map(|p| ("psnr_true", p)));
        if let (Some((view, _)), Some(particles)) = (&self.data.held_out, &self.held_out_particles)
        {
            let psnr = render_beside_truth(self.physnerf(), view, particles)?.psnr;
            evaluation.scores.extend(psnr.map(|p| ("psnr_held_out", p)));
        }
        Ok(Some(evaluation))
    }

    fn save(&self, dir: &Path) -> anyhow::Result<StageState> {
        let Some(fit) = &self.fit else {
            return self.warmup.save(dir);
        };
        checkpoint::save_module(&fit.physnerf, &files::PHYSNERF.save_path(dir))?;
        let mut state = fit.rng.to_state();
        let adam = files::REFIT_PHYSNERF_ADAM.save_path(dir);
        checkpoint::save_group(&fit.opt, &adam, GROUP, &mut state)?;
        Ok(state)
    }

    fn load(&mut self, dir: &Path, done: u64, state: StageState) -> anyhow::Result<()> {
        if done <= self.warmup_iters {
            self.fit = None;
            return self.warmup.load(dir, done, state);
        }
        let physnerf = self.warmup.physnerf().clone();
        let physnerf = checkpoint::load_module(physnerf, &files::PHYSNERF.load_path(dir))?;
        let mut opt = self.joint.physnerf_optim.group();
        let adam = files::REFIT_PHYSNERF_ADAM.load_path(dir);
        // every step of the fit updates
        let fitted = done - self.warmup_iters;
        checkpoint::load_group(&mut opt, &physnerf, &adam, GROUP, &state, || fitted)?;
        self.fit = Some(FitPhase {
            physnerf,
            opt,
            rng: Rng::from_stage_state(&state, dir)?,
        });
        Ok(())
    }
}

/// A fresh second renderer for `run` (`[physnerf]` with `refit.positions`), initialised from
/// the experiment's seed.
fn new_renderer(run: &Run) -> anyhow::Result<PhysNerf> {
    neurofluid_core::device::init_seeded(run.exp.seed, &run.device, |cpu| {
        PhysNerf::new(run.refit_physnerf_config(), cpu)
    })
    .context("building the refitted PhysNeRF from [physnerf] and refit.positions")
}

/// Removes the refit's checkpoints when they were made under other settings (a joint stage
/// that went on, another `[refit]`): made from the stages before it alone, the refit starts over
/// rather than refuse the run ([`Run::prepare`], before the metrics log is opened).
pub(super) fn start_over_if_stale(run: &Run) -> anyhow::Result<()> {
    let dir = run.stage_dir(STAGE);
    let Some(ckpt) = checkpoint::latest(&dir) else {
        return Ok(());
    };
    let state: checkpoint::CheckpointState = checkpoint::load_state(&ckpt)?;
    let changes = match &state.settings {
        Some(saved) => run.settings(STAGE).changes_since(saved),
        None => Vec::new(),
    };
    if !changes.is_empty() {
        let list: Vec<String> = changes.iter().map(ToString::to_string).collect();
        tracing::warn!(
            "the refit in {} was made under other settings ({}): it starts over",
            dir.display(),
            list.join("; ")
        );
        std::fs::remove_dir_all(&dir).with_context(|| format!("removing {}", dir.display()))?;
    }
    Ok(())
}

/// Runs (or resumes) the refit of `run` to the grounded `dlf` and returns its renderer.
pub fn run(run: &Run, log: &mut MetricsLog, dlf: &DlfNet) -> anyhow::Result<PhysNerf> {
    run_until(run, log, dlf, None)
}

/// Runs (or resumes) the refit up to step `stop` (all of it for `None`), checkpointing there.
pub fn run_until(
    run: &Run,
    log: &mut MetricsLog,
    dlf: &DlfNet,
    stop: Option<u64>,
) -> anyhow::Result<PhysNerf> {
    let exp = &run.exp;
    let mut data = JointData::load(&run.scene, &exp.joint)?;
    let first = run.scene.frames(Role::Train).start;
    data.initial =
        super::initial::starting_particles(run, Role::Train, first, "first training frame")?;
    data.held_out = joint::held_out_view(run)?;
    let rollout = joint::training_rollout(dlf, &data).pos;
    tracing::info!(
        positions = ?exp.refit.positions,
        warmup_iters = exp.warmup.iters,
        fit_steps = exp.joint.epochs * data.transitions(),
        "renderer refit to the grounded rollout"
    );
    let warmup_data = warmup::warmup_data(run)?;
    let replay = if exp.refit.replay_rays > 0 {
        let teacher = warmup::load_trained(run)?;
        let up = run.scene.up_axis().index();
        let replay = super::orbit::orbit_replay(&teacher, &warmup_data, up)
            .context("the warm-up renderer's orbit (refit.replay_rays)")?;
        Some((replay, exp.refit.replay_rays))
    } else {
        None
    };
    let mut trainer = RefitTrainer::new(
        &exp.warmup,
        &exp.joint,
        new_renderer(run)?,
        RefitInputs {
            warmup_data,
            data,
            rollout,
            replay,
        },
        exp.seed,
    )?;
    // the joint stage's cadence, through both phases
    super::drive::drive(run, log, &mut trainer, STAGE, exp.joint.cadence(), stop)?;
    Ok(trainer.physnerf().clone())
}

/// The models the evaluation of `run` renders with: the joint stage's, with the refitted renderer
/// in place of the jointly trained one when `refit.enabled` (its last checkpoint).
pub fn for_views(run: &Run, mut grounded: joint::Grounded) -> anyhow::Result<joint::Grounded> {
    if !run.exp.refit.enabled {
        return Ok(grounded);
    }
    let ckpt = run.latest_checkpoint(STAGE)?;
    let model = PhysNerf::new(run.refit_physnerf_config(), &run.device)?;
    grounded.physnerf = checkpoint::load_module(model, &files::PHYSNERF.load_path(&ckpt))?;
    Ok(grounded)
}

/// The replayed loss of iteration `step`: `rays` pixels of one of `replay`'s views in turn,
/// rendered by `physnerf` from `replay`'s particles (`particles`, on the device), against the
/// view's image: the warm-up's images or the warm-up renderer's own renders from all round
/// ([`super::orbit`]).
fn replay_loss(
    physnerf: &PhysNerf,
    replay: &WarmupData,
    particles: &Tensor<2>,
    rays: usize,
    rng: &mut Rng,
    step: u64,
) -> anyhow::Result<Tensor<1>> {
    let device = physnerf.device();
    let view = &replay.views[(step % replay.views.len() as u64) as usize];
    let pixels = rng.sample_pixels(rays, view.camera.width, view.camera.height, None)?;
    let (rays, colours) = view.batch(&pixels, &device);
    let jitter = super::warmup::jitter(physnerf, rng);
    let out = physnerf.render_rays_with_host(particles, &replay.particles, &rays, jitter)?;
    Ok(physnerf.loss(&out, colours).total)
}
