//! What every stage needs: the experiment, its run folder, the device and the scene, plus the
//! conversions from scene data to tensors and rays.

use std::path::{Path, PathBuf};

use anyhow::Context;
use burn::prelude::*;
use neurofluid_core::camera::Camera;
use neurofluid_core::scene::{Image, Particles, Role, Scene};
use neurofluid_dlf::{DlfConfig, DlfNet, GeometryMode};
use neurofluid_physnerf::{FeatureFlags, NeighborSelection, PhysNerfConfig, RayBatch};

use crate::config::{Experiment, NeighborSelection as ConfigSelection};

/// An experiment ready to run: resolved config, run folder, device, opened scene.
#[derive(Debug)]
pub struct Run {
    /// The resolved experiment.
    pub exp: Experiment,
    /// `runs/<name>` (or the configured folder).
    pub dir: PathBuf,
    /// The device with autodiff enabled.
    pub device: Device,
    /// The scene the experiment trains on.
    pub scene: Scene,
}

impl Run {
    /// Resolves the device, makes sure the scene exists (generating a built-in one if it is
    /// missing), creates the run folder and saves the resolved config there.
    pub fn open(exp: Experiment) -> anyhow::Result<Self> {
        let device = neurofluid_core::device::parse_device(&exp.device)
            .with_context(|| format!("the experiment's device `{}`", exp.device))?
            .autodiff();
        let scene_dir = super::scene_source::ensure_scene(&exp)?;
        let scene = Scene::open(&scene_dir)
            .with_context(|| format!("opening the scene {}", scene_dir.display()))?;
        let dir = exp.run_dir();
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        exp.save_resolved(&dir)?;
        Ok(Self {
            exp,
            dir,
            device,
            scene,
        })
    }

    /// The run's metrics log, without the rows a resumed stage will log again (those after its
    /// latest checkpoint), so an interrupted run leaves no duplicate steps.
    pub fn open_log(&self) -> anyhow::Result<crate::metrics_log::MetricsLog> {
        let warmup = super::checkpoint::saved_step(&self.stage_dir(super::warmup::STAGE));
        let joint = super::checkpoint::saved_step(&self.stage_dir(super::joint::STAGE));
        let log = crate::metrics_log::MetricsLog::open_resumed(&self.dir, |row| {
            match row.stage.trim_end_matches("-preview") {
                s if s == super::warmup::STAGE => row.step <= warmup,
                s if s == super::joint::STAGE => row.step <= joint,
                _ => true,
            }
        })?;
        Ok(log)
    }

    /// The folder of one stage inside the run folder.
    pub fn stage_dir(&self, stage: &str) -> PathBuf {
        self.dir.join(stage)
    }

    /// The renderer settings: the experiment's `[renderer]`, with near/far from the scene
    /// manifest unless the experiment sets them.
    pub fn renderer_config(&self) -> PhysNerfConfig {
        let r = &self.exp.renderer;
        let m = self.scene.manifest();
        let (near, far) = r.bounds(m.near, m.far);
        PhysNerfConfig {
            near: near as f64,
            far: far as f64,
            n_samples: r.n_samples,
            n_importance: r.n_importance,
            search_radius: r.radius as f64,
            k: r.k,
            selection: match r.selection {
                ConfigSelection::LowestIndex => NeighborSelection::LowestIndex,
                ConfigSelection::Nearest => NeighborSelection::Nearest,
            },
            stratified: r.jitter,
            features: FeatureFlags {
                pc: r.encoding.pc,
                sigma_p: r.encoding.sigma_p,
                vd: r.encoding.vd,
                dc: r.encoding.dc,
            },
            depth: r.depth,
            width: r.width,
            skip: r.skip,
            ..PhysNerfConfig::default()
        }
    }

    /// The transition model's settings: gravity along the scene's up axis, and the frame
    /// rotation that lets the y-up public weights run on a z-up scene.
    pub fn dlf_config(&self) -> DlfConfig {
        let mut cfg = match self.scene.up_axis() {
            neurofluid_core::scene::UpAxis::Z => DlfConfig::z_up(),
            _ => DlfConfig::default(),
        };
        cfg.dt = 1.0 / self.scene.manifest().fps;
        if self.exp.dlf.geometry_grad {
            cfg.geometry = GeometryMode::Differentiable;
        }
        cfg
    }

    /// Loads the transition model from the experiment's weights (`.pt`, `.safetensors` or one
    /// of our checkpoints).
    pub fn load_dlf(&self, path: &Path) -> anyhow::Result<DlfNet> {
        let net = neurofluid_dlf::load_dlf(path, self.dlf_config(), &self.device)
            .with_context(|| format!("loading DLF weights {}", path.display()))?;
        Ok(net)
    }
}

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
        let rays = RayBatch::from(&self.camera.rays(pixels));
        let mut target = Vec::with_capacity(pixels.len() * 3);
        for &p in pixels {
            let i = p as usize * 3;
            target.extend_from_slice(&self.image.rgb[i..i + 3]);
        }
        let target = Tensor::from_data(TensorData::new(target, [pixels.len(), 3]), device);
        (rays, target)
    }
}

pub use neurofluid_core::tensors::{points_tensor, tensor_points};

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

/// Scalar value of a one-element tensor.
pub fn scalar(t: &Tensor<1>) -> f64 {
    t.clone().into_scalar::<f32>() as f64
}
