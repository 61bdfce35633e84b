//! NeuroFluid's scene layout (spec §5.1), read and written:
//!
//! ```text
//! <scene>/scene.json                        manifest (optional; released-layout defaults)
//! <scene>/box.npz                           {box, box_normals} (N_b×3, inward unit normals)
//! <scene>/box.pt                            the same as a plain pickle (the released name; written, not read)
//! <scene>/view_k/transforms_<split>.json    camera_angle_x and/or fl_x, fl_y, cx, cy, w, h; frames[] {file_path, transform_matrix, particle_path, intrinsics?}
//! <scene>/view_k/<split>/NNNN.png           RGBA frames
//! <scene>/view_k/<split>/particles/NNNN.npz {pos, vel} (N×3, float32 or float64)
//! ```
//!
//! [`Scene::open`] parses the manifest and every transforms file it names and checks that the
//! frames exist; images, particles and the box are read on demand. Every missing file or field
//! is an error naming the path and the field. Writers are atomic (temporary file + rename).

mod error;
mod image;
mod manifest;
mod particles;
mod pickle;
mod transforms;
mod unpickle;

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::{Path, PathBuf};

pub use error::{Result, SceneError};
pub use image::{Image, png_size, write_png_rgba};
pub use manifest::{Aabb, FrameRange, MANIFEST_FILE, Role, SceneManifest, UpAxis, ViewSet};
pub use particles::{BoxParticles, Particles};
pub use pickle::box_pickle;
pub use transforms::{FrameEntry, Intrinsics, TransformsFile, image_path, particle_path};

use crate::camera::{Camera, focal_from_angle_x};

/// Path of `view/transforms_<split>.json` under a scene root.
pub fn transforms_path(root: &Path, view: &str, split: &str) -> PathBuf {
    root.join(view).join(format!("transforms_{split}.json"))
}

/// One parsed `view_k/transforms_<split>.json` with the size of its images.
#[derive(Debug, Clone)]
pub struct ViewSplit {
    /// View directory name (`view_1`).
    pub view: String,
    /// Split name (`train`, `test`).
    pub split: String,
    /// The view directory.
    pub dir: PathBuf,
    /// The transforms file.
    pub json_path: PathBuf,
    /// The parsed transforms file.
    pub transforms: TransformsFile,
    /// Image width and height (from the first used frame's PNG header).
    pub image_size: (u32, u32),
}

impl ViewSplit {
    fn entry(&self, t: usize) -> Result<&FrameEntry> {
        self.transforms.frames.get(t).ok_or_else(|| {
            SceneError::field(
                &self.json_path,
                "frames",
                format!(
                    "at least {} frames, found {}",
                    t + 1,
                    self.transforms.frames.len()
                ),
            )
        })
    }

    /// Camera of frame `t`: the frame's intrinsics, else the file's (nerfstudio's `fl_x` …
    /// before `camera_angle_x`), at the size of the view's images.
    pub fn camera(&self, t: usize) -> Result<Camera> {
        let e = self.entry(t)?;
        let (w, h) = self.image_size;
        let k = e.intrinsics.or(self.transforms.intrinsics);
        for (key, size, image) in [("w", k.w, w), ("h", k.h, h)] {
            if let Some(size) = size.filter(|&s| s != image) {
                return Err(SceneError::field(
                    &self.json_path,
                    key,
                    format!("the size of the view's images ({image} pixels), found {size}"),
                ));
            }
        }
        let fx = match (k.fl_x, self.transforms.camera_angle_x) {
            (Some(f), _) => f,
            (None, Some(a)) => focal_from_angle_x(w, a),
            (None, None) => {
                return Err(SceneError::field(
                    &self.json_path,
                    format!("frames[{t}]"),
                    "intrinsics: `camera_angle_x` or `fl_x`",
                ));
            }
        };
        let camera = Camera {
            width: w,
            height: h,
            fx,
            fy: k.fl_y.unwrap_or(fx),
            // nerfstudio's principal point is at pixel centres (+0.5), ours at pixel corners
            cx: k.cx.map_or(w as f32 / 2.0, |c| c - 0.5),
            cy: k.cy.map_or(h as f32 / 2.0, |c| c - 0.5),
            c2w: e.transform_matrix,
        };
        degenerate(&camera).map_or(Ok(camera), |(field, expected)| {
            Err(SceneError::field(
                &self.json_path,
                format!("frames[{t}]: {field}"),
                expected,
            ))
        })
    }

