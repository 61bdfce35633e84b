//! Scene data as the stages use it: a view's camera and image, rays and target colours,
//! checked particle states, and the held-out render every stage previews with.

use anyhow::Context;
use burn::module::Module;
use burn::prelude::*;
use neurofluid_core::camera::Camera;
use neurofluid_core::metrics::{RgbImage, psnr};
use neurofluid_core::scene::{Image, Particles, Role, Scene};
use neurofluid_outputs::pictures::side_by_side;
use neurofluid_physnerf::{PhysNerf, RayBatch, render_image};

use crate::config::JointSection;
use crate::trainer::Evaluation;

/// One view of one frame: camera and target image.
#[derive(Debug, Clone)]
pub struct ViewFrame {
    /// The camera.
    pub camera: Camera,
    /// The image composited on white.
    pub image: Image,
}

impl ViewFrame {
    /// Loads view `view` at frame `t` of `role`'s split.
    pub fn load(scene: &Scene, role: Role, view: &str, t: usize) -> anyhow::Result<Self> {
        Ok(Self {
            camera: scene.camera(role, view, t)?,
            image: scene.image(role, view, t)?,
        })
    }

    /// Rays and target colours `[R, 3]` of the given pixels.
    pub fn batch(&self, pixels: &[u32], device: &Device) -> (RayBatch, Tensor<2>) {
        batch_of(&[(self, pixels)], device)
    }
}

/// Rays and target colours `[R, 3]` of several views' pixels in one batch, view after view.
pub fn batch_of(parts: &[(&ViewFrame, &[u32])], device: &Device) -> (RayBatch, Tensor<2>) {
    let mut rays = RayBatch::default();
    let mut target = Vec::new();
    for (view, pixels) in parts {
        let r = RayBatch::from(&view.camera.rays(pixels));
        rays.origins.extend(r.origins);
        rays.dirs.extend(r.dirs);
        for &p in *pixels {
            let i = p as usize * 3;
            target.extend_from_slice(&view.image.rgb[i..i + 3]);
        }
    }
    let n = target.len() / 3;
    let target = neurofluid_core::transfer::upload(TensorData::new(target, [n, 3]), device);
    (rays, target)
}

/// The rays of part `i` when `rays` are shared among `parts` parts: `rays / parts`, and one
/// more for each of the first `rays % parts`.
pub fn ray_share(rays: usize, parts: usize, i: usize) -> usize {
    rays / parts + usize::from(i < rays % parts)
}

pub use neurofluid_core::tensors::{points_tensor, tensor_points};

/// The views the joint stage trains on, each at every training frame: the training view (split
/// `train`), then `joint.extra_views` (warm-up views).
pub fn joint_sources(scene: &Scene, cfg: &JointSection) -> anyhow::Result<Vec<(Role, String)>> {
    cfg.view(scene).context("the scene has no training view")?;
    if !cfg.extra_views.is_empty() {
        require_warmup_every_frame(scene, &cfg.extra_views_label())?;
    }
    Ok(cfg.views_by_role(scene))
}

/// Checks that `scene` has its warm-up views at every training frame, which `what` trains on;
/// the error says how a built-in scene gets them.
pub fn require_warmup_every_frame(scene: &Scene, what: &str) -> anyhow::Result<()> {
    let (warm, train) = (scene.frames(Role::Warmup), scene.frames(Role::Train));
    anyhow::ensure!(
        warm.start <= train.start && warm.end >= train.end,
        "{what} trains on warm-up views at every training frame, but the scene has them only at \
         frames {}..{} (training frames {}..{}); for a built-in scene, set \
         `scene.generate.warmup_every_frame = true` and the generator renders them",
        warm.start,
        warm.end,
        train.start,
        train.end
    );
    Ok(())
}

/// Checks a particle state read from a scene: finite values, matching lengths.
pub fn check_particles(p: &Particles, what: &str) -> anyhow::Result<()> {
    anyhow::ensure!(
        p.pos.len() == p.vel.len(),
        "{what}: {} positions but {} velocities",
        p.pos.len(),
        p.vel.len()
    );
    anyhow::ensure!(!p.pos.is_empty(), "{what}: no particles");
    if let Some(i) = p
        .pos
        .iter()
        .chain(&p.vel)
        .position(|v| !v.iter().all(|x| x.is_finite()))
    {
        anyhow::bail!("{what}: particle {} is not finite", i % p.pos.len());
    }
    Ok(())
}

/// The particles of frame `t` of `role`'s split, checked ([`check_particles`]); `what` names them
/// in errors.
pub fn load_particles(
    scene: &Scene,
    role: Role,
    t: usize,
    what: &str,
) -> anyhow::Result<Particles> {
    let p = scene.particles(role, t).with_context(|| what.to_string())?;
    check_particles(&p, what)?;
    Ok(p)
}

/// Checks a particle sequence (frames `first`, `first + 1`, …): every frame as
/// [`check_particles`], and the fluid keeps its particle count.
pub fn check_sequence(frames: &[Particles], first: usize) -> anyhow::Result<()> {
    let n = frames.first().map_or(0, |f| f.pos.len());
    for (i, f) in frames.iter().enumerate() {
        let t = first + i;
        check_particles(f, &format!("frame {t}"))?;
        anyhow::ensure!(
            f.pos.len() == n,
            "frame {t} has {} particles, frame {first} has {n}: a fluid keeps its particles",
            f.pos.len()
        );
    }
    Ok(())
}

/// Scalar value of a one-element tensor.
pub fn scalar(t: &Tensor<1>) -> f64 {
    neurofluid_core::transfer::read_scalar(t.clone())
}

/// Renders `particles` (`[N, 3]`) from `view` with PhysNeRF (no gradients) and compares the
/// render with the view's image: the PSNR and `[render | truth]`.
pub fn render_beside_truth(
    physnerf: &PhysNerf,
    view: &ViewFrame,
    particles: &Tensor<2>,
) -> anyhow::Result<Evaluation> {
    let physnerf = physnerf.valid();
    let cam = &view.camera;
    let chunk = physnerf.config.chunk;
    let image = render_image(&physnerf, cam, particles, chunk, &mut |_, _| {})?;
    let (w, h) = (cam.width as usize, cam.height as usize);
    let pred = RgbImage::new(w, h, image.best().to_vec())?;
    let truth = RgbImage::new(w, h, view.image.rgb.clone())?;
    Ok(Evaluation {
        psnr: Some(psnr(&pred, &truth)?),
        picture: Some(side_by_side(&pred, &truth)),
        scores: Vec::new(),
    })
}
