//! Warm-up (spec §4.1): PhysNeRF alone on the first frame, seen from the warm-up views. Every
//! step draws `rays` pixels per view (from the central window during the precrop iterations),
//! sums the views' coarse + fine MSE and takes one Adam step with the learning rate
//! lr0·0.1^(s/decay_steps). On an accelerator the views' rays go through the renderer in one
//! pass (one read of the coarse weights and one set of kernel launches a step, not one per
//! view); on the CPU each view has its pass, as when the published figures were measured.

use std::path::Path;

use anyhow::Context;
use burn::optim::GradientsParams;
use burn::prelude::*;
use neurofluid_core::gradients;
use neurofluid_core::scene::{Role, Scene};
use neurofluid_core::transfer::read_together;
use neurofluid_physnerf::{Loss, PhysNerf, RayBatch};

use super::run_folder::Run;
use super::views::{ViewFrame, batch_of, load_particles, points_tensor, render_beside_truth};
use crate::config::Cadenced;
use crate::config::WarmupSection;
use crate::optim::{Group, WarmupGroup};
use crate::stage::{Stage, files};
use crate::trainer::checkpoint;
use crate::trainer::{Evaluation, StageState, StepStats, Trainer};
use neurofluid_core::sampler::Rng;
use neurofluid_outputs::metrics_log::{MetricsLog, psnr_from_mse};

/// Folder of the stage inside the run folder.
pub const STAGE: Stage = Stage::Warmup;

/// What the warm-up trains on: the warm-up views of frame 0, the particles of frame 0 and the
/// view its previews render at the same frame (the held-out warm-up view, else the first test
/// view).
#[derive(Debug, Clone)]
pub struct WarmupData {
    /// The warm-up views.
    pub views: Vec<ViewFrame>,
    /// Particle positions of frame 0.
    pub particles: Vec<[f32; 3]>,
    /// The previews' view at frame 0, when previews are on.
    pub held_out: Option<ViewFrame>,
}

impl WarmupData {
    /// Loads the data `cfg` asks for from `scene`.
    pub fn load(scene: &Scene, cfg: &WarmupSection) -> anyhow::Result<Self> {
        let t0 = scene.frames(Role::Warmup).start;
        let views = cfg
            .views(scene)
            .iter()
            .map(|v| ViewFrame::load(scene, Role::Warmup, v, t0))
            .collect::<anyhow::Result<Vec<_>>>()?;
        anyhow::ensure!(!views.is_empty(), "the warm-up has no views");
        let gt = load_particles(scene, Role::Warmup, t0, "warm-up particles")?;
        let held_out = cfg
            .preview_view(scene)
            .map(|(v, role)| ViewFrame::load(scene, role, &v, t0))
            .transpose()?;
        Ok(Self {
            views,
            particles: gt.pos,
            held_out,
        })
    }
}

/// PhysNeRF, its Adam and the pixel stream, trained on frame 0.
pub struct WarmupTrainer {
    cfg: WarmupSection,
    physnerf: PhysNerf,
    opt: Group<WarmupGroup>,
    rng: Rng,
    data: WarmupData,
    particles: Tensor<2>,
    one_pass: bool,
}

impl WarmupTrainer {
    /// A warm-up of `physnerf` on `data`; the pixel stream follows `seed`.
    pub fn new(cfg: &WarmupSection, physnerf: PhysNerf, data: WarmupData, seed: u64) -> Self {
        let device = physnerf.device();
        Self {
            opt: cfg.optim.group(),
            rng: Rng::stream(seed, STAGE.folder()),
            particles: points_tensor(&data.particles, &device),
            one_pass: !neurofluid_core::device::is_host(&device),
            cfg: cfg.clone(),
            physnerf,
            data,
        }
    }

    /// Renders every view's rays of a step in one pass (`true`, the default on an accelerator:
    /// one read of the coarse weights and one set of kernel launches instead of one per view) or
    /// each view in a pass of its own (the default on the CPU, whose figures were measured so).
    /// The loss is the same sum of the views' MSEs either way.
    pub fn with_one_pass(mut self, one_pass: bool) -> Self {
        self.one_pass = one_pass;
        self
    }

    /// The trained PhysNeRF.
    pub fn into_physnerf(self) -> PhysNerf {
        self.physnerf
    }

    /// PhysNeRF now.
    pub fn physnerf(&self) -> &PhysNerf {
        &self.physnerf
    }

    /// The renderer's loss on `rays` (target colours `target`) through the warm-up's particles.
    fn loss_of(&mut self, rays: &RayBatch, target: Tensor<2>) -> anyhow::Result<Loss> {
        let jitter = jitter(&self.physnerf, &mut self.rng);
        let out = self.physnerf.render_rays_with_host(
            &self.particles,
            &self.data.particles,
            rays,
            jitter,
        )?;
        Ok(self.physnerf.loss(&out, target))
    }

