//! Joint grounding (spec §4.2): DLF (the transition model) and PhysNeRF (the renderer) trained
//! together from the training view only.
//!
//! Frames are visited in order; at the start of every epoch the state is reset to the known
//! ground-truth state of the first training frame. Each step moves DLF one transition, renders
//! the prediction with the camera of frame t+1 at `rays` random pixels of image t+1, and adds
//! MSE_coarse + MSE_fine + w·L1(outside the box) to the window's loss. Two Adams, each with its
//! own schedule, update PhysNeRF and DLF at the end of every window of `bptt_steps` transitions
//! (1 = the reference's truncated BPTT), after which the carried state is detached. With
//! `dlf_every` > 1, DLF steps only after every `dlf_every`-th window (and at the end of every
//! epoch), with its gradients summed over those windows, while PhysNeRF steps after each.
//!
//! The image loss is differentiated in two parts, which give the gradients of the one loss by
//! the chain rule: the render of x_{t+1} (a leaf) gives PhysNeRF's gradients and g = ∂L/∂x_{t+1}
//! at once; DLF's come from the surrogate Σ x_{t+1}·g (plus the boundary term), differentiated
//! through the transitions of the window. The split exposes g, which the diagnostics compare with
//! the true error (x_true − x_pred): [`Diagnostics`], at every evaluation, with the rollout d over
//! the training frames and the renderer's PSNR on the true particles, where the scene has them.
//!
//! With `silhouette_weight` > 0 the [`crate::silhouette`] term of every view joins the loss at
//! the same leaf: its gradient is added to g, so DLF sees it through the same surrogate.

use std::path::Path;

use anyhow::Context;
use burn::optim::{GradientsAccumulator, GradientsParams};
use burn::prelude::*;
use burn::tensor::activation::relu;
use neurofluid_core::metrics::gt_to_pred_distance;
use neurofluid_core::npz::{NpzReader, NpzWriter};
use neurofluid_core::scene::{Aabb, Particles, Role, Scene};
use neurofluid_core::square_sums;
use neurofluid_core::tensors::{mean_all, sum_all};
use neurofluid_core::transfer::read_together;
use neurofluid_dlf::{Boundary, DlfNet};
use neurofluid_physnerf::{PhysNerf, RayBatch};

use super::run_folder::Run;
use super::views::{
    ViewFrame, batch_of, check_sequence, joint_sources, load_particles, points_tensor, ray_share,
    render_beside_truth, scalar, tensor_points,
};
use super::warmup::{self, WarmupData};
use crate::config::Cadenced;
use crate::config::{AnchorAlong, ColourHead, JointSection, ReplayOf};
use crate::density_prior::DensityPrior;
use crate::energy_prior::{energy_gain, energy_gains};
use crate::focus::{image_foreground, mark_particles, sample_focused};
use crate::metrics_log::{MetricsLog, psnr_from_mse};
use crate::optim::{Group, JointDlfGroup, JointPhysNerfGroup};
use crate::rest_density::{RestDensity, SUPPORT_RADII, mean_density};
use crate::sampler::Rng;
use crate::silhouette::{projected_radius, silhouette_loss};
use crate::stage::{Stage, files};
use crate::trainer::checkpoint;
use crate::trainer::{Evaluation, StageState, StepStats, Trainer, guard};

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

/// Mean over particles and axes of the distance outside the box interior (the reference's
/// boundary L1 penalty, `mean |x − clamp(x, lo, hi)|`).
pub fn boundary_penalty(pos: Tensor<2>, interior: &Aabb) -> Tensor<1> {
    let device = pos.device();
    let lo = neurofluid_core::transfer::upload::<1, burn::tensor::Float, _>(interior.min, &device)
        .unsqueeze_dim::<2>(0);
    let hi = neurofluid_core::transfer::upload::<1, burn::tensor::Float, _>(interior.max, &device)
        .unsqueeze_dim::<2>(0);
    let below = relu(lo - pos.clone());
    let above = relu(pos - hi);
    mean_all(below + above)
}

/// `joint.truth_weight`: every training frame's true particles on the device, refused with the
/// key named where the scene has none or they are not the predicted particles (another count:
/// initial particles from images).
fn true_frames(data: &JointData, device: &Device) -> anyhow::Result<Vec<Tensor<2>>> {
    let truth = data.truth.as_ref().with_context(|| {
        "joint.truth_weight > 0 needs the scene's true particles of every training frame; \
         this scene has none"
    })?;
    anyhow::ensure!(
        truth.len() as u64 > data.transitions() && truth[0].len() == data.initial.pos.len(),
        "joint.truth_weight > 0 needs the true particles of every training frame matched to the \
         predicted ones by index: the truth has {} frames of {} particles, the joint stage {} \
         transitions from {} particles",
        truth.len(),
        truth.first().map_or(0, Vec::len),
        data.transitions(),
        data.initial.pos.len()
    );
    Ok(truth.iter().map(|p| points_tensor(p, device)).collect())
}

