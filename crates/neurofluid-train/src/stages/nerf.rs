//! A plain NeRF or NeRF-T trained on the scene's images, by the same driver as every stage
//! (checkpoints, exact resume, progress, previews, metrics log). NeRF trains on the warm-up views
//! of frame 0 (the paper's NeRF baseline, and the density field of the initial particles);
//! NeRF-T on one warm-up view per training frame, cycling through the views (the paper's protocol
//! for its time-conditioned baselines), or on the images NeuroFluid trains on
//! (`nerf.t_images = "neurofluid"`).

use std::path::Path;

use anyhow::Context;
use burn::optim::GradientsParams;
use neurofluid_core::gradients;
use neurofluid_core::metrics::{RgbImage, psnr};
use neurofluid_core::scene::{Role, Scene};
use neurofluid_outputs::pictures::side_by_side;
use neurofluid_physnerf::{Nerf, NerfConfig};

use super::run_folder::Run;
use super::views::{ViewFrame, batch_of, joint_sources, ray_share, require_warmup_every_frame};
use crate::config::Cadenced;
use crate::config::{Experiment, NerfSection, NerfTImages};
use crate::optim::{Group, NerfGroup};
use crate::stage::{Stage, files};
use crate::trainer::checkpoint;
use crate::trainer::{Evaluation, StageState, StepStats, Trainer};
use neurofluid_core::sampler::Rng;
use neurofluid_outputs::metrics_log::{MetricsLog, psnr_from_mse};

/// Which NeRF.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum NerfKind {
    /// NeRF on the warm-up views of frame 0.
    Nerf,
    /// NeRF-T: time as an input, one warm-up view per training frame.
    #[value(name = "nerf-t")]
    NerfT,
}

impl NerfKind {
    /// The stage that trains it.
    pub const fn stage(self) -> Stage {
        match self {
            NerfKind::Nerf => Stage::Nerf,
            NerfKind::NerfT => Stage::NerfT,
        }
    }

    /// The name in tables.
    pub const fn label(self) -> &'static str {
        self.stage().label()
    }
}

/// One training image: the view of a frame and, for NeRF-T, its time.
#[derive(Debug, Clone)]
pub struct TimedView {
    /// Camera and image.
    pub view: ViewFrame,
    /// `(t − t₀)/frames` of the training sequence (NeRF-T), `None` for NeRF.
    pub time: Option<f64>,
}

/// What a NeRF trains on, and the held-out view its previews render.
#[derive(Debug, Clone)]
pub struct NerfData {
    /// The training images.
    pub images: Vec<TimedView>,
    /// The first test view at frame t₀ (time 0), when previews are on.
    pub held_out: Option<TimedView>,
}

/// The time input of frame `t` for a training sequence over `frames` (t₀ at 0, t₀ + frames at 1).
pub fn time_of(t: usize, frames: &std::ops::Range<usize>) -> f64 {
    (t as f64 - frames.start as f64) / frames.len().max(1) as f64
}

impl NerfData {
    /// The images of `kind`'s protocol from `scene`, as `exp` sets them: the warm-up views
    /// (`warmup.views`) and, for NeRF-T, `nerf.t_images`.
    pub fn load(
        scene: &Scene,
        kind: NerfKind,
        exp: &Experiment,
        preview: bool,
    ) -> anyhow::Result<Self> {
        let views = exp.warmup.views(scene);
        anyhow::ensure!(
            !views.is_empty(),
            "the scene has no warm-up views (scene.json `warmup.views`): a NeRF needs images of \
             frame 0 from several views"
        );
        let t0 = scene.frames(Role::Warmup).start;
        let train = scene.frames(Role::Train);
        let time = |t| (kind == NerfKind::NerfT).then(|| time_of(t, &train));
        let load = |role, view: &str, t| -> anyhow::Result<TimedView> {
            Ok(TimedView {
                view: ViewFrame::load(scene, role, view, t)?,
                time: time(t),
            })
        };
        let first_frame = || views.iter().map(|v| load(Role::Warmup, v, t0));
        let images = match (kind, exp.nerf.t_images) {
            (NerfKind::Nerf, _) => first_frame().collect::<anyhow::Result<Vec<_>>>()?,
            (NerfKind::NerfT, NerfTImages::Cycle) => {
                require_warmup_every_frame(scene, "NeRF-T (one warm-up view per frame)")?;
                train
                    .clone()
                    .map(|t| load(Role::Warmup, &views[(t - train.start) % views.len()], t))
                    .collect::<anyhow::Result<Vec<_>>>()?
            }
            (NerfKind::NerfT, NerfTImages::Neurofluid) => {
                let joint = joint_sources(scene, &exp.joint)?;
                let over_time = joint
                    .iter()
                    .flat_map(|(role, v)| train.clone().map(move |t| (*role, v, t)));
                first_frame()
                    .chain(over_time.map(|(role, v, t)| load(role, v, t)))
                    .collect::<anyhow::Result<Vec<_>>>()?
            }
        };
        let held_out = match scene.views(Role::Test).first() {
            Some(v) if preview => Some(TimedView {
                view: ViewFrame::load(scene, Role::Test, v, t0)?,
                time: (kind == NerfKind::NerfT).then_some(0.0),
            }),
            _ => None,
        };
        Ok(Self { images, held_out })
    }
}

