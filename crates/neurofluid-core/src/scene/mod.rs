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
/// within an image size of the image, a camera-to-world rotation (uniformly scaled) and a
/// position within 10 km of the origin.
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
    let column = |j: usize| [r(0, j), r(1, j), r(2, j)];
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    // a rotation, uniformly scaled as the released scenes' are: columns of one length at right
    // angles (to a tolerance far above float32's rounding)
    let length = |j: usize| dot(column(j), column(j)).sqrt();
    let expected = "a camera-to-world rotation, uniformly scaled (3×3 block of columns of one \
                    length, 10⁻³ to 10³, at right angles)";
    let scale = length(0);
    for j in 0..3 {
        let l = length(j);
        if !((1e-3..=1e3).contains(&l) && (l / scale - 1.0).abs() <= ROTATION_TOLERANCE) {
            return Some((
                "transform_matrix",
                format!("{expected}, found column {j} of length {l:e} (column 0: {scale:e})"),
            ));
        }
        for k in j + 1..3 {
            let cos = dot(column(j), column(k)) / (l * length(k));
            if cos.is_nan() || cos.abs() > ROTATION_TOLERANCE {
                return Some((
                    "transform_matrix",
                    format!("{expected}, found columns {j} and {k} at cosine {cos:e}"),
                ));
            }
        }
    }
    let reach = f64::from(manifest::SCENE_EXTENT);
    if let Some(v) = (0..3)
        .map(|i| r(i, 3))
        .find(|v| v.is_nan() || v.abs() > reach)
    {
        return Some((
            "transform_matrix",
            format!("a camera position within ±{reach} m of the origin, found {v:e}"),
        ));
    }
    None
}

/// Whether two cameras see the same image: the same size, intrinsics and pose (to float32's
/// rounding of a pose written twice).
fn same_camera(a: &Camera, b: &Camera) -> bool {
    let close = |x: f32, y: f32| (x - y).abs() <= 1e-5 * (1.0 + x.abs().max(y.abs()));
    (a.width, a.height) == (b.width, b.height)
        && [(a.fx, b.fx), (a.fy, b.fy), (a.cx, b.cx), (a.cy, b.cy)]
            .iter()
            .all(|&(x, y)| close(x, y))
        && (0..3).all(|i| (0..4).all(|j| close(a.c2w[i][j], b.c2w[i][j])))
}

/// How far a rotation's columns may be from unit length and right angles.
const ROTATION_TOLERANCE: f64 = 1e-2;

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
    /// views, and checks that each has the frames the manifest asks for, that their first
    /// image exists with the size the transforms give, that every frame's camera is one a real
    /// scene has, that no test camera is a training camera, and that the images the roles use
    /// fit `NEUROFLUID_MAX_DATASET_MB` decoded. A scene without images (its particles only: for
    /// DLF rollouts and DLF training) opens where its transforms give the images' size (`w`,
    /// `h`); loading an image it lacks is then the error that names it.
    pub fn open(dir: impl AsRef<Path>) -> Result<Self> {
        let root = dir.as_ref().to_path_buf();
        if !root.is_dir() {
            return Err(SceneError::io(
                &root,
                std::io::Error::new(std::io::ErrorKind::NotFound, "scene directory not found"),
            ));
        }
        let mpath = root.join(MANIFEST_FILE);
        // anything at the manifest's path is read as one (its reader refuses a FIFO or a device)
        let manifest_found = mpath.symlink_metadata().is_ok();
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
                    Some(size) => {
                        // the header against the transforms' size, before any image is decoded
                        let found = png_size(&first)?;
                        if found != size {
                            return Err(SceneError::field(
                                &vs.json_path,
                                "w, h",
                                format!(
                                    "the size of the view's images ({}×{} pixels in {}), found \
                                     {}×{}",
                                    found.0,
                                    found.1,
                                    first.display(),
                                    size.0,
                                    size.1
                                ),
                            ));
                        }
                        found
                    }
                    None => png_size(&first)?,
                };
                splits.insert(key, vs);
            }
        }
        let scene = Self {
            root,
            manifest,
            manifest_found,
            splits,
        };
        crate::limits::check_dataset(
            &format!("the images of {}", scene.root.display()),
            scene.decoded_image_bytes(),
        )
        .map_err(SceneError::Lookup)?;
        // every camera a role uses is one a real scene has (a matter of a few numbers each)
        for role in [Role::Warmup, Role::Train, Role::Test, Role::Validation] {
            for view in scene.views(role) {
                for t in scene.frames(role) {
                    scene.camera(role, view, t)?;
                }
            }
        }
        scene.check_test_views_are_novel()?;
        Ok(scene)
    }

    /// A test view must see the fluid from a camera no training view has: one that is a
    /// training view's camera scores images the model was fitted to as novel views.
    fn check_test_views_are_novel(&self) -> Result<()> {
        let first = |role: Role| self.frames(role).start;
        for test in self.views(Role::Test) {
            let seen = self.camera(Role::Test, test, first(Role::Test))?;
            for train in self.views(Role::Train) {
                let trained = self.camera(Role::Train, train, first(Role::Train))?;
                if same_camera(&seen, &trained) {
                    let split = self.view_split(Role::Test, test)?;
                    return Err(SceneError::field(
                        &split.json_path,
                        format!("frames[{}].transform_matrix", first(Role::Test)),
                        format!(
                            "a test camera apart from the training views' (a novel view), \
                             found the camera of training view {}",
                            crate::paths::shown(train)
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The bytes the images the manifest's roles use take once decoded (each view's frames
    /// counted once, whichever roles use them).
    pub fn decoded_image_bytes(&self) -> u64 {
        let mut frames: BTreeMap<(&str, &str), std::collections::BTreeSet<usize>> = BTreeMap::new();
        for role in [Role::Warmup, Role::Train, Role::Test, Role::Validation] {
            let set = self.manifest.role(role);
            for view in &set.views {
                frames
                    .entry((view.as_str(), set.split.as_str()))
                    .or_default()
                    .extend(set.frames.range());
            }
        }
        frames
            .iter()
            .map(|((view, split), ts)| {
                let (w, h) = self.splits[&(view.to_string(), split.to_string())].image_size;
                ts.len() as u64 * w as u64 * h as u64 * crate::limits::BYTES_PER_PIXEL
            })
            .sum()
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