/// The anchor term (`joint.anchor_weight`): the mean over particles of the squared distance
/// between the grounded step's positions `pred` and the pretrained DLF's step `anchor` from the
/// same state (a constant), in particle radii². With `eye` (`joint.anchor_along = "depth"`)
/// only the part of each difference along the ray from `eye` through the particle's anchored
/// position counts.
///
/// One view cannot tell where along its rays the fluid is, nor see where it is not: the image
/// loss leaves DLF free to move mass there, and a grounded DLF does (the spray of the test bed:
/// dense fluid where the truth has none, BENCHMARKS.md "Issue 34"). The anchor keeps each step
/// near the pretrained physics wherever the images do not ask for a change: a trust region on
/// DLF's step; along the rays alone, it leaves free what the training view sees.
pub fn anchor_penalty(
    pred: Tensor<2>,
    anchor: Tensor<2>,
    radius: f32,
    eye: Option<[f32; 3]>,
) -> Tensor<1> {
    let n = pred.dims()[0].max(1) as f64;
    let r2 = f64::from(radius) * f64::from(radius);
    let diff = pred - anchor.clone();
    let squares = match eye {
        None => diff.powi_scalar(2),
        Some(eye) => {
            let device = anchor.device();
            let eye = neurofluid_core::transfer::upload::<1, burn::tensor::Float, _>(eye, &device)
                .cast(anchor.dtype())
                .unsqueeze_dim::<2>(0);
            let ray = anchor - eye;
            let length = ray
                .clone()
                .powi_scalar(2)
                .sum_dim(1)
                .sqrt()
                .clamp_min(1e-12);
            (diff * (ray / length)).sum_dim(1).powi_scalar(2)
        }
    };
    sum_all(squares).mul_scalar(1.0 / (n * r2))
}

/// What the joint stage trains on: the training view at every training frame, the true state of
/// the first training frame, and the box.
#[derive(Debug, Clone)]
pub struct JointData {
    /// The images of frames 0 … T−1 of the training split, per view: the training view first,
    /// then `joint.extra_views`.
    pub views: Vec<Vec<ViewFrame>>,
    /// The true state at the first training frame (every epoch starts from it).
    pub initial: Particles,
    /// Box particles and their normals.
    pub walls: (Vec<[f32; 3]>, Vec<[f32; 3]>),
    /// The box interior (the boundary penalty's bounds).
    pub interior: Aabb,
    /// The true positions at every training frame, when the scene has them (diagnostics only).
    pub truth: Option<Vec<Vec<[f32; 3]>>>,
    /// Where each image of `views` shows fluid (empty unless `joint.foreground_rays` or
    /// `joint.silhouette_weight` uses it).
    pub foreground: Vec<Vec<Vec<bool>>>,
    /// The particle radius (the projected footprint of a particle).
    pub radius: f32,
    /// `joint.replay_rays` > 0: the warm-up's views and particles, which PhysNeRF keeps
    /// rendering while it is grounded.
    pub replay: Option<WarmupData>,
    /// `warmup.held_out`: that view at the warm-up's frame and the frame's particles, which the
    /// evaluations render (`psnr_held_out`).
    pub held_out: Option<(ViewFrame, Vec<[f32; 3]>)>,
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
        let views = joint_sources(scene, cfg)?
            .into_iter()
            .map(|(role, v)| {
                frames
                    .clone()
                    .map(|t| ViewFrame::load(scene, role, &v, t))
                    .collect::<anyhow::Result<Vec<_>>>()
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        let initial = load_particles(scene, Role::Train, frames.start, "first training frame")?;
        let walls = scene.boundary()?;
        // only `joint.foreground_rays` and `joint.silhouette_weight` use them
        let foreground = if cfg.foreground_rays > 0.0 || cfg.silhouette_weight > 0.0 {
            views
                .iter()
                .map(|frames| frames.iter().map(|v| image_foreground(&v.image)).collect())
                .collect()
        } else {
            Vec::new()
        };
        // the diagnostics' ground truth: every training frame's particles, if the scene has them
        let truth = scene
            .particle_sequence(Role::Train)
            .ok()
            .filter(|seq| seq.len() == frames.len() && check_sequence(seq, frames.start).is_ok());
        Ok(Self {
            views,
            initial,
            walls: (walls.points, walls.normals),
            interior: scene.manifest().box_interior,
            truth: truth.map(|seq| seq.into_iter().map(|p| p.pos).collect()),
            foreground,
            radius: scene.manifest().particle_radius,
            replay: None,
            held_out: None,
        })
    }

    /// Transitions per epoch.
    pub fn transitions(&self) -> u64 {
        (self.views[0].len() - 1) as u64
    }

    /// The training view's image of training frame `t` (counted from the split's first).
    pub fn target(&self, t: usize) -> &ViewFrame {
        &self.views[0][t]
    }
}

/// The carried particle state (positions, velocities) on the device.
type State = (Tensor<2>, Tensor<2>);

/// What the joint stage measures besides its loss, at every evaluation (metrics columns
/// `rollout_d`, `rollout_d_prime`, `rollout_energy_gain`, `rollout_particle_energy_gain`,
/// `rollout_density`, `grad_alignment`, `psnr_true`, `psnr_held_out`).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Diagnostics {
    /// d (× 1000) of DLF's rollout from the first true frame over the training frames
    /// t = 1 … T−1, against the true particles: is the simulator getting closer to the truth?
    pub rollout_d: Option<f64>,
    /// d′ (× 1000) of the same rollout: from each predicted particle to the nearest true one
    /// (spray, which d does not see).
    pub rollout_d_prime: Option<f64>,
    /// The mechanical energy (J/kg) the same rollout gains over the training frames, summed over
    /// the steps that gain ([`crate::energy_prior::energy_gains`]): a fluid in a closed box gains
    /// none. Needs no true particles.
    pub rollout_energy_gain: Option<f64>,
    /// The same per particle: the sum over steps of the mean of each particle's own gain (in a
    /// viscous fluid no particle gains any; water passes energy between particles).
    pub rollout_particle_energy_gain: Option<f64>,
    /// The same rollout's mean kernel density relative to the first training state's, the mean
    /// over the training frames ([`crate::rest_density::mean_density`]): below 1, the fluid
    /// spread thinner than it started. Needs no true particles.
    pub rollout_density: Option<f64>,
    /// The mean, over the transitions since the last evaluation, of the cosine between the image
    /// loss's descent direction at the prediction, −∂L/∂x_{t+1}, and the true error
    /// x_true − x_pred (particles matched by index): does the image signal point at the truth?
    pub grad_alignment: Option<f64>,
    /// PSNR of the renderer on the *true* particles of every 7th training frame (the same
    /// pixels at every evaluation): renderer error apart from dynamics error.
    pub psnr_true: Option<f64>,
    /// With `warmup.held_out`, PSNR of the renderer on that warm-up view at the warm-up's frame,
    /// from the frame's particles: how grounding on the training view carries the renderer to a
    /// view no stage trained on. Needs no true particles past the first frame.
    pub psnr_held_out: Option<f64>,
}