/// A NeRF, its Adam and its pixel stream.
pub struct NerfTrainer {
    kind: NerfKind,
    cfg: NerfSection,
    nerf: Nerf,
    opt: Group<NerfGroup>,
    rng: Rng,
    data: NerfData,
}

impl NerfTrainer {
    /// A trainer of `nerf` on `data`; the pixel stream follows `seed`.
    pub fn new(kind: NerfKind, cfg: &NerfSection, nerf: Nerf, data: NerfData, seed: u64) -> Self {
        Self {
            kind,
            opt: cfg.optim.group(),
            rng: Rng::stream(seed, kind.stage().folder()),
            cfg: cfg.clone(),
            nerf,
            data,
        }
    }

    /// The trained NeRF.
    pub fn into_nerf(self) -> Nerf {
        self.nerf
    }
}

impl Trainer for NerfTrainer {
    fn stage(&self) -> &'static str {
        self.kind.stage().folder()
    }

    fn total_steps(&self) -> u64 {
        self.cfg.iters
    }

    fn step(&mut self, step: u64) -> anyhow::Result<StepStats> {
        let lr = self.opt.lr();
        let device = self.nerf.device();
        let n = self.data.images.len();
        let k = self.cfg.images_per_step.min(n);
        let picks = self.rng.sample_indices(k, n)?;
        let mut times = Vec::new();
        let mut parts = Vec::with_capacity(k);
        for (i, &pick) in picks.iter().enumerate() {
            let image = &self.data.images[pick];
            let count = ray_share(self.cfg.rays, k, i);
            let (w, h) = (image.view.camera.width, image.view.camera.height);
            let pixels = self.rng.sample_pixels(
                count.min((w * h) as usize),
                w,
                h,
                self.cfg.precrop_at(step),
            )?;
            times.extend(
                image
                    .time
                    .map(|t| vec![t; pixels.len()])
                    .unwrap_or_default(),
            );
            parts.push((&image.view, pixels));
        }
        let parts: Vec<(&ViewFrame, &[u32])> = parts.iter().map(|(v, p)| (*v, &p[..])).collect();
        let (rays, target) = batch_of(&parts, &device);
        let times = self.nerf.config.time.then_some(times);
        let jitter: Option<&mut dyn rand::RngCore> = if self.nerf.config.stratified {
            Some(&mut self.rng)
        } else {
            None
        };
        let out = self.nerf.render_rays(&rays, times.as_deref(), jitter)?;
        let loss = out.loss(target);
        // one read for the step: the MSEs, the loss and the gradients' squares (a non-finite
        // loss is not used to update: the guard stops the run on it)
        let grads = gradients::backward(loss.total.clone())
            .map(|g| GradientsParams::from_grads(g, &self.nerf));
        let mut parts = vec![loss.fine, loss.coarse, loss.total];
        if let Some(g) = &grads {
            parts.extend(gradients::grad_square_sums(g, &self.nerf));
        }
        let values = neurofluid_core::transfer::read_together(parts)?;
        let (fine_mse, coarse_mse, value) = (values[0], values[1], values[2]);
        let mut grad_norm = 0.0;
        if value.is_finite()
            && let Some(grads) = grads
        {
            grad_norm = gradients::norm_of(&values[3..]);
            if grad_norm.is_finite() {
                self.nerf = self.opt.step(self.nerf.clone(), grads);
            }
        }
        Ok(StepStats {
            loss: value,
            psnr: Some(psnr_from_mse(if out.fine.is_some() {
                fine_mse
            } else {
                coarse_mse
            })),
            rays: rays.len(),
            lrs: vec![("nerf", lr)],
            grad_norms: vec![("nerf", grad_norm)],
            updated: true,
            ..StepStats::default()
        })
    }

    fn evaluate(&mut self, _done: u64) -> anyhow::Result<Option<Evaluation>> {
        let Some(held) = &self.data.held_out else {
            return Ok(None);
        };
        let cam = &held.view.camera;
        let image = self.nerf.render_image(cam, held.time)?;
        let (w, h) = (cam.width as usize, cam.height as usize);
        let pred = RgbImage::new(w, h, image.best().to_vec())?;
        let truth = RgbImage::new(w, h, held.view.image.rgb.clone())?;
        Ok(Some(Evaluation {
            psnr: Some(psnr(&pred, &truth)?),
            picture: Some(side_by_side(&pred, &truth)),
            scores: Vec::new(),
        }))
    }

    fn save(&self, dir: &Path) -> anyhow::Result<StageState> {
        checkpoint::save_module(&self.nerf, &files::NERF.save_path(dir))?;
        let mut state = self.rng.to_state();
        checkpoint::save_group(
            &self.opt,
            &files::NERF_ADAM.save_path(dir),
            "nerf",
            &mut state,
        )?;
        Ok(state)
    }

    fn load(&mut self, dir: &Path, done: u64, state: StageState) -> anyhow::Result<()> {
        self.nerf = checkpoint::load_module(self.nerf.clone(), &files::NERF.load_path(dir))?;
        let adam = files::NERF_ADAM.load_path(dir);
        // every step updates
        checkpoint::load_group(&mut self.opt, &self.nerf, &adam, "nerf", &state, || done)?;
        self.rng = Rng::from_stage_state(&state, dir)?;
        Ok(())
    }
}

