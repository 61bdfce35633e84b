//! The `[scene]` table of an experiment TOML: which built-in scene to generate, at which scale,
//! with which seed and where, plus optional overrides of the preset.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// The built-in scenes of the paper.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SceneKind {
    /// A water cube dropped into the box.
    WaterCube,
    /// A water sphere dropped into the box.
    WaterSphere,
    /// A honey cone slumping on the floor.
    HoneyCone,
    /// A procedural water bunny (the novel shape).
    WaterBunny,
}

impl SceneKind {
    /// All scenes.
    pub const ALL: [SceneKind; 4] = [
        SceneKind::WaterCube,
        SceneKind::WaterSphere,
        SceneKind::HoneyCone,
        SceneKind::WaterBunny,
    ];

    /// Lower-case name (`watercube`).
    pub fn name(self) -> &'static str {
        match self {
            SceneKind::WaterCube => "watercube",
            SceneKind::WaterSphere => "watersphere",
            SceneKind::HoneyCone => "honeycone",
            SceneKind::WaterBunny => "waterbunny",
        }
    }

    /// Parses a name (case-insensitive).
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL
            .into_iter()
            .find(|k| k.name().eq_ignore_ascii_case(s))
    }
}

/// Size class of a scene.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Scale {
    /// A few thousand particles, ≤ 100×100 images: minutes on 2 cores.
    #[default]
    Quick,
    /// ~10k particles, 400×400 images, as in the paper.
    Paper,
}

impl Scale {
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Scale::Quick => "quick",
            Scale::Paper => "paper",
        }
    }

    /// Parses a name (case-insensitive).
    pub fn parse(s: &str) -> Option<Self> {
        [Scale::Quick, Scale::Paper]
            .into_iter()
            .find(|k| k.name().eq_ignore_ascii_case(s))
    }
}

/// The `[scene]` table. Only `name` is required.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneConfig {
    /// Which scene.
    pub name: SceneKind,
    /// `quick` (default) or `paper`.
    #[serde(default)]
    pub scale: Scale,
    /// Seed of the placement and lattice jitter (same seed → byte-identical files).
    #[serde(default)]
    pub seed: u64,
    /// Output directory (default `data/<name>_<scale>`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub out: Option<PathBuf>,
    /// Image width = height in pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image_size: Option<u32>,
    /// Sub-samples per pixel per axis (antialiasing; 2 → 4 rays per pixel).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub samples_per_axis: Option<u32>,
    /// Frames of the training sequence (view_1, split `train`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub train_frames: Option<usize>,
    /// Frames of the test sequence (split `test`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub test_frames: Option<usize>,
    /// Number of held-out test views.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub test_views: Option<usize>,
    /// Horizontal field of view (radians).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_angle_x: Option<f32>,
    /// Camera elevation above the horizontal (degrees).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub elevation_deg: Option<f32>,
    /// Fluid viscosity coefficient (m²/s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub viscosity: Option<f64>,
    /// Fluid rest density (kg/m³).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub density: Option<f64>,
    /// Gravity's magnitude (m/s², default 9.81), pointing down the scene's −y: a scene whose
    /// truth falls faster or slower than the world's, for identifying gravity from images.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gravity: Option<f64>,
    /// Render the warm-up views at every training frame (default false: at frame 0 only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warmup_every_frame: Option<bool>,
    /// Render validation views too (default false): views on the warm-up ring over the test
    /// frames, at the warm-up azimuths' midpoints that no test view takes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub validation_views: Option<bool>,
}

impl SceneConfig {
    /// A config for `name` at `scale` with seed 0 and no overrides.
    pub fn new(name: SceneKind, scale: Scale) -> Self {
        Self {
            name,
            scale,
            seed: 0,
            out: None,
            image_size: None,
            samples_per_axis: None,
            train_frames: None,
            test_frames: None,
            test_views: None,
            camera_angle_x: None,
            elevation_deg: None,
            viscosity: None,
            density: None,
            gravity: None,
            warmup_every_frame: None,
            validation_views: None,
        }
    }

    /// The output directory: `out`, or `data/<name>_<scale>`.
    pub fn out_dir(&self) -> PathBuf {
        self.out.clone().unwrap_or_else(|| {
            PathBuf::from(format!("data/{}_{}", self.name.name(), self.scale.name()))
        })
    }

    /// Reads the `[scene]` table of an experiment TOML file.
    pub fn from_toml_file(path: &Path) -> Result<Self, ConfigError> {
        let text = neurofluid_core::input_file::read_string(path).map_err(|e| ConfigError::Io {
            path: path.to_path_buf(),
            error: e,
        })?;
        Self::from_toml_str(&text, path)
    }