impl Diagnostics {
    /// The named scores of an evaluation.
    pub fn scores(&self) -> Vec<(&'static str, f64)> {
        [
            ("rollout_d", self.rollout_d),
            ("rollout_d_prime", self.rollout_d_prime),
            ("grad_alignment", self.grad_alignment),
            ("psnr_true", self.psnr_true),
            ("psnr_held_out", self.psnr_held_out),
            ("rollout_energy_gain", self.rollout_energy_gain),
            (
                "rollout_particle_energy_gain",
                self.rollout_particle_energy_gain,
            ),
            ("rollout_density", self.rollout_density),
        ]
        .into_iter()
        .filter_map(|(k, v)| v.map(|v| (k, v)))
        .collect()
    }
}

/// The cosine `Σab / (√Σa² √Σb²)` from its three sums; `None` when either norm is zero.
pub fn cosine_of_sums([ab, aa, bb]: [f64; 3]) -> Option<f64> {
    (aa > 0.0 && bb > 0.0).then(|| ab / (aa.sqrt() * bb.sqrt()))
}

/// `[Σab, Σa², Σb²]` of two `[N, 3]` tensors on their device (`[1]` each, fixed-order sums), for a
/// cosine read back with a step's other values ([`cosine_of_sums`]).
pub fn cosine_sums(a: Tensor<2>, b: Tensor<2>) -> [Tensor<1>; 3] {
    [
        sum_all(a.clone() * b.clone()),
        sum_all(a.clone() * a),
        sum_all(b.clone() * b),
    ]
}

/// The image loss of one transition, differentiated at the predicted positions.
#[derive(Debug)]
pub struct SplitImageLoss {
    /// MSE_coarse + MSE_fine.
    pub loss: f64,
    /// PSNR of the fine render.
    pub psnr: f64,
    /// PhysNeRF's gradients (`None` when the loss depends on nothing trainable).
    pub physnerf_grads: Option<GradientsParams>,
    /// ∂L/∂x_{t+1} per particle (`None` when the render does not depend on the positions).
    pub dx: Option<Vec<[f32; 3]>>,
}

/// Renders `rays` from the positions `pred` (detached: a leaf) and differentiates the image loss
/// against `colours` once, for PhysNeRF's gradients and g = ∂L/∂x_{t+1}.
pub fn split_image_loss(
    physnerf: &PhysNerf,
    pred: &Tensor<2>,
    rays: &RayBatch,
    colours: Tensor<2>,
    jitter: Option<&mut dyn rand::RngCore>,
) -> anyhow::Result<SplitImageLoss> {
    let split = split_on_device(physnerf, pred, None, rays, colours, jitter)?;
    let [fine, total]: [f64; 2] = read_together(vec![split.fine, split.total])?
        .try_into()
        .expect("two values");
    Ok(SplitImageLoss {
        loss: total,
        psnr: psnr_from_mse(fine),
        physnerf_grads: split.physnerf_grads,
        dx: split.dx.map(|g| tensor_points(&g)),
    })
}

/// [`SplitImageLoss`] with the losses left on the device (`[1]` each), for a step that reads
/// them back together with its other values.
struct SplitOnDevice {
    fine: Tensor<1>,
    total: Tensor<1>,
    physnerf_grads: Option<GradientsParams>,
    /// ∂L/∂x_{t+1}, left on the device (plain: not tracked).
    dx: Option<Tensor<2>>,
}

/// [`split_image_loss`] without reading the losses or the particles' gradient; `host` is
/// `pred`'s values when the caller holds them (the renderer then reads nothing back for the
/// neighbour search).
fn split_on_device(
    physnerf: &PhysNerf,
    pred: &Tensor<2>,
    host: Option<&[[f32; 3]]>,
    rays: &RayBatch,
    colours: Tensor<2>,
    jitter: Option<&mut dyn rand::RngCore>,
) -> anyhow::Result<SplitOnDevice> {
    let x = pred.clone().detach().require_grad();
    let out = match host {
        Some(h) => physnerf.render_rays_with_host(&x, h, rays, jitter)?,
        None => physnerf.render_rays(&x, rays, jitter)?,
    };
    let image_loss = physnerf.loss(&out, colours);
    let (physnerf_grads, dx) = match guard::backward(image_loss.total.clone()) {
        Some(mut grads) => (
            Some(GradientsParams::from_module(&mut grads, physnerf)),
            x.grad(&grads),
        ),
        None => (None, None),
    };
    Ok(SplitOnDevice {
        fine: image_loss.fine,
        total: image_loss.total,
        physnerf_grads,
        dx,
    })
}

/// Σ x_{t+1}·g with g = ∂L/∂x_{t+1} held constant: its gradient with respect to anything
/// x_{t+1} depends on (DLF's weights, earlier states) is the image loss's, by the chain rule.
/// Zero without a g. `g` is a plain tensor (a constant in the product).
pub fn dlf_surrogate(pred: &Tensor<2>, dx: Option<Tensor<2>>) -> Tensor<1> {
    match dx {
        Some(g) => sum_all(pred.clone() * g),
        None => sum_all(pred.clone()).mul_scalar(0.0),
    }
}

