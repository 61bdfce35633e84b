//! Run-time settings of the DLF model: gravity, time step, frame, geometry mode, and the rules of
//! its step ([`StepRules`]) with the box its walls keep.

use neurofluid_core::scene::{Aabb, UpAxis};

use crate::rules::{RulesError, StepRules};

/// How the conv geometry (mapped coordinates, trilinear and window weights) enters autodiff.
/// In files: `"constant"` or `"differentiable"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GeometryMode {
    /// Geometry is a constant: gradients reach features and kernels only (Open3D, the default).
    #[default]
    Constant,
    /// Gradients also flow through positions into the mapping, trilinear weights and window.
    Differentiable,
}

/// Rotation from the scene's frame into the frame the weights were trained in (y up).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Frame {
    /// The scene is y-up like the public DLF weights: no rotation.
    #[default]
    YUp,
    /// The scene is z-up (NeuroFluid's Blender scenes): model (x, y, z) = scene (x, z, −y).
    ZUp,
    /// Any rotation matrix R (row-major), model = R · scene.
    Custom([[f32; 3]; 3]),
}

impl Frame {
    /// The scene→model rotation, `None` for the identity.
    pub fn rotation(&self) -> Option<[[f32; 3]; 3]> {
        match self {
            Frame::YUp => None,
            Frame::ZUp => Some([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]),
            Frame::Custom(r) => Some(*r),
        }
    }

    /// Rotates a scene vector into the model frame.
    pub fn to_model(&self, v: [f32; 3]) -> [f32; 3] {
        match self.rotation() {
            None => v,
            Some(r) => std::array::from_fn(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2]),
        }
    }

    /// Rotates a model vector back into the scene frame.
    pub fn to_scene(&self, v: [f32; 3]) -> [f32; 3] {
        match self.rotation() {
            None => v,
            Some(r) => std::array::from_fn(|i| r[0][i] * v[0] + r[1][i] * v[1] + r[2][i] * v[2]),
        }
    }
}

/// Settings of a DLF model that are not weights.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DlfConfig {
    /// Gravity in the **scene** frame (m/s²).
    pub gravity: [f32; 3],
    /// Time step of one network step (s).
    pub dt: f32,
    /// Filter extent (support diameter) of every conv (m); the search radius is half of it.
    pub extent: f32,
    /// Scale of the raw network output into a position correction (m).
    pub output_scale: f32,
    /// Scene→model rotation.
    pub frame: Frame,
    /// Whether the conv geometry is differentiable.
    pub geometry: GeometryMode,
    /// The rules of the step beyond the published model's (the reference: none).
    pub rules: StepRules,
    /// The box the walls keep every predicted particle in (scene frame, metres), under
    /// `rules.containment = "box"`: a step that would carry a particle through a wall ends on
    /// the wall, its velocity the displacement it really made. `None` (the reference): the
    /// walls act only through the box particles' convolution.
    pub container: Option<Aabb>,
}

impl Default for DlfConfig {
    /// The published DLF model in its own y-up frame.
    fn default() -> Self {
        Self {
            gravity: [0.0, -9.81, 0.0],
            dt: 1.0 / 50.0,
            extent: crate::geometry::FILTER_EXTENT,
            output_scale: 1.0 / 128.0,
            frame: Frame::YUp,
            geometry: GeometryMode::Constant,
            rules: StepRules::default(),
            container: None,
        }
    }
}

impl DlfConfig {
    /// NeuroFluid's z-up scenes (gravity (0, 0, −9.81)) with the y-up weights.
    pub fn z_up() -> Self {
        Self {
            gravity: [0.0, 0.0, -9.81],
            frame: Frame::ZUp,
            ..Self::default()
        }
    }

    /// The published model on a scene with up axis `up`: [`DlfConfig::default`] for y-up,
    /// [`DlfConfig::z_up`] for z-up.
    pub fn for_up_axis(up: UpAxis) -> Self {
        match up {
            UpAxis::Y => Self::default(),
            UpAxis::Z => Self::z_up(),
        }
    }

    /// This model under `rules`, its walls at `box_interior` (the scene's box; `None` where
    /// none is known, which only rules without walls accept).
    pub fn with_rules(
        mut self,
        rules: StepRules,
        box_interior: Option<Aabb>,
    ) -> Result<Self, RulesError> {
        if let Some(e) = rules.problem() {
            return Err(e);
        }
        self.container = rules.container(box_interior)?;
        self.rules = rules;
        Ok(self)
    }

    /// Gravity in the model frame.
    pub fn model_gravity(&self) -> [f32; 3] {
        self.frame.to_model(self.gravity)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn z_up_gravity_points_down_in_model_frame() {
        let c = DlfConfig::z_up();
        assert_eq!(c.model_gravity(), [0.0, -9.81, 0.0]);
        let v = [0.3, -0.2, 0.7];
        assert_eq!(c.frame.to_scene(c.frame.to_model(v)), v);
    }
}