    /// Parses the `[scene]` table of TOML text (`path` only names the source in errors).
    /// Settings may sit in `[scene]` itself or in its `[scene.generate]` sub-table (the
    /// experiment shape); `builtin` and `dir` are accepted for `name` and `out`.
    pub fn from_toml_str(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let table: toml::Table = toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let scene = table.get("scene").ok_or_else(|| ConfigError::Parse {
            path: path.to_path_buf(),
            message: "missing table `[scene]` (with at least `name = \"watercube\"`)".into(),
        })?;
        let mut scene = scene.clone();
        if let Some(t) = scene.as_table_mut() {
            // the experiment shape: `[scene]` name/builtin, scale, out/dir + `[scene.generate]`
            if let Some(toml::Value::Table(generate)) = t.remove("generate") {
                for (k, v) in generate {
                    t.entry(k).or_insert(v);
                }
            }
            for (alias, key) in [("builtin", "name"), ("dir", "out")] {
                if let Some(v) = t.remove(alias) {
                    t.entry(key).or_insert(v);
                }
            }
        }
        let cfg: Self = scene
            .try_into()
            .map_err(|e: toml::de::Error| ConfigError::Parse {
                path: path.to_path_buf(),
                message: format!("in `[scene]`: {e}"),
            })?;
        cfg.validate(path)?;
        Ok(cfg)
    }

    /// Checks the value ranges of the overrides.
    pub fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        let bad = |field: &str, expected: &str| {
            Err(ConfigError::Parse {
                path: path.to_path_buf(),
                message: format!("`scene.{field}`: expected {expected}"),
            })
        };
        if self.image_size.is_some_and(|s| !(8..=4096).contains(&s)) {
            return bad("image_size", "8 ≤ size ≤ 4096");
        }
        if self.samples_per_axis.is_some_and(|s| !(1..=8).contains(&s)) {
            return bad("samples_per_axis", "1 ≤ n ≤ 8");
        }
        if self.train_frames.is_some_and(|f| f < 2) {
            return bad("train_frames", "at least 2 frames");
        }
        if self.test_frames.is_some_and(|f| f < 2) {
            return bad("test_frames", "at least 2 frames");
        }
        if self.test_views.is_some_and(|v| !(1..=16).contains(&v)) {
            return bad("test_views", "1 to 16 views");
        }
        if self.validation_views == Some(true)
            && crate::generate::validation_azimuths(self.test_views.unwrap_or(1)).is_empty()
        {
            return bad(
                "validation_views",
                "test views that leave a warm-up midpoint azimuth (75°, 165°, 255°, 345°) free",
            );
        }
        if self.camera_angle_x.is_some_and(|a| !(a > 0.01 && a < 3.0)) {
            return bad("camera_angle_x", "an angle in (0.01, 3) radians");
        }
        if self
            .elevation_deg
            .is_some_and(|a| !(-80.0..=80.0).contains(&a))
        {
            return bad("elevation_deg", "an angle in [−80, 80] degrees");
        }
        if self.viscosity.is_some_and(|v| !(0.0..=10.0).contains(&v)) {
            return bad("viscosity", "0 ≤ viscosity ≤ 10 m²/s");
        }
        if self
            .density
            .is_some_and(|v| !(100.0..=20000.0).contains(&v))
        {
            return bad("density", "100 ≤ density ≤ 20000 kg/m³");
        }
        if self.gravity.is_some_and(|g| !(0.0..=100.0).contains(&g)) {
            return bad("gravity", "0 ≤ gravity ≤ 100 m/s²");
        }
        Ok(())
    }
}

/// A bad `[scene]` table: the scene error's `Io` (the file could not be read) or `Parse` (the
/// TOML is malformed, or a field is missing or out of range, named in the message).
pub type ConfigError = neurofluid_core::scene::SceneError;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scene_table_parses_with_defaults_and_overrides() {
        let p = Path::new("exp.toml");
        let c = SceneConfig::from_toml_str("[scene]\nname = \"honeycone\"\n", p).unwrap();
        assert_eq!(c, SceneConfig::new(SceneKind::HoneyCone, Scale::Quick));
        assert_eq!(c.out_dir(), PathBuf::from("data/honeycone_quick"));
        let c = SceneConfig::from_toml_str(
            "[other]\nx = 1\n[scene]\nname = \"waterbunny\"\nscale = \"paper\"\nseed = 3\nout = \"d\"\nimage_size = 64\n",
            p,
        )
        .unwrap();
        assert_eq!(
            (c.name, c.scale, c.seed, c.image_size),
            (SceneKind::WaterBunny, Scale::Paper, 3, Some(64))
        );
        assert_eq!(c.out_dir(), PathBuf::from("d"));
        let nested = SceneConfig::from_toml_str(
            "name = \"run\"\n[scene]\nbuiltin = \"waterbunny\"\nscale = \"paper\"\ndir = \"d\"\n\
             [scene.generate]\nseed = 3\nimage_size = 64\n",
            p,
        )
        .unwrap();
        assert_eq!(nested, c);
    }

    #[test]
    fn bad_tables_name_the_file_and_field() {
        let p = Path::new("exp.toml");
        let e = SceneConfig::from_toml_str("[train]\n", p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("exp.toml") && e.contains("[scene]"), "{e}");
        let e = SceneConfig::from_toml_str("[scene]\nname = \"lava\"\n", p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("lava") || e.contains("name"), "{e}");
        let e = SceneConfig::from_toml_str("[scene]\nname = \"watercube\"\nimgsize = 3\n", p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("imgsize"), "{e}");
        let e = SceneConfig::from_toml_str("[scene]\nname = \"watercube\"\nimage_size = 3\n", p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("scene.image_size"), "{e}");
    }
}