/// Which parameter groups a step of the joint stage updates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Updates {
    /// PhysNeRF: at the end of every window of `bptt_steps` transitions and of every epoch.
    pub physnerf: bool,
    /// DLF: at the end of every `dlf_every`-th window and of every epoch.
    pub dlf: bool,
}

/// The groups updated after iteration `step` (0-based) of a joint stage of `total` iterations
/// over `transitions` per epoch.
pub fn updates_after(cfg: &JointSection, transitions: u64, total: u64, step: u64) -> Updates {
    let done = step + 1;
    let edge = done.is_multiple_of(transitions) || done == total;
    let window = cfg.bptt_steps.max(1) as u64;
    let window_end = edge || done.is_multiple_of(window);
    Updates {
        physnerf: window_end,
        dlf: window_end && (edge || done.is_multiple_of(window * cfg.dlf_every.max(1) as u64)),
    }
}

/// The updates (PhysNeRF's, DLF's) of the first `done` iterations: the counts of a checkpoint
/// written before the groups counted their own.
pub fn updates_before(cfg: &JointSection, transitions: u64, total: u64, done: u64) -> (u64, u64) {
    (0..done)
        .map(|step| updates_after(cfg, transitions, total, step))
        .fold((0, 0), |(p, d), u| {
            (p + u64::from(u.physnerf), d + u64::from(u.dlf))
        })
}

/// The rays and target colours of a joint step at iteration `step` predicting training frame
/// `t` (its positions `pred`, on the host): `joint.rays` shared among the views, each view's
/// drawn uniformly (the reference) or partly from where the fluid is (`joint.foreground_rays`).
pub fn training_rays(
    cfg: &JointSection,
    data: &JointData,
    rng: &mut Rng,
    step: u64,
    t: usize,
    pred: &[[f32; 3]],
    device: &Device,
) -> anyhow::Result<(RayBatch, Tensor<2>)> {
    let focused = cfg.foreground_rays > 0.0;
    let n_views = data.views.len();
    let mut parts = Vec::with_capacity(n_views);
    for (v, frames) in data.views.iter().enumerate() {
        let target = &frames[t];
        let (w, h) = (target.camera.width, target.camera.height);
        let count = ray_share(cfg.rays, n_views, v);
        let pixels = match cfg.precrop_at(step) {
            None if focused => {
                let mut mask = data.foreground[v][t].clone();
                mark_particles(&mut mask, &target.camera, pred, data.radius);
                sample_focused(rng, count, w, h, &mask, cfg.foreground_rays)?
            }
            precrop => rng.sample_pixels(count, w, h, precrop)?,
        };
        parts.push((target, pixels));
    }
    let parts: Vec<(&ViewFrame, &[u32])> = parts.iter().map(|(v, p)| (*v, &p[..])).collect();
    Ok(batch_of(&parts, device))
}

/// `dlf`'s rollout from the true state of the first training frame of `data` over its training
/// frames, without gradients (index 0: that state).
pub fn training_rollout(dlf: &DlfNet, data: &JointData) -> neurofluid_dlf::rollout::Rollout {
    let dlf = dlf.valid();
    let boundary = dlf.boundary(&data.walls.0, &data.walls.1, &dlf.device());
    let first = &data.initial;
    let steps = data.transitions() as usize;
    neurofluid_dlf::rollout::rollout(&dlf, &first.pos, &first.vel, &boundary, steps, |_| {})
}

/// PSNR of `physnerf` on the *true* particles of every [`PSNR_TRUE_EVERY`]-th training frame at
/// the training view, at `rays` pixels drawn from `seed`'s diagnostics stream (the same pixels
/// at every call): renderer error apart from dynamics error. `None` without true particles.
pub fn psnr_on_truth(
    physnerf: &PhysNerf,
    data: &JointData,
    rays: usize,
    seed: u64,
) -> anyhow::Result<Option<f64>> {
    let Some(truth) = &data.truth else {
        return Ok(None);
    };
    let physnerf = physnerf.valid();
    let device = physnerf.device();
    let mut rng = Rng::stream(seed, "joint-diagnostics");
    let (mut mse, mut frames) = (0.0, 0);
    for t in (1..truth.len()).step_by(PSNR_TRUE_EVERY) {
        let target = data.target(t);
        let (w, h) = (target.camera.width, target.camera.height);
        let pixels = rng.sample_pixels(rays, w, h, None)?;
        let (rays, colours) = target.batch(&pixels, &device);
        let out = physnerf.render_rays(&points_tensor(&truth[t], &device), &rays, None)?;
        mse += scalar(&physnerf.loss(&out, colours).fine);
        frames += 1;
    }
    Ok((frames > 0).then(|| psnr_from_mse(mse / frames as f64)))
}

/// Every this many training frames the renderer is scored on the true particles.
const PSNR_TRUE_EVERY: usize = 7;