    /// The images' size that the transforms give for frame `t` (nerfstudio's `w` and `h`).
    fn declared_size(&self, t: usize) -> Option<(u32, u32)> {
        let e = self.entry(t).ok()?;
        let k = e.intrinsics.or(self.transforms.intrinsics);
        k.w.zip(k.h)
    }

    /// An image of this view must have the size of its first one (the camera's).
    fn check_size(&self, path: &Path, size: (u32, u32)) -> Result<()> {
        let (w, h) = self.image_size;
        if size == (w, h) {
            return Ok(());
        }
        Err(SceneError::field(
            path,
            "size",
            format!(
                "{w}×{h} pixels like the view's first image (its camera), found {}×{}",
                size.0, size.1
            ),
        ))
    }

    /// Image path of frame `t`.
    pub fn image_path(&self, t: usize) -> Result<PathBuf> {
        Ok(image_path(&self.dir, self.entry(t)?))
    }

    /// Particle file path of frame `t`.
    pub fn particle_path(&self, t: usize) -> Result<PathBuf> {
        let e = self.entry(t)?;
        let rel = e.particle_path.as_deref().ok_or_else(|| {
            SceneError::field(
                &self.json_path,
                format!("frames[{t}].particle_path"),
                "a particle file path",
            )
        })?;
        Ok(particle_path(&self.dir, &self.split, rel))
    }
}

/// The first field of `c` no real camera has, and what was expected: a focal length between
/// 1/1000 and 10 000 image widths (fields of view from 0.006° to 179.9°), the principal point
/// within an image size of the image, and a camera-to-world rotation that is invertible.
fn degenerate(c: &Camera) -> Option<(&'static str, String)> {
    let size = c.width.max(c.height) as f32;
    let (lo, hi) = (size * 1e-3, size * 1e4);
    for (field, f) in [("fl_x", c.fx), ("fl_y", c.fy)] {
        if !(lo..=hi).contains(&f) {
            return Some((
                field,
                format!(
                    "a focal length from {lo} to {hi} pixels for {size}-pixel images, found {f}"
                ),
            ));
        }
    }
    for (field, p, n) in [("cx", c.cx, c.width), ("cy", c.cy, c.height)] {
        let n = n as f32;
        if !(-n..=2.0 * n).contains(&p) {
            return Some((
                field,
                format!(
                    "a principal point from {} to {} pixels, found {p}",
                    -n,
                    2.0 * n
                ),
            ));
        }
    }
    let r = |i: usize, j: usize| c.c2w[i][j] as f64;
    let det = r(0, 0) * (r(1, 1) * r(2, 2) - r(1, 2) * r(2, 1))
        - r(0, 1) * (r(1, 0) * r(2, 2) - r(1, 2) * r(2, 0))
        + r(0, 2) * (r(1, 0) * r(2, 1) - r(1, 1) * r(2, 0));
    // scale-free: the volume of the unit columns (1 for a rotation, 0 for a flat matrix)
    let norm = |j: usize| (r(0, j).powi(2) + r(1, j).powi(2) + r(2, j).powi(2)).sqrt();
    let volume = det.abs() / (norm(0) * norm(1) * norm(2));
    if volume.is_nan() || volume <= 1e-3 {
        return Some((
            "transform_matrix",
            format!(
                "an invertible camera-to-world rotation (3×3 block of independent columns), \
                 found determinant {det:e}"
            ),
        ));
    }
    None
}

/// An opened scene directory.
#[derive(Debug, Clone)]
pub struct Scene {
    root: PathBuf,
    manifest: SceneManifest,
    manifest_found: bool,
    splits: BTreeMap<(String, String), ViewSplit>,
}

