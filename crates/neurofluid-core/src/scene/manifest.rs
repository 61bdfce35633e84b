//! The scene manifest (`scene.json`): which views and frames serve warm-up, training,
//! validation and testing, the up axis, the particle radius, the box interior and the ray bounds.
//!
//! NeuroFluid's released scenes have no manifest; [`SceneManifest::released`] gives the
//! defaults of their layout (spec §5.1): views 1–4 warm-up at frame 0, `view_1` trains on
//! frames 0–49 of split `train`, `view_5` tests on frames 0–59 of split `test`, z up,
//! box interior x, y ∈ [−0.975, 0.975], z ∈ [−0.975, 2.4302], near/far 9/13.

use std::ops::Range;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::error::{Result, SceneError};

/// File name of the manifest inside a scene directory.
pub const MANIFEST_FILE: &str = "scene.json";

/// Which world axis points up (against gravity).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum UpAxis {
    /// +y up, gravity (0, −9.81, 0): the built-in scenes and DLF's public weights.
    Y,
    /// +z up, gravity (0, 0, −9.81): NeuroFluid's released scenes.
    Z,
}

impl UpAxis {
    /// Index of the up axis (1 for y, 2 for z).
    pub fn index(self) -> usize {
        match self {
            UpAxis::Y => 1,
            UpAxis::Z => 2,
        }
    }

    /// Gravity vector of this frame (9.81 m/s² down the up axis).
    pub fn gravity(self) -> [f32; 3] {
        let mut g = [0.0; 3];
        g[self.index()] = -9.81;
        g
    }
}

/// A half-open range `[start, end)` of positions in a transforms file's `frames` list.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameRange {
    /// First frame (inclusive).
    pub start: usize,
    /// One past the last frame.
    pub end: usize,
}

impl FrameRange {
    /// The range as a `Range<usize>`.
    pub fn range(&self) -> Range<usize> {
        self.start..self.end
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.end.saturating_sub(self.start)
    }

    /// True when the range holds no frame.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// The views, split and frames of one role (warm-up, training or testing).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ViewSet {
    /// View directory names, e.g. `["view_1", "view_2"]`; particles come from the first.
    pub views: Vec<String>,
    /// Split name: the transforms file is `transforms_<split>.json`.
    pub split: String,
    /// Frames used, as positions in the transforms file's `frames` list.
    pub frames: FrameRange,
}

/// An axis-aligned box.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Aabb {
    /// Lower corner.
    pub min: [f32; 3],
    /// Upper corner.
    pub max: [f32; 3],
}

impl Aabb {
    /// True when `p` lies inside (boundary included).
    pub fn contains(&self, p: [f32; 3]) -> bool {
        self.within(p, 0.0)
    }

    /// True when `p` lies no farther than `margin` outside the box on any axis.
    pub fn within(&self, p: [f32; 3], margin: f32) -> bool {
        (0..3).all(|a| p[a] >= self.min[a] - margin && p[a] <= self.max[a] + margin)
    }

    /// `p` moved to the nearest point of the box (each axis clamped).
    pub fn clamp(&self, p: [f32; 3]) -> [f32; 3] {
        std::array::from_fn(|a| p[a].clamp(self.min[a], self.max[a]))
    }

    /// The centre point.
    pub fn centre(&self) -> [f32; 3] {
        std::array::from_fn(|a| 0.5 * (self.min[a] + self.max[a]))
    }
}

/// The role a view plays.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// Renderer warm-up (several views, usually frame 0 only).
    Warmup,
    /// Joint training (one view, a frame sequence).
    Train,
    /// Held-out evaluation.
    Test,
    /// Views kept aside to choose settings with (optional): no stage trains on them, and
    /// `eval.novel_views = "validation"` scores them in place of the test views. They hold the
    /// test frames, so their scores fall in the same windows.
    Validation,
}

/// The validation set of a manifest that has none: no views.
/// Particle radii a scene may give, in metres (the built-in scenes' and NeuroFluid's: 0.025).
const RADIUS_RANGE: std::ops::RangeInclusive<f32> = 1e-4..=1.0;

/// Frame rates a scene may give (the built-in scenes' and NeuroFluid's: 50).
const FPS_RANGE: std::ops::RangeInclusive<f32> = 1.0..=1e4;