/// DLF and PhysNeRF, their two Adams, the pixel stream and the carried state.
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
    /// DLF's surrogate loss of the window so far (several transitions with `bptt_steps` > 1).
    pending: Option<Tensor<1>>,
    /// The window's loss so far.
    pending_loss: f64,
    /// PhysNeRF's gradients of the window so far.
    physnerf_grads: GradientsAccumulator<PhysNerf>,
    /// Sum and count of the gradient alignment since the last evaluation.
    alignment: (f64, usize),
    seed: u64,
    /// The target frame of the last step (what a preview shows).
    last_target: usize,
    /// `joint.density_weight` > 0: the density prior.
    density: Option<DensityPrior>,
    /// `joint.rest_density_weight` > 0: the rest-density prior.
    rest_density: Option<RestDensity>,
    /// `joint.anchor_weight` > 0: the pretrained DLF (frozen), whose step anchors DLF's.
    anchor: Option<DlfNet>,
    /// `joint.truth_weight` > 0: every training frame's true particles on the device.
    truth: Option<Vec<Tensor<2>>>,
    /// `joint.anchor_horizon` > 0: where the horizon's rollouts start: the grounded rollout's last
    /// prediction of the latest finished epoch (before the first ends, the pretrained DLF's state
    /// at the end of the training window, rolled from the true first state; no images).
    horizon_start: Option<State>,
    /// `joint.replay_rays` > 0: the warm-up's particles on the device (uploaded once).
    replay_particles: Option<Tensor<2>>,
    /// `warmup.held_out`: the warm-up frame's particles on the device (uploaded once).
    held_out_particles: Option<Tensor<2>>,
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
        let state = initial_state(&data, &device);
        // the gate's count: a particle with fewer close neighbours renders as nothing
        let density = (cfg.density_weight > 0.0)
            .then(|| DensityPrior::new(&data.initial.pos, physnerf.config.k, cfg.density_weight))
            .transpose()?;
        let rest_density = (cfg.rest_density_weight > 0.0)
            .then(|| RestDensity::new(&data.initial.pos, data.radius, cfg.rest_density_weight))
            .transpose()?;
        let truth = (cfg.truth_weight > 0.0)
            .then(|| true_frames(&data, &device))
            .transpose()?;
        // `dlf` is the pretrained model here (a resumed run loads its own weights later)
        let anchor = (cfg.anchor_weight > 0.0).then(|| dlf.clone().no_grad());
        let horizon_start = anchor
            .as_ref()
            .filter(|_| cfg.anchor_horizon > 0)
            .map(|net| {
                let mut s = initial_state(&data, &device);
                for _ in 0..data.transitions() {
                    let next = net.step(s.0, s.1, &boundary);
                    s = (next.pos.detach(), next.vel.detach());
                }
                s
            });
        let replay_particles = data
            .replay
            .as_ref()
            .map(|r| points_tensor(&r.particles, &device));
        let held_out_particles = data
            .held_out
            .as_ref()
            .map(|(_, p)| points_tensor(p, &device));
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
            pending: None,
            pending_loss: 0.0,
            physnerf_grads: GradientsAccumulator::new(),
            alignment: (0.0, 0),
            seed,
            last_target: 1,
            density,
            rest_density,
            anchor,
            truth,
            horizon_start,
            replay_particles,
            held_out_particles,
        })
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
        STAGE.folder()
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
        // the prediction on the host, read once: the rays, the renderer's neighbour search, the
        // silhouette, the alignment and the state check all use it
        let pred_host = tensor_points(&pred.pos);
        self.last_target = t + 1;
        let (rays, colours) = training_rays(
            &self.cfg,
            &self.data,
            &mut self.rng,
            step,
            t + 1,
            &pred_host,
            &device,
        )?;
        let jitter = super::warmup::jitter(&self.physnerf, &mut self.rng);
        let split = split_on_device(
            &self.physnerf,
            &pred.pos,
            Some(&pred_host),
            &rays,
            colours,
            jitter,
        )?;
        let boundary = boundary_penalty(pred.pos.clone(), &self.data.interior)
            .mul_scalar(self.cfg.boundary_weight);
        if let Some(g) = split.physnerf_grads {
            self.physnerf_grads.accumulate(&self.physnerf, g);
        }
        // the terms besides the image's and the boundary's (read back with them, at once)
        let mut extra = boundary.clone().mul_scalar(0.0);
        if self.data.replay.is_some() {
            let (loss, grads) = self.replay_step(step)?;
            extra = extra + loss;
            if let Some(g) = grads {
                self.physnerf_grads.accumulate(&self.physnerf, g);
            }
        }
        let mut dx = split.dx;
        let mut silhouette = None;
        if self.cfg.silhouette_weight > 0.0 {
            let (loss, g) = self.silhouette_at(t + 1, &pred_host);
            silhouette = Some(loss);
            let g = points_tensor(&g, &device);
            dx = Some(match dx {
                Some(d) => d + g,
                None => g,
            });
        }
        let mut surrogate = dlf_surrogate(&pred.pos, dx.clone()) + boundary.clone();
        if let Some(anchor) = &self.anchor {
            let (x, v) = (self.state.0.clone().detach(), self.state.1.clone().detach());
            let target = anchor.step(x, v, &self.boundary).pos.detach();
            // the training view's camera at the predicted frame
            let eye = (self.cfg.anchor_along == AnchorAlong::Depth)
                .then(|| self.data.views[0][t + 1].camera.origin());
            let term = anchor_penalty(pred.pos.clone(), target, self.data.radius, eye)
                .mul_scalar(self.cfg.anchor_weight);
            extra = extra + term.clone().detach();
            surrogate = surrogate + term;
        }
        let Updates {
            physnerf: window_end,
            dlf: dlf_end,
        } = updates_after(&self.cfg, transitions, self.total_steps(), step);
        if self.horizon_start.is_some() && (t + 1) as u64 == transitions {
            self.horizon_start = Some((pred.pos.clone().detach(), pred.vel.clone().detach()));
        }
        if let (Some(anchor), Some((x, v))) = (&self.anchor, &self.horizon_start)
            && window_end
            && dlf_end
        {
            let term = self.horizon_penalty(anchor, x, v);
            extra = extra + term.clone().detach();
            surrogate = surrogate + term;
        }
        if let Some(prior) = &self.density
            && let (Some(term), _) = prior.loss(&pred.pos, &pred_host)
        {
            extra = extra + term.clone().detach();
            surrogate = surrogate + term;
        }
        if let Some(prior) = &self.rest_density
            && let (Some(term), _) = prior.loss(&pred.pos, &pred_host)
        {
            extra = extra + term.clone().detach();
            surrogate = surrogate + term;
        }
        if let Some(truth) = &self.truth {
            let term = anchor_penalty(
                pred.pos.clone(),
                truth[t + 1].clone(),
                self.data.radius,
                None,
            )
            .mul_scalar(self.cfg.truth_weight);
            extra = extra + term.clone().detach();
            surrogate = surrogate + term;
        }
        if self.cfg.energy_weight > 0.0 {
            let after = (pred.pos.clone(), pred.vel.clone());
            let term = energy_gain(
                self.state.clone(),
                after,
                self.dlf.config.gravity,
                self.data.radius,
                self.cfg.energy_per,
            )
            .mul_scalar(self.cfg.energy_weight);
            extra = extra + term.clone().detach();
            surrogate = surrogate + term;
        }
        let alignment = dx.and_then(|g| self.alignment_sums(t + 1, &pred_host, g));
        self.pending = Some(match self.pending.take() {
            None => surrogate,
            Some(p) => p + surrogate,
        });
        self.state = (pred.pos, pred.vel);
        self.state_host = Some(pred_host);
        // at the end of a window the gradients too, so that the step reads its values back once
        // (a non-finite loss is not used to update: the guard stops the run on it)
        let mut g_physnerf = None;
        let mut g_dlf = None;
        let mut parts = vec![split.fine, split.total, boundary, extra];
        let (mut n_physnerf, mut n_dlf) = (0, 0);
        if window_end {
            let g = self.physnerf_grads.grads();
            let sums = guard::grad_square_sums(&g, &self.physnerf);
            n_physnerf = square_sums::count(&sums);
            parts.extend(sums);
            g_physnerf = Some(g);
            if dlf_end {
                let surrogate = self.pending.take().context("no loss to optimise")?;
                let g = match guard::backward(surrogate) {
                    Some(mut grads) => GradientsParams::from_module(&mut grads, &self.dlf),
                    None => GradientsParams::new(),
                };
                let sums = guard::grad_square_sums(&g, &self.dlf);
                n_dlf = square_sums::count(&sums);
                parts.extend(sums);
                g_dlf = Some(g);
            }
        }
        let n_alignment = alignment.as_ref().map_or(0, |a| a.len());
        parts.extend(alignment.into_iter().flatten());
        let mut values = read_together(parts)?;
        // the alignment's sums are the read's last values
        let sums = values.split_off(values.len() - n_alignment);
        if let Ok(sums) = <[f64; 3]>::try_from(sums)
            && let Some(c) = cosine_of_sums(sums)
        {
            self.alignment.0 += c;
            self.alignment.1 += 1;
        }
        let (fine, image, boundary, extra) = (values[0], values[1], values[2], values[3]);
        self.pending_loss += image + boundary + extra;
        if let Some(loss) = silhouette {
            self.pending_loss += loss;
        }
        let mut stats = StepStats {
            psnr: Some(psnr_from_mse(fine)),
            rays: self.cfg.rays,
            loss: self.pending_loss,
            ..StepStats::default()
        };
        let Some(g_physnerf) = g_physnerf else {
            return Ok(stats);
        };
        self.pending_loss = 0.0;
        if !stats.loss.is_finite() {
            return Ok(stats);
        }
        let (lr_p, lr_d) = (self.opt_physnerf.lr(), self.opt_dlf.lr());
        let norm_p = guard::norm_of(&values[4..4 + n_physnerf]);
        let norm_d = g_dlf
            .as_ref()
            .map(|_| guard::norm_of(&values[4 + n_physnerf..4 + n_physnerf + n_dlf]));
        if norm_p.is_finite() && norm_d.is_none_or(f64::is_finite) {
            let g_physnerf = match self.cfg.colour_head {
                ColourHead::Trained => g_physnerf,
                ColourHead::Frozen => without_colour_heads(g_physnerf, &self.physnerf),
            };
            self.physnerf = self.opt_physnerf.step(self.physnerf.clone(), g_physnerf);
            if let Some(g) = g_dlf {
                self.dlf = self.opt_dlf.step(self.dlf.clone(), g);
            }
        }
        // the carried state leaves the graph: truncated backpropagation through time (DLF's
        // pending surrogate keeps the graphs of its transitions until its own step)
        self.state = (self.state.0.clone().detach(), self.state.1.clone().detach());
        // a point to log, evaluate and checkpoint at: nothing pending in either group (between
        // DLF's steps, PhysNeRF's norm is still checked for divergence)
        stats.grad_norms = vec![("physnerf", norm_p)];
        if let Some(norm_d) = norm_d {
            stats.grad_norms.push(("dlf", norm_d));
            stats.lrs = vec![("physnerf", lr_p), ("dlf", lr_d)];
            stats.updated = true;
        }
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
        let mut w = NpzWriter::new();
        w.add_points("pos", &tensor_points(&self.state.0));
        w.add_points("vel", &tensor_points(&self.state.1));
        if let Some((x, v)) = &self.horizon_start {
            w.add_points("horizon_pos", &tensor_points(x));
            w.add_points("horizon_vel", &tensor_points(v));
        }
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
        self.rng = Rng::from_stage_state(&state, dir)?;
        let mid_epoch = !done.is_multiple_of(self.data.transitions());
        let horizon = self.horizon_start.is_some() && done > 0;
        if mid_epoch || horizon {
            let mut r = NpzReader::open(dir.join("carried_state.npz"))?;
            let mut pair = |pos: &str, vel: &str| -> anyhow::Result<State> {
                Ok((
                    points_tensor(&r.points(pos)?, &device),
                    points_tensor(&r.points(vel)?, &device),
                ))
            };
            if mid_epoch {
                self.state = pair("pos", "vel")?;
                self.state_host = None;
            }
            if horizon {
                self.horizon_start = Some(pair("horizon_pos", "horizon_vel")?);
            }
        }
        Ok(())
    }
}

