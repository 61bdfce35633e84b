//! `view_k/transforms_<split>.json`, the NeRF-synthetic camera file extended with particle paths.
//! The intrinsics are NeRF's `camera_angle_x` or nerfstudio's `fl_x`, `fl_y`, `cx`, `cy`, `w`,
//! `h` (global, or per frame where a frame sets them); a file may hold both.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::error::{Result, SceneError};

/// nerfstudio's pinhole intrinsics (pixels; `cx`, `cy` put pixel i's ray through i + 0.5) and
/// the distortion coefficients of its OpenCV models, which must be zero here.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Focal length along x.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fl_x: Option<f32>,
    /// Focal length along y (`fl_x` when absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fl_y: Option<f32>,
    /// Principal point, x.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cx: Option<f32>,
    /// Principal point, y.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cy: Option<f32>,
    /// Image width.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub w: Option<u32>,
    /// Image height.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub h: Option<u32>,
    /// Radial distortion k1 (must be 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k1: Option<f32>,
    /// Radial distortion k2 (must be 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k2: Option<f32>,
    /// Radial distortion k3 (must be 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k3: Option<f32>,
    /// Radial distortion k4 (must be 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k4: Option<f32>,
    /// Tangential distortion p1 (must be 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub p1: Option<f32>,
    /// Tangential distortion p2 (must be 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub p2: Option<f32>,
}

impl Intrinsics {
    /// Each field of `self`, or `outer`'s where `self` has none.
    pub fn or(self, outer: Intrinsics) -> Intrinsics {
        Intrinsics {
            fl_x: self.fl_x.or(outer.fl_x),
            fl_y: self.fl_y.or(outer.fl_y),
            cx: self.cx.or(outer.cx),
            cy: self.cy.or(outer.cy),
            w: self.w.or(outer.w),
            h: self.h.or(outer.h),
            k1: self.k1.or(outer.k1),
            k2: self.k2.or(outer.k2),
            k3: self.k3.or(outer.k3),
            k4: self.k4.or(outer.k4),
            p1: self.p1.or(outer.p1),
            p2: self.p2.or(outer.p2),
        }
    }

    /// The first invalid field (`prefix` names where it sits) and what was expected.
    fn problem(&self, prefix: &str) -> Option<(String, String)> {
        let positive = [("fl_x", self.fl_x), ("fl_y", self.fl_y)];
        for (key, v) in positive {
            if v.is_some_and(|v| !(v.is_finite() && v > 0.0)) {
                return Some((format!("{prefix}{key}"), "a focal length > 0 pixels".into()));
            }
        }
        for (key, v) in [("cx", self.cx), ("cy", self.cy)] {
            if v.is_some_and(|v| !v.is_finite()) {
                return Some((format!("{prefix}{key}"), "a finite pixel coordinate".into()));
            }
        }
        let distortion = [
            ("k1", self.k1),
            ("k2", self.k2),
            ("k3", self.k3),
            ("k4", self.k4),
            ("p1", self.p1),
            ("p2", self.p2),
        ];
        for (key, v) in distortion {
            if v.is_some_and(|v| v != 0.0) {
                return Some((
                    format!("{prefix}{key}"),
                    "0: lens distortion is not supported (undistort the images first)".into(),
                ));
            }
        }
        None
    }
}

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
    /// This frame's own intrinsics, where it has any.
    #[serde(flatten)]
    pub intrinsics: Intrinsics,
}

/// A parsed `transforms_<split>.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TransformsFile {
    /// Horizontal field of view in radians (NeRF's intrinsics).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_angle_x: Option<f32>,
    /// nerfstudio's intrinsics shared by the frames.
    #[serde(flatten)]
    pub intrinsics: Intrinsics,
    /// Box particle file relative to the scene root, as the released data records it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bounding_box: Option<String>,
    /// The frames in time order.
    pub frames: Vec<FrameEntry>,
}

impl TransformsFile {
    /// Reads and checks `path`.
    pub fn read(path: &Path) -> Result<Self> {
        let text = crate::input_file::read_string(path).map_err(|e| SceneError::io(path, e))?;
        let t: Self = serde_json::from_str(&text).map_err(|e| SceneError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        if let Some(a) = t.camera_angle_x
            && !(a > 0.0 && a < std::f32::consts::PI)
        {
            return Err(SceneError::field(
                path,
                "camera_angle_x",
                format!("an angle in (0, π) radians, got {a}"),
            ));
        }
        if let Some((key, expected)) = t.intrinsics.problem("") {
            return Err(SceneError::field(path, key, expected));
        }
        for (i, f) in t.frames.iter().enumerate() {
            if let Some((key, expected)) = f.intrinsics.problem(&format!("frames[{i}].")) {
                return Err(SceneError::field(path, key, expected));
            }
            if t.camera_angle_x.is_none() && f.intrinsics.or(t.intrinsics).fl_x.is_none() {
                return Err(SceneError::field(
                    path,
                    format!("frames[{i}]"),
                    "intrinsics: `camera_angle_x` or `fl_x` (in the file or the frame)",
                ));
            }
            // the image sits under the view folder, the particles under view/split
            let paths = [
                ("file_path", Some(&f.file_path), 1),
                ("particle_path", f.particle_path.as_ref(), 2),
            ];
            for (key, rel, depth) in paths {
                if let Some(rel) = rel {
                    crate::paths::confined(rel, depth).map_err(|expected| {
                        SceneError::field(path, format!("frames[{i}].{key}"), expected)
                    })?;
                }
            }
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
