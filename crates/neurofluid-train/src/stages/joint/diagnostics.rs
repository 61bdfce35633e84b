//! What the joint stage measures besides its loss, at every evaluation: DLF's rollout over the
//! training frames against the truth, the energy it gains, its density, whether the image
//! signal points at the truth, and the renderer on the true particles and a held-out view.

use burn::prelude::*;
use neurofluid_core::metrics::{SUPPORT_RADII, energy_gains, gt_to_pred_distance, mean_density};
use neurofluid_core::scene::Role;
use neurofluid_core::tensors::sum_all;
use neurofluid_physnerf::PhysNerf;

use super::JointTrainer;
use super::data::{JointData, training_rollout};
use crate::stages::run_folder::Run;
use crate::stages::views::{ViewFrame, points_tensor, render_beside_truth, scalar};
use crate::stages::warmup;
use neurofluid_core::sampler::Rng;
use neurofluid_outputs::metrics_log::psnr_from_mse;

/// What the joint stage measures besides its loss, at every evaluation (metrics columns
/// `rollout_d`, `rollout_d_prime`, `rollout_energy_gain`, `rollout_particle_energy_gain`,
/// `rollout_density`, `rollout_psnr`, `grad_alignment`, `psnr_true`, `psnr_held_out`).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Diagnostics {
    /// d (× 1000) of DLF's rollout from the first true frame over the training frames
    /// t = 1 … T−1, against the true particles: is the simulator getting closer to the truth?
    pub rollout_d: Option<f64>,
    /// d′ (× 1000) of the same rollout: from each predicted particle to the nearest true one
    /// (spray, which d does not see).
    pub rollout_d_prime: Option<f64>,
    /// The mechanical energy (J/kg) the same rollout gains over the training frames, summed over
    /// the steps that gain ([`neurofluid_core::metrics::energy_gains`]): a fluid in a closed box gains
    /// none. Needs no true particles.
    pub rollout_energy_gain: Option<f64>,
    /// The same per particle: the sum over steps of the mean of each particle's own gain (in a
    /// viscous fluid no particle gains any; water passes energy between particles).
    pub rollout_particle_energy_gain: Option<f64>,
    /// The same rollout's mean kernel density relative to the first training state's, the mean
    /// over the training frames ([`neurofluid_core::metrics::mean_density`]): below 1, the fluid
    /// spread thinner than it started. Needs no true particles.
    pub rollout_density: Option<f64>,
    /// PSNR of the renderer on the same rollout's particles at `psnr_true`'s frames and pixels:
    /// with `psnr_true` beside it, how much of the image error is the dynamics' (the two equal
    /// when the rollout is the truth; above `psnr_true`, the renderer prefers the rollout to the
    /// truth).
    pub rollout_psnr: Option<f64>,
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
            ("rollout_psnr", self.rollout_psnr),
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

/// Every this many training frames the renderer is scored on the true particles.
const PSNR_TRUE_EVERY: usize = 7;

/// PSNR of `physnerf` on the *true* particles of every [`PSNR_TRUE_EVERY`]-th training frame at
/// the training view, at `rays` pixels drawn from `seed`'s diagnostics stream (the same pixels
/// at every call): renderer error apart from dynamics error. `None` without true particles.
pub fn psnr_on_truth(
    physnerf: &PhysNerf,
    data: &JointData,
    rays: usize,
    seed: u64,
) -> anyhow::Result<Option<f64>> {
    match &data.truth {
        Some(truth) => psnr_on_frames(physnerf, data, truth, rays, seed),
        None => Ok(None),
    }
}

/// PSNR of `physnerf` on `particles[t]` (per training frame, from the first) at the frames and
/// pixels of [`psnr_on_truth`]. `None` with fewer than two frames.
pub fn psnr_on_frames(
    physnerf: &PhysNerf,
    data: &JointData,
    particles: &[Vec<[f32; 3]>],
    rays: usize,
    seed: u64,
) -> anyhow::Result<Option<f64>> {
    let last = particles.len().min(data.transitions() as usize + 1);
    let frames: Vec<usize> = (1..last).step_by(PSNR_TRUE_EVERY).collect();
    if frames.is_empty() {
        return Ok(None);
    }
    let (_, fine) = image_mse(
        physnerf,
        &data.views[0],
        particles,
        &frames,
        rays,
        seed,
        "joint-diagnostics",
    )?;
    Ok(Some(psnr_from_mse(fine)))
}

/// The mean coarse + fine and fine MSE of `physnerf` rendering `view` (one view's images at every
/// training frame) from `particles[t]` at each training frame t of `frames`, at `rays` pixels a
/// frame drawn in order from `seed`'s `stream` (the same pixels at every call).
pub(super) fn image_mse(
    physnerf: &PhysNerf,
    view: &[ViewFrame],
    particles: &[Vec<[f32; 3]>],
    frames: &[usize],
    rays: usize,
    seed: u64,
    stream: &str,
) -> anyhow::Result<(f64, f64)> {
    let physnerf = physnerf.valid();
    let device = physnerf.device();
    let mut rng = Rng::stream(seed, stream);
    let (mut total, mut fine) = (0.0, 0.0);
    for &t in frames {
        let target = &view[t];
        let (w, h) = (target.camera.width, target.camera.height);
        let pixels = rng.sample_pixels(rays, w, h, None)?;
        let (rays, colours) = target.batch(&pixels, &device);
        let out = physnerf.render_rays(&points_tensor(&particles[t], &device), &rays, None)?;
        let loss = physnerf.loss(&out, colours);
        total += scalar(&loss.total);
        fine += scalar(&loss.fine);
    }
    let n = frames.len().max(1) as f64;
    Ok((total / n, fine / n))
}

/// With `warmup.held_out`, that view at the warm-up's frame and the frame's particles (what
/// `psnr_held_out` renders).
pub fn held_out_view(run: &Run) -> anyhow::Result<Option<(ViewFrame, Vec<[f32; 3]>)>> {
    let Some(view) = &run.exp.warmup.held_out else {
        return Ok(None);
    };
    let t0 = run.scene.frames(Role::Warmup).start;
    let frame = ViewFrame::load(&run.scene, Role::Warmup, view, t0)?;
    Ok(Some((frame, warmup::warmup_particles(run)?)))
}

impl JointTrainer {
    /// The sums of the cosine between −`dx` and the true error at training frame `t`, on the
    /// device (read with the step's values: ∂L/∂x stays there), where the truth is known and has
    /// the prediction's particles (matched by index).
    pub(super) fn alignment_sums(
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
        // the rollout as DLF steps now: with the physical scalars fitted so far, if any
        let dlf = self.stepping_dlf();
        let rollout = training_rollout(&dlf, &self.data);
        let steps = self.data.transitions() as usize;
        let config = &dlf.config;
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
        d.rollout_psnr = psnr_on_frames(
            &self.physnerf,
            &self.data,
            &rollout.pos,
            self.cfg.rays,
            self.seed,
        )?;
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