impl JointTrainer {
    /// `joint.anchor_horizon`: the grounded DLF rolled on from `(pos, vel)` past the training
    /// window, each step's anchor term (in full: no camera there) and boundary term, the state
    /// detached between steps.
    fn horizon_penalty(&self, anchor: &DlfNet, pos: &Tensor<2>, vel: &Tensor<2>) -> Tensor<1> {
        let (mut x, mut v) = (pos.clone().detach(), vel.clone().detach());
        let mut total = Tensor::<1>::zeros([1], (&x.device(), x.dtype()));
        for _ in 0..self.cfg.anchor_horizon {
            let next = self.dlf.step(x.clone(), v.clone(), &self.boundary);
            let target = anchor.step(x, v, &self.boundary).pos.detach();
            let held = anchor_penalty(next.pos.clone(), target, self.data.radius, None)
                .mul_scalar(self.cfg.anchor_weight);
            let inside = boundary_penalty(next.pos.clone(), &self.data.interior)
                .mul_scalar(self.cfg.boundary_weight);
            total = total + held + inside;
            (x, v) = (next.pos.detach(), next.vel.detach());
        }
        total
    }

    /// The replayed warm-up loss of iteration `step` ([`replay_loss`]; detached, to be read
    /// with the step's other values) and PhysNeRF's gradients of it.
    fn replay_step(&mut self, step: u64) -> anyhow::Result<(Tensor<1>, Option<GradientsParams>)> {
        let replay = self.data.replay.as_ref().context("no warm-up to replay")?;
        let particles = self
            .replay_particles
            .as_ref()
            .context("no warm-up particles to replay")?;
        let loss = replay_loss(
            &self.physnerf,
            replay,
            particles,
            self.cfg.replay_rays,
            &mut self.rng,
            step,
        )?;
        let value = loss.clone().detach();
        let grads = guard::backward(loss).map(|g| GradientsParams::from_grads(g, &self.physnerf));
        Ok((value, grads))
    }