/// How far from the origin a scene's box, far plane and cameras may reach, in metres.
pub(super) const SCENE_EXTENT: f32 = 1e4;

static NO_VIEWS: ViewSet = ViewSet {
    views: Vec::new(),
    split: String::new(),
    frames: FrameRange { start: 0, end: 0 },
};

/// Contents of `scene.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneManifest {
    /// Scene name.
    pub name: String,
    /// The up axis.
    pub up_axis: UpAxis,
    /// Fluid particle radius in metres.
    pub particle_radius: f32,
    /// Frames per second of the particle sequences.
    pub fps: f32,
    /// Warm-up views and frames.
    pub warmup: ViewSet,
    /// Training view(s) and frames.
    pub train: ViewSet,
    /// Test views and frames.
    pub test: ViewSet,
    /// Validation views (kept aside to choose settings with; [`Role::Validation`]), if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub validation: Option<ViewSet>,
    /// Box particle file relative to the scene root (`box.npz`, or the released `box.pt`).
    pub box_file: String,
    /// The box interior the fluid must stay in (for the boundary loss and clipped metrics).
    pub box_interior: Aabb,
    /// Near ray bound (world units).
    pub near: f32,
    /// Far ray bound (world units).
    pub far: f32,
    /// Free-form provenance (the generator's settings), if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub generator: Option<serde_json::Value>,
}

fn views(ids: &[u32]) -> Vec<String> {
    ids.iter().map(|k| format!("view_{k}")).collect()
}

impl SceneManifest {
    /// The defaults for a scene in NeuroFluid's released layout, named `name`
    /// (`honeycone` trains on frames 15–64, as in the released configuration).
    pub fn released(name: &str) -> Self {
        let train_start = if name.to_ascii_lowercase().contains("honeycone") {
            15
        } else {
            0
        };
        Self {
            name: name.to_string(),
            up_axis: UpAxis::Z,
            particle_radius: 0.025,
            fps: 50.0,
            warmup: ViewSet {
                views: views(&[1, 2, 3, 4]),
                split: "train".into(),
                frames: FrameRange { start: 0, end: 1 },
            },
            train: ViewSet {
                views: views(&[1]),
                split: "train".into(),
                frames: FrameRange {
                    start: train_start,
                    end: train_start + 50,
                },
            },
            test: ViewSet {
                views: views(&[5]),
                split: "test".into(),
                frames: FrameRange { start: 0, end: 60 },
            },
            validation: None,
            box_file: "box.pt".into(),
            box_interior: Aabb {
                min: [-0.975, -0.975, -0.975],
                max: [0.975, 0.975, 2.4302],
            },
            near: 9.0,
            far: 13.0,
            generator: None,
        }
    }

    /// The view set of a role (no views for [`Role::Validation`] when the scene has none).
    pub fn role(&self, role: Role) -> &ViewSet {
        match role {
            Role::Warmup => &self.warmup,
            Role::Train => &self.train,
            Role::Test => &self.test,
            Role::Validation => self.validation.as_ref().unwrap_or(&NO_VIEWS),
        }
    }

