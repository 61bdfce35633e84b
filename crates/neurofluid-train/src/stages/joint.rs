//! Joint grounding (spec §4.2): the transition model T_θ (DLF) and the renderer R_φ (PhysNeRF)
//! trained together from the training view only.
//!
//! Frames are visited in order; at the start of every epoch the state is reset to the known
//! ground-truth state of the first training frame. Each iteration steps DLF once, renders the
//! prediction with the camera of frame t+1 at `rays` random pixels of image t+1, and minimises
//! MSE_coarse + MSE_fine + w·L1(outside the box). Two Adams, each with its own multi-step
//! schedule, update the renderer and the transition model. The carried state is detached after
//! every `bptt_steps` transitions (1 = the reference's truncated BPTT).

use anyhow::Context;
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use burn::tensor::activation::relu;
use neurofluid_core::npz::{NpzReader, NpzWriter};
use neurofluid_core::scene::{Aabb, Role};
use neurofluid_dlf::{Boundary, DlfNet};
use neurofluid_physnerf::PhysNerf;
use serde::{Deserialize, Serialize};

use super::checkpoint;
use super::context::{Run, ViewFrame, check_particles, points_tensor, scalar, tensor_points};
use super::preview;
use super::progress::StageProgress;
use super::warmup;
use crate::metrics_log::{MetricsLog, psnr_from_mse};
use crate::rng::Rng;

/// Folder of the stage inside the run folder.
pub const STAGE: &str = "joint";

/// What `state.json` of a joint checkpoint holds.
#[derive(Debug, Serialize, Deserialize)]
struct JointState {
    /// Iterations (transitions) done.
    step: u64,
    /// Pixel-sampling RNG state.
    rng: u64,
}