    /// The weighted silhouette term of training frame `t` over every view, and its gradient
    /// with respect to the predicted positions `pred`.
    fn silhouette_at(&self, t: usize, points: &[[f32; 3]]) -> (f64, Vec<[f32; 3]>) {
        let weight = self.cfg.silhouette_weight;
        let mut loss = 0.0;
        let mut grad = vec![[0.0f32; 3]; points.len()];
        let centre = self.data.interior.centre();
        for (v, frames) in self.data.views.iter().enumerate() {
            let camera = &frames[t].camera;
            let Some(radius) = projected_radius(camera, centre, self.data.radius) else {
                continue;
            };
            let s = silhouette_loss(
                camera,
                &self.data.foreground[v][t],
                points,
                radius,
                self.cfg.silhouette_cover,
            );
            loss += weight * s.loss;
            for (g, d) in grad.iter_mut().zip(&s.grad) {
                for k in 0..3 {
                    g[k] += (weight * d[k] as f64) as f32;
                }
            }
        }
        (loss, grad)
    }

    /// The sums of the cosine between −`dx` and the true error at training frame `t`, on the
    /// device (read with the step's values: ∂L/∂x stays there), where the truth is known and has
    /// the prediction's particles (matched by index).
    fn alignment_sums(
        &self,
        t: usize,
        predicted: &[[f32; 3]],
        dx: Tensor<2>,
    ) -> Option<[Tensor<1>; 3]> {
        let truth = &self.data.truth.as_ref()?[t];
        if truth.len() != predicted.len() {
            return None;
        }
        let error: Vec<[f32; 3]> = truth
            .iter()
            .zip(predicted)
            .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
            .collect();
        let error = points_tensor(&error, &dx.device());
        Some(cosine_sums(dx.neg(), error))
    }

    /// The [`Diagnostics`] now (the gradient alignment since the last call).
    pub fn diagnostics(&mut self) -> anyhow::Result<Diagnostics> {
        let (sum, n) = std::mem::take(&mut self.alignment);
        let mut d = Diagnostics {
            grad_alignment: (n > 0).then(|| sum / n as f64),
            ..Diagnostics::default()
        };
        let rollout = training_rollout(&self.dlf, &self.data);
        let steps = self.data.transitions() as usize;
        let config = &self.dlf.config;
        let gains = energy_gains(&rollout.pos, config.dt, config.gravity);
        d.rollout_energy_gain = Some(gains.fluid.iter().sum());
        d.rollout_particle_energy_gain = Some(gains.particle.iter().sum());
        let support = SUPPORT_RADII * self.data.radius;
        let rest = mean_density(&self.data.initial.pos, support);
        d.rollout_density = (rest > 0.0).then(|| {
            (1..=steps)
                .map(|t| mean_density(&rollout.pos[t], support) / rest)
                .sum::<f64>()
                / steps.max(1) as f64
        });
        if let (Some((view, _)), Some(particles)) = (&self.data.held_out, &self.held_out_particles)
        {
            d.psnr_held_out = render_beside_truth(&self.physnerf, view, particles)?.psnr;
        }
        let Some(truth) = &self.data.truth else {
            return Ok(d);
        };
        let mean_over =
            |f: &dyn Fn(usize) -> f64| (1..=steps).map(f).sum::<f64>() / steps.max(1) as f64;
        d.rollout_d = Some(mean_over(&|t| {
            gt_to_pred_distance(&truth[t], &rollout.pos[t]).mean
        }));
        d.rollout_d_prime = Some(mean_over(&|t| {
            gt_to_pred_distance(&rollout.pos[t], &truth[t]).mean
        }));
        // the renderer on the true particles, at the same pixels every time
        d.psnr_true = psnr_on_truth(&self.physnerf, &self.data, self.cfg.rays, self.seed)?;
        Ok(d)
    }
}

