//! Warm-up (spec §4.1): PhysNeRF alone on the first frame, seen from the warm-up views. Every
//! iteration draws `rays` pixels per view (from the central window during the precrop
//! iterations), sums the views' coarse + fine MSE and takes one Adam step with the learning rate
//! lr0·0.1^(s/decay_steps).

use anyhow::Context;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use neurofluid_core::scene::Role;
use neurofluid_physnerf::PhysNerf;
use serde::{Deserialize, Serialize};

use super::checkpoint;
use super::context::{Run, ViewFrame, check_particles, points_tensor, scalar};
use super::preview;
use super::progress::StageProgress;
use crate::metrics_log::{MetricsLog, psnr_from_mse};
use crate::rng::Rng;

/// Folder of the stage inside the run folder.
pub const STAGE: &str = "warmup";

/// What `state.json` of a warm-up checkpoint holds.
#[derive(Debug, Serialize, Deserialize)]
struct WarmupState {
    /// Iterations done.
    step: u64,
    /// Pixel-sampling RNG state.
    rng: u64,
}

/// Adam as the reference configures it (PyTorch's epsilon 1e-8).
pub fn adam() -> ModuleOptimizer {
    AdamConfig::new().with_epsilon(1e-8).init()
}

/// Runs (or resumes) the warm-up and returns the trained renderer.
pub fn run(run: &Run, log: &mut MetricsLog) -> anyhow::Result<PhysNerf> {
    run_until(run, log, None)
}

/// Runs (or resumes) the warm-up up to iteration `stop` (all of it for `None`), checkpointing
/// there, so a long warm-up can run in pieces.
pub fn run_until(run: &Run, log: &mut MetricsLog, stop: Option<u64>) -> anyhow::Result<PhysNerf> {
    let cfg = &run.exp.warmup;
    let device = &run.device;
    let scene = &run.scene;
    let t0 = scene.frames(Role::Warmup).start;
    let views: Vec<String> = cfg
        .views
        .clone()
        .unwrap_or_else(|| scene.views(Role::Warmup).to_vec());
    let frames = views
        .iter()
        .map(|v| ViewFrame::load(scene, Role::Warmup, v, t0))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let gt = scene.particles(Role::Warmup, t0)?;
    check_particles(&gt, "warm-up particles")?;
    let particles = points_tensor(&gt.pos, device);
    // the held-out view of the same frame, for the periodic previews
    let test_view = scene.views(Role::Test).first().cloned();
    let held_out = match &test_view {
        Some(v) if cfg.eval_every > 0 => Some(ViewFrame::load(scene, Role::Test, v, t0)?),
        _ => None,
    };

    let stage_dir = run.stage_dir(STAGE);
    // the renderer's initial weights follow the experiment's seed
    device.seed(run.exp.seed);
    let mut model = PhysNerf::new(run.renderer_config(), device)
        .context("building the renderer from [renderer]")?;
    let mut opt = adam();
    let mut rng = Rng::stream(run.exp.seed, STAGE);
    let mut start = 0;
    if let Some(ckpt) = checkpoint::latest(&stage_dir) {
        let state: WarmupState = checkpoint::load_state(&ckpt)?;
        model = checkpoint::load_module(model, &ckpt.join("renderer.bpk"))?;
        opt = checkpoint::load_optimizer(opt, &ckpt.join("optim.bpk"))?;
        rng = Rng::from_state(state.rng);
        start = state.step;
        tracing::info!(step = start, "resuming the warm-up from {}", ckpt.display());
    }
    let save = |model: &PhysNerf, opt: &ModuleOptimizer, rng: &Rng, step: u64| {
        checkpoint::write(&stage_dir, |dir| {
            checkpoint::save_module(model, &dir.join("renderer.bpk"))?;
            checkpoint::save_optimizer(opt, &dir.join("optim.bpk"))?;
            checkpoint::save_state(
                &WarmupState {
                    step,
                    rng: rng.state(),
                },
                dir,
            )
        })
    };

    tracing::info!(
        views = ?views,
        frame = t0,
        iters = cfg.iters,
        rays = cfg.rays,
        particles = gt.pos.len(),
        "warm-up"
    );
    let schedule = cfg.lr_schedule();
    let end = stop.map_or(cfg.iters, |s| s.min(cfg.iters));
    let mut bar = StageProgress::new("warm-up", start, cfg.iters);
    for step in start..end {
        let lr = schedule.lr_at(step);
        let mut total: Option<Tensor<1>> = None;
        let mut fine_mse = 0.0;
        for view in &frames {
            let (w, h) = (view.camera.width, view.camera.height);
            let pixels = rng.sample_pixels(cfg.rays, w, h, cfg.precrop_at(step))?;
            let (rays, target) = view.batch(&pixels, device);
            let jitter: Option<&mut dyn rand::RngCore> = if run.exp.renderer.jitter {
                Some(&mut rng)
            } else {
                None
            };
            let out = model.render_rays(&particles, &rays, jitter)?;
            let loss = model.loss(&out, target);
            fine_mse += scalar(&loss.fine) / frames.len() as f64;
            total = Some(match total {
                None => loss.total,
                Some(t) => t + loss.total,
            });
            bar.add_rays(cfg.rays);
        }
        let total = total.context("the warm-up has no views")?;
        let loss_value = scalar(&total);
        anyhow::ensure!(
            loss_value.is_finite(),
            "warm-up loss is {loss_value} at step {step}"
        );
        let grads = GradientsParams::from_grads(total.backward(), &model);
        model = opt.step(lr, model, grads);
        let done = step + 1;
        let psnr = psnr_from_mse(fine_mse);
        bar.update(done, loss_value, psnr);
        if done % cfg.log_every.max(1) == 0 || done == cfg.iters {
            let mut row = bar.row(STAGE, done, loss_value, psnr);
            row.lr_renderer = Some(lr);
            log.append(&row)?;
        }
        if let Some(view) = &held_out
            && done % cfg.eval_every == 0
        {
            let dir = stage_dir.join("previews");
            let elapsed = bar.elapsed();
            preview::preview(
                STAGE,
                done,
                &model,
                view,
                &particles,
                run.exp.renderer.chunk,
                &dir,
                elapsed,
                log,
            )?;
        }
        if cfg.ckpt_every > 0 && done % cfg.ckpt_every == 0 && done < end {
            save(&model, &opt, &rng, done)?;
        }
    }
    bar.finish();
    if start < end {
        save(&model, &opt, &rng, end)?;
    }
    Ok(model)
}

/// The renderer of a finished warm-up (its last checkpoint).
pub fn load_trained(run: &Run) -> anyhow::Result<PhysNerf> {
    let stage_dir = run.stage_dir(STAGE);
    let ckpt = checkpoint::latest(&stage_dir).with_context(|| {
        format!(
            "no warm-up checkpoint in {}: run the `warmup` stage first",
            stage_dir.display()
        )
    })?;
    let model = PhysNerf::new(run.renderer_config(), &run.device)?;
    checkpoint::load_module(model, &ckpt.join("renderer.bpk"))
}