/// The models the joint stage trains.
#[derive(Debug, Clone)]
pub struct Grounded {
    /// The renderer R_φ.
    pub renderer: PhysNerf,
    /// The transition model T_θ.
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

/// The carried particle state (positions, velocities) on the device.
type State = (Tensor<2>, Tensor<2>);

fn save_carried(dir: &std::path::Path, state: &State) -> anyhow::Result<()> {
    let mut w = NpzWriter::new();
    w.add_points("pos", &tensor_points(&state.0));
    w.add_points("vel", &tensor_points(&state.1));
    w.write(dir.join("carried_state.npz"))?;
    Ok(())
}

fn load_carried(dir: &std::path::Path, device: &Device) -> anyhow::Result<State> {
    let mut r = NpzReader::open(dir.join("carried_state.npz"))?;
    Ok((
        points_tensor(&r.points("pos")?, device),
        points_tensor(&r.points("vel")?, device),
    ))
}

/// Runs (or resumes) the joint stage and returns the grounded models.
pub fn run(run: &Run, log: &mut MetricsLog) -> anyhow::Result<Grounded> {
    run_until(run, log, None)
}

/// Runs (or resumes) the joint stage up to iteration `stop` (all of it for `None`),
/// checkpointing there (with the carried particle state when `stop` falls inside an epoch).
pub fn run_until(run: &Run, log: &mut MetricsLog, stop: Option<u64>) -> anyhow::Result<Grounded> {
    let cfg = &run.exp.joint;
    let device = &run.device;
    let scene = &run.scene;
    let frames = scene.frames(Role::Train);
    anyhow::ensure!(
        frames.len() >= 2,
        "the training split has {} frame(s); joint training needs at least 2",
        frames.len()
    );
    let transitions = (frames.len() - 1) as u64;
    let total = cfg.epochs * transitions;
    let view = cfg
        .view
        .clone()
        .unwrap_or_else(|| scene.views(Role::Train)[0].clone());
    let targets = frames
        .clone()
        .map(|t| ViewFrame::load(scene, Role::Train, &view, t))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let gt0 = scene.particles(Role::Train, frames.start)?;
    check_particles(&gt0, "first training frame")?;
    let box_particles = scene.boundary()?;
    let interior = scene.manifest().box_interior;
    let bptt = run.exp.dlf.bptt_steps.max(1) as u64;

    let stage_dir = run.stage_dir(STAGE);
    let mut renderer = warmup::load_trained(run)?;
    let mut dlf = run.load_dlf(&run.exp.dlf.weights)?;
    let boundary: Boundary = dlf.boundary(&box_particles.points, &box_particles.normals, device);
    let mut opt_r: ModuleOptimizer = warmup::adam();
    let mut opt_t: ModuleOptimizer = warmup::adam();
    let mut rng = Rng::stream(run.exp.seed, STAGE);
    let mut start = 0;
    let initial = || -> State {
        (
            points_tensor(&gt0.pos, device),
            points_tensor(&gt0.vel, device),
        )
    };
    let mut state = initial();
    if let Some(ckpt) = checkpoint::latest(&stage_dir) {
        let s: JointState = checkpoint::load_state(&ckpt)?;
        renderer = checkpoint::load_module(renderer, &ckpt.join("renderer.bpk"))?;
        dlf = checkpoint::load_module(dlf, &ckpt.join("dlf.bpk"))?;
        opt_r = checkpoint::load_optimizer(opt_r, &ckpt.join("optim_renderer.bpk"))?;
        opt_t = checkpoint::load_optimizer(opt_t, &ckpt.join("optim_transition.bpk"))?;
        rng = Rng::from_state(s.rng);
        start = s.step;
        if start % transitions != 0 {
            state = load_carried(&ckpt, device)?;
        }
        tracing::info!(
            step = start,
            "resuming joint training from {}",
            ckpt.display()
        );
    }
    let save = |renderer: &PhysNerf,
                dlf: &DlfNet,
                opt_r: &ModuleOptimizer,
                opt_t: &ModuleOptimizer,
                rng: &Rng,
                state: &State,
                step: u64| {
        checkpoint::write(&stage_dir, |dir| {
            checkpoint::save_module(renderer, &dir.join("renderer.bpk"))?;
            checkpoint::save_module(dlf, &dir.join("dlf.bpk"))?;
            checkpoint::save_optimizer(opt_r, &dir.join("optim_renderer.bpk"))?;
            checkpoint::save_optimizer(opt_t, &dir.join("optim_transition.bpk"))?;
            save_carried(dir, state)?;
            checkpoint::save_state(
                &JointState {
                    step,
                    rng: rng.state(),
                },
                dir,
            )
        })
    };

    tracing::info!(
        view = %view,
        frames = ?frames,
        epochs = cfg.epochs,
        iterations = total,
        bptt_steps = bptt,
        "joint grounding"
    );
    let sched_r = cfg.renderer_schedule();
    let sched_t = cfg.transition_schedule();
    let end = stop.map_or(total, |s| s.min(total));
    let mut bar = StageProgress::new("joint", start, total);
    let mut pending: Option<Tensor<1>> = None;
    let mut pending_mse: f64;
    for step in start..end {
        let t = (step % transitions) as usize;
        if t == 0 {
            state = initial();
        }
        let pred = dlf.step(state.0.clone(), state.1.clone(), &boundary);
        let target = &targets[t + 1];
        let (w, h) = (target.camera.width, target.camera.height);
        let pixels = rng.sample_pixels(cfg.rays, w, h, cfg.precrop_at(step))?;
        let (rays, colours) = target.batch(&pixels, device);
        let jitter: Option<&mut dyn rand::RngCore> = if run.exp.renderer.jitter {
            Some(&mut rng)
        } else {
            None
        };
        let out = renderer.render_rays(&pred.pos, &rays, jitter)?;
        let image_loss = renderer.loss(&out, colours);
        pending_mse = scalar(&image_loss.fine);
        let loss = image_loss.total
            + boundary_penalty(pred.pos.clone(), &interior).mul_scalar(cfg.boundary_weight);
        pending = Some(match pending {
            None => loss,
            Some(p) => p + loss,
        });
        bar.add_rays(cfg.rays);
        state = (pred.pos, pred.vel);
        let done = step + 1;
        let window_end = done % bptt == 0 || (t + 1) as u64 == transitions || done == end;
        if !window_end {
            continue;
        }
        let loss = pending.take().context("no loss to optimise")?;
        let loss_value = scalar(&loss);
        anyhow::ensure!(
            loss_value.is_finite(),
            "joint loss is {loss_value} at iteration {step}"
        );
        let mut grads = loss.backward();
        let g_r = GradientsParams::from_module(&mut grads, &renderer);
        let g_t = GradientsParams::from_module(&mut grads, &dlf);
        let (lr_r, lr_t) = (sched_r.lr_at(step), sched_t.lr_at(step));
        renderer = opt_r.step(lr_r, renderer, g_r);
        dlf = opt_t.step(lr_t, dlf, g_t);
        // the carried state leaves the graph: truncated backpropagation through time
        state = (state.0.detach(), state.1.detach());
        let psnr = psnr_from_mse(pending_mse);
        bar.update(done, loss_value, psnr);
        if done % cfg.log_every.max(1) == 0 || done == total {
            let mut row = bar.row(STAGE, done, loss_value, psnr);
            row.lr_renderer = Some(lr_r);
            row.lr_transition = Some(lr_t);
            log.append(&row)?;
        }
        if cfg.eval_every > 0 && done % cfg.eval_every == 0 {
            // the training view at the frame just predicted, rendered from the prediction
            let dir = stage_dir.join("previews");
            let elapsed = bar.elapsed();
            preview::preview(
                STAGE,
                done,
                &renderer,
                target,
                &state.0,
                run.exp.renderer.chunk,
                &dir,
                elapsed,
                log,
            )?;
        }
        if cfg.ckpt_every > 0 && done % cfg.ckpt_every == 0 && done < end {
            save(&renderer, &dlf, &opt_r, &opt_t, &rng, &state, done)?;
        }
    }
    bar.finish();
    if start < end {
        save(&renderer, &dlf, &opt_r, &opt_t, &rng, &state, end)?;
    }
    Ok(Grounded { renderer, dlf })
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
    let renderer = neurofluid_physnerf::PhysNerf::new(run.renderer_config(), &run.device)?;
    let renderer = checkpoint::load_module(renderer, &ckpt.join("renderer.bpk"))?;
    let dlf = run.load_dlf(&run.exp.dlf.weights)?;
    let dlf = checkpoint::load_module(dlf, &ckpt.join("dlf.bpk"))?;
    Ok(Grounded { renderer, dlf })
}
