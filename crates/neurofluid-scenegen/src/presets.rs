//! The built-in scenes at their two scales: box, initial fluid body, material and views.
//!
//! Paper scale uses the released data's box turned y-up (x, z ∈ [−1, 1], y ∈ [−1, 2.455],
//! ~34k wall particles) and ~10k fluid particles; quick scale a 1.4 × 1.7 × 1.4 m box and
//! ~2–3k particles so a scene renders in a few minutes on 2 cores.

use serde::Serialize;

use crate::config::{Scale, SceneConfig, SceneKind};
use crate::render::trace::Appearance;
use crate::shapes::Shape;
use crate::sph::Fluid;

/// Everything needed to generate one scene.
#[derive(Debug, Clone, Serialize)]
pub struct Preset {
    /// Scene name.
    pub name: String,
    /// Scale name.
    pub scale: Scale,
    /// Seed.
    pub seed: u64,
    /// Box walls, lower corner.
    pub box_lo: [f64; 3],
    /// Box walls, upper corner.
    pub box_hi: [f64; 3],
    /// Initial fluid body (before the seeded placement jitter).
    pub shape: Shape,
    /// Fluid rest density (kg/m³).
    pub density: f64,
    /// Fluid viscosity (m²/s).
    pub viscosity: f64,
    /// Wall viscosity (m²/s).
    pub wall_viscosity: f64,
    /// Gravity's magnitude (m/s²) down −y; recorded only where it is not the world's, so that
    /// scenes made before it existed keep their manifests.
    #[serde(skip_serializing_if = "is_earth")]
    pub gravity: f64,
    /// Look of the fluid.
    pub appearance: Appearance,
    /// Particle radius (m).
    pub radius: f64,
    /// Frames per second.
    pub fps: f64,
    /// Training frames (view_1).
    pub train_frames: usize,
    /// Test frames (test views).
    pub test_frames: usize,
    /// Number of test views.
    pub test_views: usize,
    /// Image width = height.
    pub image_size: u32,
    /// Sub-samples per pixel per axis.
    pub samples_per_axis: u32,
    /// Horizontal field of view (radians).
    pub camera_angle_x: f32,
    /// Camera elevation (degrees).
    pub elevation_deg: f32,
    /// Surface voxel size (m).
    pub voxel: f32,
    /// Surface iso level (fraction of rest density).
    pub iso: f32,
    /// Support of the surface kernel in particle radii.
    pub surface_support: f32,
    /// Render every warm-up view at every training frame (not only at frame 0): the images of
    /// the NeRF-T baseline and of multi-view losses.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub warmup_every_frame: bool,
    /// Render validation views too: views on the warm-up ring over the test frames, at the
    /// warm-up azimuths' midpoints that no test view takes ([`crate::generate::validation_views`]).
    /// No stage trains on them; `eval.novel_views = "validation"` scores them.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub validation_views: bool,
}