    /// A step's loss (the views' coarse + fine MSEs summed) and fine MSEs, one pass per view.
    fn view_by_view(&mut self, step: u64) -> anyhow::Result<(Tensor<1>, Vec<Tensor<1>>)> {
        let device = self.particles.device();
        let mut total: Option<Tensor<1>> = None;
        let mut fine = Vec::with_capacity(self.data.views.len());
        for v in 0..self.data.views.len() {
            let view = &self.data.views[v];
            let (w, h) = (view.camera.width, view.camera.height);
            let pixels = self
                .rng
                .sample_pixels(self.cfg.rays, w, h, self.cfg.precrop_at(step))?;
            let (rays, target) = view.batch(&pixels, &device);
            let loss = self.loss_of(&rays, target)?;
            fine.push(loss.fine);
            total = Some(match total {
                None => loss.total,
                Some(t) => t + loss.total,
            });
        }
        Ok((total.context("the warm-up has no views")?, fine))
    }

    /// The same loss with every view's rays in one pass: the batch's MSEs are the means over all
    /// views' rays, each view `rays` of them, so their sum over the views is the batch's times
    /// the number of views.
    fn views_in_one_pass(&mut self, step: u64) -> anyhow::Result<(Tensor<1>, Vec<Tensor<1>>)> {
        let device = self.particles.device();
        let precrop = self.cfg.precrop_at(step);
        let views = &self.data.views;
        anyhow::ensure!(!views.is_empty(), "the warm-up has no views");
        let mut pixels = Vec::with_capacity(views.len());
        for view in views {
            let (w, h) = (view.camera.width, view.camera.height);
            pixels.push(self.rng.sample_pixels(self.cfg.rays, w, h, precrop)?);
        }
        let parts: Vec<(&ViewFrame, &[u32])> = views
            .iter()
            .zip(&pixels)
            .map(|(v, p)| (v, p.as_slice()))
            .collect();
        let (rays, target) = batch_of(&parts, &device);
        let n = parts.len() as f64;
        let loss = self.loss_of(&rays, target)?;
        Ok((loss.total * n, vec![loss.fine]))
    }
}

/// The stream the renderer jitters its depths from, where it does (`physnerf.stratified`).
pub(crate) fn jitter<'a>(
    physnerf: &PhysNerf,
    rng: &'a mut Rng,
) -> Option<&'a mut dyn rand::RngCore> {
    if physnerf.config.stratified {
        Some(rng)
    } else {
        None
    }
}

/// One renderer update: what [`renderer_update`] read back and the updated PhysNeRF.
pub struct RendererUpdate {
    /// The updated PhysNeRF (`None` when the loss or the gradients were not finite, or the loss
    /// depended on nothing trainable: the guard stops the run on a non-finite loss).
    pub physnerf: Option<PhysNerf>,
    /// The loss.
    pub loss: f64,
    /// PSNR of the mean of the fine MSEs.
    pub psnr: f64,
    /// The L2 norm of the gradients (0 without any).
    pub grad_norm: f64,
}

/// Differentiates `total` (whose fine MSEs, one per image batch, are `fine`) and takes one step
/// of `opt` on `physnerf`, reading back once: the fine MSEs, the loss and the gradients' squares.
pub fn renderer_update<G: crate::optim::OptimDefaults>(
    physnerf: &PhysNerf,
    opt: &mut Group<G>,
    fine: Vec<Tensor<1>>,
    total: Tensor<1>,
) -> anyhow::Result<RendererUpdate> {
    let batches = fine.len();
    let grads =
        gradients::backward(total.clone()).map(|g| GradientsParams::from_grads(g, physnerf));
    let mut parts = fine;
    parts.push(total);
    if let Some(g) = &grads {
        parts.extend(gradients::grad_square_sums(g, physnerf));
    }
    let values = read_together(parts)?;
    // each term divided first, in the order the warm-up has always logged its PSNR
    let n = batches.max(1) as f64;
    let fine_mse = values[..batches].iter().fold(0.0, |sum, v| sum + v / n);
    let loss = values[batches];
    let mut update = RendererUpdate {
        physnerf: None,
        loss,
        psnr: psnr_from_mse(fine_mse),
        grad_norm: 0.0,
    };
    if loss.is_finite()
        && let Some(grads) = grads
    {
        update.grad_norm = gradients::norm_of(&values[batches + 1..]);
        if update.grad_norm.is_finite() {
            update.physnerf = Some(opt.step(physnerf.clone(), grads));
        }
    }
    Ok(update)
}

