//! What the joint stage trains on: the views' images at every training frame, the true first
//! state, the box; and DLF's rollout over the training frames.

use burn::prelude::*;
use neurofluid_core::ray_focus::image_foreground;
use neurofluid_core::scene::{Aabb, Particles, Role, Scene};
use neurofluid_dlf::DlfNet;

use crate::config::JointSection;
use crate::stages::views::{
    ViewFrame, check_sequence, joint_sources, load_particles, points_tensor,
};

/// The carried particle state (positions, velocities) on the device.
pub type State = (Tensor<2>, Tensor<2>);

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
    /// The true positions at every training frame, when the scene has them (diagnostics and the
    /// truth term only).
    pub truth: Option<Vec<Vec<[f32; 3]>>>,
    /// Where each image of `views` shows fluid (empty unless `joint.foreground_rays` uses it).
    pub foreground: Vec<Vec<Vec<bool>>>,
    /// The particle radius (the projected footprint of a particle).
    pub radius: f32,
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
        // only `joint.foreground_rays` uses them
        let foreground = if cfg.foreground_rays > 0.0 {
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

    /// The true first training state on `device`, where every epoch starts.
    pub fn initial_state(&self, device: &Device) -> State {
        (
            points_tensor(&self.initial.pos, device),
            points_tensor(&self.initial.vel, device),
        )
    }
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