impl Preset {
    /// The preset of `cfg.name` at `cfg.scale` with `cfg`'s overrides applied.
    pub fn resolve(cfg: &SceneConfig) -> Self {
        let paper = cfg.scale == Scale::Paper;
        let (box_lo, box_hi) = if paper {
            ([-1.0, -1.0, -1.0], [1.0, 2.455, 1.0])
        } else {
            ([-0.7, -0.7, -0.7], [0.7, 1.0, 0.7])
        };
        let floor = box_lo[1];
        let shape = match (cfg.name, paper) {
            (SceneKind::WaterCube, false) => Shape::Cube {
                center: [-0.12, floor + 0.35 + 0.325, 0.05],
                size: 0.65,
            },
            (SceneKind::WaterCube, true) => Shape::Cube {
                center: [-0.2, floor + 0.4 + 0.55, 0.05],
                size: 1.1,
            },
            (SceneKind::WaterSphere, false) => Shape::Sphere {
                center: [0.1, floor + 0.43 + 0.3, -0.05],
                radius: 0.43,
            },
            (SceneKind::WaterSphere, true) => Shape::Sphere {
                center: [0.15, floor + 0.67 + 0.5, -0.05],
                radius: 0.67,
            },
            (SceneKind::HoneyCone, false) => Shape::Cone {
                base: [0.0, floor + 0.08, 0.0],
                radius: 0.55,
                height: 0.95,
            },
            (SceneKind::HoneyCone, true) => Shape::Cone {
                base: [0.0, floor + 0.1, 0.0],
                radius: 0.85,
                height: 1.5,
            },
            (SceneKind::WaterBunny, false) => Shape::Bunny {
                base: [-0.03, floor + 0.12, 0.0],
                scale: 1.0,
            },
            (SceneKind::WaterBunny, true) => Shape::Bunny {
                base: [-0.08, floor + 0.2, 0.0],
                scale: 1.6,
            },
        };
        let honey = cfg.name == SceneKind::HoneyCone;
        let fluid = if honey { Fluid::HONEY } else { Fluid::WATER };
        let viscosity = cfg.viscosity.unwrap_or(fluid.viscosity);
        Self {
            name: cfg.name.name().to_string(),
            scale: cfg.scale,
            seed: cfg.seed,
            box_lo,
            box_hi,
            shape,
            density: cfg.density.unwrap_or(fluid.density),
            viscosity,
            wall_viscosity: if honey {
                viscosity
            } else {
                fluid.wall_viscosity
            },
            gravity: cfg.gravity.unwrap_or(EARTH_GRAVITY),
            appearance: if honey {
                Appearance::Honey
            } else {
                Appearance::Water
            },
            radius: 0.025,
            fps: 50.0,
            train_frames: cfg.train_frames.unwrap_or(50),
            test_frames: cfg.test_frames.unwrap_or(60),
            test_views: cfg.test_views.unwrap_or(1),
            image_size: cfg.image_size.unwrap_or(if paper { 400 } else { 100 }),
            samples_per_axis: cfg.samples_per_axis.unwrap_or(if paper { 1 } else { 2 }),
            camera_angle_x: cfg.camera_angle_x.unwrap_or(0.55),
            elevation_deg: cfg.elevation_deg.unwrap_or(26.0),
            voxel: if paper { 0.02 } else { 0.025 },
            iso: 0.4,
            surface_support: 5.0,
            warmup_every_frame: cfg.warmup_every_frame.unwrap_or(false),
            validation_views: cfg.validation_views.unwrap_or(false),
        }
    }

    /// The fluid material of the solver.
    pub fn fluid(&self) -> Fluid {
        Fluid {
            density: self.density,
            viscosity: self.viscosity,
            wall_viscosity: self.wall_viscosity,
        }
    }
}

/// The world's gravity (m/s²), every built-in scene's unless `gravity` says otherwise.
pub const EARTH_GRAVITY: f64 = 9.81;

fn is_earth(g: &f64) -> bool {
    *g == EARTH_GRAVITY
}

/// The settings that only add views to a scene (compared by no identity check).
const ADDED_VIEWS: [&str; 2] = ["warmup_every_frame", "validation_views"];

impl Preset {
    /// The settings of this preset that differ from `generator`, the serialisation a generated
    /// scene's manifest records (`warmup_every_frame` and `validation_views` aside: they add
    /// views to an existing scene and change nothing simulated or rendered). Settings the record
    /// lacks (a scene of an earlier release) are not compared, except gravity, which a record
    /// leaves out where it is the world's.
    pub fn changes_from(&self, generator: &serde_json::Value) -> Vec<String> {
        let Ok(serde_json::Value::Object(mut now)) = serde_json::to_value(self) else {
            return Vec::new();
        };
        now.insert("gravity".into(), serde_json::json!(self.gravity));
        now.iter()
            .filter(|(k, _)| !ADDED_VIEWS.contains(&k.as_str()))
            .filter(|(k, v)| recorded(generator, k).is_some_and(|g| g != **v))
            .map(|(k, _)| k.clone())
            .collect()
    }
}

/// The value of setting `key` in a generator record (`gravity` absent: the world's).
fn recorded(generator: &serde_json::Value, key: &str) -> Option<serde_json::Value> {
    generator
        .get(key)
        .cloned()
        .or_else(|| (key == "gravity").then(|| serde_json::json!(EARTH_GRAVITY)))
}