    /// Reads `path`.
    pub fn read(path: &Path) -> Result<Self> {
        let text = crate::input_file::read_string(path).map_err(|e| SceneError::io(path, e))?;
        let m: Self = serde_json::from_str(&text).map_err(|e| SceneError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        m.validate(path)?;
        Ok(m)
    }

    /// Checks the values a parser cannot: non-empty view lists of plain names (they become
    /// folder and file names), a box file inside the scene, positive radius and fps, ordered
    /// frame ranges and bounds, validation views (if any) on the test frames and apart from
    /// every other role's views.
    pub fn validate(&self, path: &Path) -> Result<()> {
        let sets = [
            ("warmup", &self.warmup),
            ("train", &self.train),
            ("test", &self.test),
        ];
        for (name, set) in sets
            .into_iter()
            .chain(self.validation.iter().map(|v| ("validation", v)))
        {
            for (field, value) in set
                .views
                .iter()
                .map(|v| (format!("{name}.views"), v))
                .chain([(format!("{name}.split"), &set.split)])
            {
                crate::paths::one_component(value)
                    .map_err(|expected| SceneError::field(path, field, expected))?;
            }
            if set.views.is_empty() {
                return Err(SceneError::field(
                    path,
                    format!("{name}.views"),
                    "at least one view",
                ));
            }
            if let Some(v) = crate::paths::first_repeated(&set.views) {
                return Err(SceneError::field(
                    path,
                    format!("{name}.views"),
                    format!("each view once, found {} twice", crate::paths::shown(v)),
                ));
            }
            if set.frames.start >= set.frames.end {
                return Err(SceneError::field(
                    path,
                    format!("{name}.frames"),
                    format!("start < end, got {}..{}", set.frames.start, set.frames.end),
                ));
            }
        }
        if let Some(val) = &self.validation {
            if val.frames != self.test.frames {
                return Err(SceneError::field(
                    path,
                    "validation.frames",
                    format!(
                        "the test frames {}..{} (validation scores share the test windows), got \
                         {}..{}",
                        self.test.frames.start,
                        self.test.frames.end,
                        val.frames.start,
                        val.frames.end
                    ),
                ));
            }
            if let Some(v) = val
                .views
                .iter()
                .find(|v| sets.iter().any(|(_, set)| set.views.contains(v)))
            {
                return Err(SceneError::field(
                    path,
                    "validation.views",
                    format!("views no other role lists, got {v:?}, which another role lists"),
                ));
            }
        }
        crate::paths::confined(&self.box_file, 0)
            .map_err(|expected| SceneError::field(path, "box_file", expected))?;
        if !RADIUS_RANGE.contains(&self.particle_radius) {
            return Err(SceneError::field(
                path,
                "particle_radius",
                format!(
                    "a radius from {} to {} m, found {}",
                    RADIUS_RANGE.start(),
                    RADIUS_RANGE.end(),
                    self.particle_radius
                ),
            ));
        }
        if !FPS_RANGE.contains(&self.fps) {
            return Err(SceneError::field(
                path,
                "fps",
                format!(
                    "a frame rate from {} to {} per second, found {}",
                    FPS_RANGE.start(),
                    FPS_RANGE.end(),
                    self.fps
                ),
            ));
        }
        if !(self.near >= 0.0 && self.far > self.near && self.far <= SCENE_EXTENT) {
            return Err(SceneError::field(
                path,
                "near/far",
                format!("0 ≤ near < far ≤ {SCENE_EXTENT} m"),
            ));
        }
        let corners = [self.box_interior.min, self.box_interior.max];
        if let Some(v) = corners
            .iter()
            .flatten()
            .find(|v| v.is_nan() || v.abs() > SCENE_EXTENT)
        {
            return Err(SceneError::field(
                path,
                "box_interior",
                format!("corners within ±{SCENE_EXTENT} m of the origin, found {v}"),
            ));
        }
        if (0..3).any(|a| {
            self.box_interior.min[a].partial_cmp(&self.box_interior.max[a])
                != Some(std::cmp::Ordering::Less)
        }) {
            return Err(SceneError::field(
                path,
                "box_interior",
                "min < max on every axis",
            ));
        }
        Ok(())
    }

    /// Writes the manifest to `path` atomically (pretty JSON).
    pub fn write(&self, path: &Path) -> Result<()> {
        let mut text = serde_json::to_string_pretty(self).map_err(|e| SceneError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        text.push('\n');
        crate::atomic::write_bytes(path, text.as_bytes()).map_err(|e| SceneError::io(path, e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Values no real scene has are refused with the field named (issue 72: fps 1e-30, a box of
    /// ±1e30 and a view listed twice were accepted).
    #[test]
    fn values_out_of_range_are_refused() {
        let path = Path::new("scene.json");
        let good = SceneManifest::released("watercube");
        good.validate(path).unwrap();
        type Edit = fn(&mut SceneManifest);
        let cases: [(&str, Edit); 6] = [
            ("fps", |m| m.fps = 1e-30),
            ("fps", |m| m.fps = 1e30),
            ("particle_radius", |m| m.particle_radius = 1e30),
            ("box_interior", |m| m.box_interior.min[1] = -1e30),
            ("near/far", |m| m.far = 1e30),
            ("test.views", |m| {
                let v = m.test.views[0].clone();
                m.test.views.push(v);
            }),
        ];
        for (field, edit) in cases {
            let mut m = good.clone();
            edit(&mut m);
            let e = m.validate(path).unwrap_err().to_string();
            assert!(e.contains(field), "{field}: {e}");
        }
    }
}