/// `grads` without the gradients of both networks' colour heads (`dir_encoding`, `rgb`), which
/// the step then leaves as they are (`joint.colour_head = "frozen"`).
fn without_colour_heads(mut grads: GradientsParams, physnerf: &PhysNerf) -> GradientsParams {
    for net in [&physnerf.coarse, &physnerf.fine] {
        for layer in [&net.dir_encoding, &net.rgb] {
            let _ = grads.remove::<2>(layer.weight.id);
            if let Some(bias) = &layer.bias {
                let _ = grads.remove::<1>(bias.id);
            }
        }
    }
    grads
}

/// The replayed loss of iteration `step`: `rays` pixels of one of `replay`'s views in turn,
/// rendered by `physnerf` from `replay`'s particles (`particles`, on the device), against the
/// view's image: the warm-up's images (`joint.replay_of = "images"`) or the warm-up renderer's
/// own renders from all round ([`super::orbit`]).
pub(super) fn replay_loss(
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

/// With `warmup.held_out`, that view at the warm-up's frame and the frame's particles (what
/// `psnr_held_out` renders).
pub(super) fn held_out_view(run: &Run) -> anyhow::Result<Option<(ViewFrame, Vec<[f32; 3]>)>> {
    let Some(view) = &run.exp.warmup.held_out else {
        return Ok(None);
    };
    let t0 = run.scene.frames(Role::Warmup).start;
    let frame = ViewFrame::load(&run.scene, Role::Warmup, view, t0)?;
    Ok(Some((frame, warmup::warmup_particles(run)?)))
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
    if cfg.replay_rays > 0 {
        let warmup = warmup::warmup_data(run)?;
        data.replay = Some(match cfg.replay_of {
            ReplayOf::Images => warmup,
            ReplayOf::Renders => {
                let up = run.scene.up_axis().index();
                super::orbit::orbit_replay(&physnerf, &warmup, up)
                    .context("the warm-up renderer's orbit (joint.replay_of = \"renders\")")?
            }
        });
    }
    data.held_out = held_out_view(run)?;
    let dlf = run.load_dlf(&run.exp.dlf.weights)?;
    let mut trainer = JointTrainer::new(cfg, physnerf, dlf, data, run.exp.seed)?;
    super::drive::drive(run, log, &mut trainer, STAGE, cfg.cadence(), stop)?;
    Ok(trainer.into_models())
}

/// The models of a finished joint stage (its last checkpoint).
pub fn load_trained(run: &Run) -> anyhow::Result<Grounded> {
    let ckpt = run.latest_checkpoint(STAGE)?;
    let physnerf = PhysNerf::new(run.physnerf_config(), &run.device)?;
    let physnerf = checkpoint::load_module(physnerf, &files::PHYSNERF.load_path(&ckpt))?;
    let dlf = run.load_dlf(&run.exp.dlf.weights)?;
    let dlf = checkpoint::load_module(dlf, &files::DLF.load_path(&ckpt))?;
    Ok(Grounded { physnerf, dlf })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn value(t: Tensor<1>) -> f64 {
        f64::from(t.into_scalar::<f32>())
    }

    fn rows(v: &[[f32; 3]]) -> Tensor<2> {
        let device = neurofluid_core::device::cpu().autodiff();
        let flat: Vec<f32> = v.iter().flatten().copied().collect();
        Tensor::<2>::from_data(TensorData::new(flat, [v.len(), 3]), &device)
    }

    #[test]
    fn the_depth_anchor_counts_only_the_move_along_the_ray() {
        // two particles 2 and 3 units in front of an eye at the origin looking down −z; radius 0.5
        let anchor = [[0.0, 0.0, -2.0], [0.0, 0.0, -3.0]];
        let eye = Some([0.0, 0.0, 0.0]);
        // across the ray: free; all of it counts without the eye
        let across = [[0.5, 0.0, -2.0], [0.0, -0.5, -3.0]];
        let free = value(anchor_penalty(rows(&across), rows(&anchor), 0.5, eye));
        assert!(free.abs() < 1e-12, "{free}");
        let all = value(anchor_penalty(rows(&across), rows(&anchor), 0.5, None));
        assert!((all - 1.0).abs() < 1e-6, "{all}");
        // along the ray by one radius for one particle of two: mean 0.5 radii²
        let along = [[0.0, 0.0, -2.5], [0.0, 0.0, -3.0]];
        let p = value(anchor_penalty(rows(&along), rows(&anchor), 0.5, eye));
        assert!((p - 0.5).abs() < 1e-6, "{p}");
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

    #[test]
    fn the_depth_anchors_gradient_points_along_the_ray() {
        let eye = [1.0f32, 2.0, 3.0];
        let anchor = [[2.0f32, 4.0, 5.0]];
        let pred = rows(&[[2.3, 3.9, 5.4]]).require_grad();
        let loss = anchor_penalty(pred.clone(), rows(&anchor), 0.1, Some(eye));
        let g: Vec<f32> = pred
            .grad(&loss.backward())
            .unwrap()
            .into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .unwrap();
        // the ray's unit direction (1, 2, 2)/3: the gradient is parallel to it
        let u = [1.0f32 / 3.0, 2.0 / 3.0, 2.0 / 3.0];
        let along: f32 = g.iter().zip(u).map(|(a, b)| a * b).sum();
        let off: f32 = g.iter().zip(u).map(|(a, b)| (a - along * b).powi(2)).sum();
        assert!(
            along.abs() > 1.0 && off.sqrt() < 1e-4 * along.abs(),
            "{g:?}"
        );
    }
}
