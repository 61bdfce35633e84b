//! `view_k/transforms_<split>.json`, the NeRF-synthetic camera file extended with particle paths.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::error::{Result, SceneError};

/// One frame of a transforms file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameEntry {
    /// Image path relative to the view directory, without `.png` (e.g. `train/0001`).
    pub file_path: String,
    /// Camera-to-world 4×4 (Blender/OpenGL axes), row-major.
    pub transform_matrix: [[f32; 4]; 4],
    /// Particle file relative to `view_k/<split>/` (e.g. `particles/0001.npz`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub particle_path: Option<String>,
}

/// A parsed `transforms_<split>.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TransformsFile {
    /// Horizontal field of view in radians.
    pub camera_angle_x: f32,
    /// Box particle file relative to the scene root, as the released data records it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bounding_box: Option<String>,
    /// The frames in time order.
    pub frames: Vec<FrameEntry>,
}

impl TransformsFile {
    /// Reads and checks `path`.
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| SceneError::io(path, e))?;
        let t: Self = serde_json::from_str(&text).map_err(|e| SceneError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        if !(t.camera_angle_x > 0.0 && t.camera_angle_x < std::f32::consts::PI) {
            return Err(SceneError::field(
                path,
                "camera_angle_x",
                format!("an angle in (0, π) radians, got {}", t.camera_angle_x),
            ));
        }
        for (i, f) in t.frames.iter().enumerate() {
            if f.transform_matrix.iter().flatten().any(|v| !v.is_finite()) {
                return Err(SceneError::field(
                    path,
                    format!("frames[{i}].transform_matrix"),
                    "finite numbers",
                ));
            }
        }
        Ok(t)
    }

    /// Writes the file atomically (pretty JSON).
    pub fn write(&self, path: &Path) -> Result<()> {
        let mut text = serde_json::to_string_pretty(self).map_err(|e| SceneError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        text.push('\n');
        crate::atomic::write_bytes(path, text.as_bytes()).map_err(|e| SceneError::io(path, e))
    }
}

/// Resolves a frame's image path: `view_dir/file_path` with a leading `./` dropped and `.png`
/// appended unless present.
pub fn image_path(view_dir: &Path, entry: &FrameEntry) -> PathBuf {
    let rel = entry.file_path.trim_start_matches("./");
    let mut p = view_dir.join(rel);
    if p.extension().is_none_or(|e| e != "png") {
        let mut s = p.into_os_string();
        s.push(".png");
        p = PathBuf::from(s);
    }
    p
}

/// Resolves a frame's particle path: `view_dir/<split>/particle_path`.
pub fn particle_path(view_dir: &Path, split: &str, rel: &str) -> PathBuf {
    view_dir.join(split).join(rel.trim_start_matches("./"))
}