impl Trainer for WarmupTrainer {
    fn stage(&self) -> &'static str {
        STAGE.folder()
    }

    fn total_steps(&self) -> u64 {
        self.cfg.iters
    }

    fn step(&mut self, step: u64) -> anyhow::Result<StepStats> {
        let lr = self.opt.lr();
        let (total, fine) = if self.one_pass {
            self.views_in_one_pass(step)?
        } else {
            self.view_by_view(step)?
        };
        let update = renderer_update(&self.physnerf, &mut self.opt, fine, total)?;
        if let Some(updated) = update.physnerf {
            self.physnerf = updated;
        }
        Ok(StepStats {
            loss: update.loss,
            psnr: Some(update.psnr),
            rays: self.cfg.rays * self.data.views.len(),
            lrs: vec![("physnerf", lr)],
            grad_norms: vec![("physnerf", update.grad_norm)],
            updated: true,
            ..StepStats::default()
        })
    }

    fn evaluate(&mut self, _done: u64) -> anyhow::Result<Option<Evaluation>> {
        match &self.data.held_out {
            Some(view) => render_beside_truth(&self.physnerf, view, &self.particles).map(Some),
            None => Ok(None),
        }
    }

    fn save(&self, dir: &Path) -> anyhow::Result<StageState> {
        checkpoint::save_module(&self.physnerf, &files::PHYSNERF.save_path(dir))?;
        let mut state = self.rng.to_state();
        let adam = files::WARMUP_PHYSNERF_ADAM.save_path(dir);
        checkpoint::save_group(&self.opt, &adam, "physnerf", &mut state)?;
        Ok(state)
    }

    fn load(&mut self, dir: &Path, done: u64, state: StageState) -> anyhow::Result<()> {
        self.physnerf =
            checkpoint::load_module(self.physnerf.clone(), &files::PHYSNERF.load_path(dir))?;
        let adam = files::WARMUP_PHYSNERF_ADAM.load_path(dir);
        // every step updates
        checkpoint::load_group(
            &mut self.opt,
            &self.physnerf,
            &adam,
            "physnerf",
            &state,
            || done,
        )?;
        self.rng = Rng::from_stage_state(&state, dir)?;
        Ok(())
    }
}

/// A fresh PhysNeRF for `run`, initialised from the experiment's seed (the same weights on
/// every device).
pub fn new_physnerf(run: &Run) -> anyhow::Result<PhysNerf> {
    neurofluid_core::device::init_seeded(run.exp.seed, &run.device, |cpu| {
        PhysNerf::new(run.physnerf_config(), cpu)
    })
    .context("building PhysNeRF from [physnerf]")
}

/// Runs (or resumes) the warm-up of `run` with the CLI's sinks and returns PhysNeRF.
pub fn run(run: &Run, log: &mut MetricsLog) -> anyhow::Result<PhysNerf> {
    run_until(run, log, None)
}

/// Runs (or resumes) the warm-up up to step `stop` (all of it for `None`), checkpointing
/// there, so a long warm-up can run in pieces.
pub fn run_until(run: &Run, log: &mut MetricsLog, stop: Option<u64>) -> anyhow::Result<PhysNerf> {
    let cfg = &run.exp.warmup;
    let data = warmup_data(run)?;
    tracing::info!(
        views = data.views.len(),
        iters = cfg.iters,
        rays = cfg.rays,
        particles = data.particles.len(),
        "warm-up"
    );
    let mut trainer = WarmupTrainer::new(cfg, new_physnerf(run)?, data, run.exp.seed);
    super::drive::drive(run, log, &mut trainer, STAGE, cfg.cadence(), stop)?;
    Ok(trainer.into_physnerf())
}

/// The warm-up's views and particles in `run` (the starting particles of its first frame).
pub fn warmup_data(run: &Run) -> anyhow::Result<WarmupData> {
    let mut data = WarmupData::load(&run.scene, &run.exp.warmup)?;
    data.particles = warmup_particles(run)?;
    Ok(data)
}

/// The particles the warm-up renders in `run`: the starting particles of its frame.
pub fn warmup_particles(run: &Run) -> anyhow::Result<Vec<[f32; 3]>> {
    let t0 = run.scene.frames(Role::Warmup).start;
    Ok(super::initial::starting_particles(run, Role::Warmup, t0, "warm-up particles")?.pos)
}

/// PhysNeRF of a finished warm-up (its last checkpoint).
pub fn load_trained(run: &Run) -> anyhow::Result<PhysNerf> {
    let ckpt = run.latest_checkpoint(STAGE)?;
    let model = PhysNerf::new(run.physnerf_config(), &run.device)?;
    checkpoint::load_module(model, &files::PHYSNERF.load_path(&ckpt))
}
