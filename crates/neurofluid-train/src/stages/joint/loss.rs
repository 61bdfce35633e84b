//! The paper's loss of one joint step: the image loss at the predicted particles, differentiated
//! in two parts (PhysNeRF's gradients and g = ∂L/∂x_{t+1} from one render of the prediction as a
//! leaf; DLF's through the surrogate Σ x_{t+1}·g), the box's boundary penalty, and the rays the
//! image loss is taken at.

use burn::optim::GradientsParams;
use burn::prelude::*;
use burn::tensor::activation::relu;
use neurofluid_core::gradients;
use neurofluid_core::ray_focus::{mark_particles, sample_focused};
use neurofluid_core::scene::Aabb;
use neurofluid_core::tensors::{mean_all, sum_all};
use neurofluid_core::transfer::read_together;
use neurofluid_physnerf::{PhysNerf, RayBatch};

use super::data::JointData;
use crate::config::JointSection;
use crate::stages::views::{ViewFrame, batch_of, ray_share, tensor_points};
use neurofluid_core::sampler::Rng;
use neurofluid_outputs::metrics_log::psnr_from_mse;

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
pub(super) struct SplitOnDevice {
    /// MSE_fine.
    pub fine: Tensor<1>,
    /// MSE_coarse + MSE_fine.
    pub total: Tensor<1>,
    /// PhysNeRF's gradients.
    pub physnerf_grads: Option<GradientsParams>,
    /// ∂L/∂x_{t+1}, left on the device (plain: not tracked).
    pub dx: Option<Tensor<2>>,
}

/// [`split_image_loss`] without reading the losses or the particles' gradient; `host` is
/// `pred`'s values when the caller holds them (the renderer then reads nothing back for the
/// neighbour search).
pub(super) fn split_on_device(
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
    let (physnerf_grads, dx) = match gradients::backward(image_loss.total.clone()) {
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