/// The NeRF of `kind` for `run`'s scene (the ray segment is the scene's), freshly initialised
/// from the experiment's seed (the same weights on every device).
pub fn new_nerf(run: &Run, kind: NerfKind) -> anyhow::Result<Nerf> {
    neurofluid_core::device::init_seeded(run.exp.seed, &run.device, |cpu| {
        Nerf::new(nerf_config(run, kind), cpu)
    })
    .context("building the NeRF from [nerf.model]")
}

fn nerf_config(run: &Run, kind: NerfKind) -> NerfConfig {
    let (near, far) = run.exp.scene.bounds(0.0, 0.0);
    let b = run.scene.manifest().box_interior;
    NerfConfig {
        near: near as f64,
        far: far as f64,
        time: kind == NerfKind::NerfT,
        bounds: run
            .exp
            .nerf
            .clip_to_box
            .then(|| (b.min.map(f64::from), b.max.map(f64::from))),
        ..run.exp.nerf.model.clone()
    }
}

/// Trains (or resumes, or finds finished) the NeRF of `kind` in `run` and returns it.
pub fn train(run: &Run, log: &mut MetricsLog, kind: NerfKind) -> anyhow::Result<Nerf> {
    let cfg = &run.exp.nerf;
    let data = NerfData::load(&run.scene, kind, &run.exp, cfg.preview_every > 0)?;
    tracing::info!(
        model = kind.label(),
        images = data.images.len(),
        iters = cfg.iters,
        rays = cfg.rays,
        "NeRF training"
    );
    let mut trainer = NerfTrainer::new(kind, cfg, new_nerf(run, kind)?, data, run.exp.seed);
    super::drive::drive(run, log, &mut trainer, kind.stage(), cfg.cadence(), None)?;
    Ok(trainer.into_nerf())
}