impl Scene {
    /// Opens the scene at `dir`: reads `scene.json` (or uses the released-layout defaults named
    /// after the directory), parses every transforms file of the warm-up, training and test
    /// views, and checks that each has the frames the manifest asks for and that their first
    /// image exists. A scene without images (its particles only: for DLF rollouts and DLF
    /// training) opens where its transforms give the images' size (`w`, `h`); loading an image
    /// it lacks is then the error that names it.
    pub fn open(dir: impl AsRef<Path>) -> Result<Self> {
        let root = dir.as_ref().to_path_buf();
        if !root.is_dir() {
            return Err(SceneError::io(
                &root,
                std::io::Error::new(std::io::ErrorKind::NotFound, "scene directory not found"),
            ));
        }
        let mpath = root.join(MANIFEST_FILE);
        let manifest_found = mpath.is_file();
        let manifest = if manifest_found {
            SceneManifest::read(&mpath)?
        } else {
            let name = root
                .canonicalize()
                .ok()
                .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
                .unwrap_or_else(|| "scene".into());
            SceneManifest::released(&name)
        };
        let mut splits = BTreeMap::new();
        for role in [Role::Warmup, Role::Train, Role::Test, Role::Validation] {
            let set = manifest.role(role).clone();
            for view in &set.views {
                let key = (view.clone(), set.split.clone());
                let needed = set.frames.end;
                if let Some(vs) = splits.get(&key) {
                    let vs: &ViewSplit = vs;
                    vs.entry(needed - 1)?;
                    continue;
                }
                let json_path = transforms_path(&root, view, &set.split);
                let transforms = TransformsFile::read(&json_path)?;
                let mut vs = ViewSplit {
                    view: view.clone(),
                    split: set.split.clone(),
                    dir: root.join(view),
                    json_path,
                    transforms,
                    image_size: (0, 0),
                };
                vs.entry(needed - 1)?;
                let first = vs.image_path(set.frames.start)?;
                vs.image_size = match vs.declared_size(set.frames.start) {
                    Some(size) if !first.exists() => size,
                    _ => png_size(&first)?,
                };
                splits.insert(key, vs);
            }
        }
        Ok(Self {
            root,
            manifest,
            manifest_found,
            splits,
        })
    }

    /// The scene root.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The manifest (read from `scene.json` or the released-layout defaults).
    pub fn manifest(&self) -> &SceneManifest {
        &self.manifest
    }

    /// True when the manifest came from `scene.json` rather than the defaults.
    pub fn has_manifest_file(&self) -> bool {
        self.manifest_found
    }

    /// The up axis.
    pub fn up_axis(&self) -> UpAxis {
        self.manifest.up_axis
    }

    /// Views of a role.
    pub fn views(&self, role: Role) -> &[String] {
        &self.manifest.role(role).views
    }

    /// Frames of a role, as positions in its transforms files.
    pub fn frames(&self, role: Role) -> Range<usize> {
        self.manifest.role(role).frames.range()
    }

    /// All parsed view/split files, ordered by view then split.
    pub fn view_splits(&self) -> impl Iterator<Item = &ViewSplit> {
        self.splits.values()
    }

    /// The parsed transforms of `view` in the split of `role`.
    pub fn view_split(&self, role: Role, view: &str) -> Result<&ViewSplit> {
        let split = &self.manifest.role(role).split;
        self.splits
            .get(&(view.to_string(), split.clone()))
            .ok_or_else(|| {
                SceneError::Lookup(format!(
                    "{}: view `{view}` (split `{split}`) is not one of the scene's {role:?} views {:?}",
                    self.root.display(),
                    self.views(role)
                ))
            })
    }

    /// Camera of `view` at frame `t` in the split of `role`.
    pub fn camera(&self, role: Role, view: &str, t: usize) -> Result<Camera> {
        self.view_split(role, view)?.camera(t)
    }

    /// Image of `view` at frame `t`, composited on white. Every image of a view has the size
    /// of the view's first image (its camera's).
    pub fn image(&self, role: Role, view: &str, t: usize) -> Result<Image> {
        let split = self.view_split(role, view)?;
        let path = split.image_path(t)?;
        // the header's size first: a mismatched image is refused before it is decoded
        split.check_size(&path, png_size(&path)?)?;
        let image = Image::read(&path)?;
        split.check_size(&path, (image.width, image.height))?;
        Ok(image)
    }

    /// Particles at frame `t` of `role` (from the role's first view, as the reference loader).
    pub fn particles(&self, role: Role, t: usize) -> Result<Particles> {
        let view = &self.views(role)[0];
        Particles::read(&self.view_split(role, view)?.particle_path(t)?)
    }

    /// Particles of every frame of `role`'s frame range, in order.
    pub fn particle_sequence(&self, role: Role) -> Result<Vec<Particles>> {
        self.frames(role).map(|t| self.particles(role, t)).collect()
    }

    /// Path of the box particle file.
    pub fn box_path(&self) -> PathBuf {
        self.root.join(&self.manifest.box_file)
    }

    /// The static box particles with inward normals.
    pub fn boundary(&self) -> Result<BoxParticles> {
        BoxParticles::read(&self.box_path())
    }
}
