//! Extending a generated scene with its warm-up views at every training frame: the images of
//! the NeRF-T baseline (one warm-up view per time step) and of multi-view losses, rendered from
//! the particles the scene already holds, without simulating again.

use std::path::{Path, PathBuf};

use neurofluid_core::scene::{
    MANIFEST_FILE, Particles, SceneError, SceneManifest, TransformsFile, image_path, particle_path,
    transforms_path,
};
use serde::Serialize;
use serde::de::DeserializeOwned;
use serde_json::Value;
use tracing::info;

use crate::generate::{
    Timings, ViewSpec, bar, frame_entry, has_warm_view, render_frame, scene_manifest,
    transforms_file, views,
};
use crate::presets::Preset;

/// What [`render_warmup_frames`] added to a scene.
#[derive(Debug, Clone)]
pub struct WarmupReport {
    /// The scene directory.
    pub out: PathBuf,
    /// Images rendered (0 when the scene already had every warm-up view at every frame).
    pub images: usize,
    /// Frames at which at least one view was rendered.
    pub frames: usize,
    /// Transforms files rewritten.
    pub transforms: usize,
    /// Whether `scene.json` was rewritten (its warm-up frames extended).
    pub manifest: bool,
    /// Seconds spent building fields and rendering.
    pub render_s: f64,
    /// Seconds spent reading particles and writing files.
    pub write_s: f64,
}

/// `x` written as JSON text and parsed back (as a `U`), as a reader of a file `x` was written to
/// gets it: compares exactly with what was read from such a file (an `f32` is written as its
/// shortest text, and serde_json's default float parsing need not give back the very bits that
/// were written).
fn reparsed<T: Serialize, U: DeserializeOwned>(x: &T, path: &Path) -> Result<U, SceneError> {
    let parse_error = |e: serde_json::Error| SceneError::Parse {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    serde_json::to_string(x)
        .and_then(|s| serde_json::from_str(&s))
        .map_err(parse_error)
}

/// Dotted paths of the fields in which `a` and `b` differ (objects compared key by key).
fn differences(a: &Value, b: &Value, prefix: &str, out: &mut Vec<String>) {
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            for k in keys {
                let path = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                match (x.get(k), y.get(k)) {
                    (Some(u), Some(v)) => differences(u, v, &path, out),
                    _ => out.push(path),
                }
            }
        }
        _ if a != b => out.push(prefix.to_string()),
        _ => {}
    }
}

/// Refusal of a manifest that is not the one `generate` writes for `p`.
fn foreign_manifest(path: &Path, p: &Preset, found: &Value, candidates: &[Value]) -> SceneError {
    let diffs = candidates
        .iter()
        .map(|c| {
            let mut d = Vec::new();
            differences(found, c, "", &mut d);
            d
        })
        .min_by_key(Vec::len)
        .unwrap_or_default();
    let hint = if found.get("generator").is_none() {
        " (it has no `generator` settings: not a generated scene)"
    } else {
        ""
    };
    SceneError::field(
        path,
        diffs.join(", "),
        format!(
            "the values `generate` writes for preset `{}` ({}, seed {}){hint}: the folder is not \
             a scene generated from this preset, so its particles cannot be rendered as its views",
            p.name,
            p.scale.name(),
            p.seed
        ),
    )
}

/// Refusal of a warm-up view's transforms file that is not a prefix of the full one.
fn foreign_transforms(path: &Path, found: &TransformsFile, full: &TransformsFile) -> SceneError {
    let head = |t: &TransformsFile| TransformsFile {
        frames: Vec::new(),
        ..t.clone()
    };
    let field = if head(found) != head(full) {
        "camera_angle_x / intrinsics / bounding_box".to_string()
    } else if found.frames.is_empty() || found.frames.len() > full.frames.len() {
        "frames".to_string()
    } else {
        let k = found
            .frames
            .iter()
            .zip(&full.frames)
            .position(|(a, b)| a != b)
            .unwrap_or(0);
        format!("frames[{k}]")
    };
    SceneError::field(
        path,
        field,
        format!(
            "the camera and frames `generate` writes for this view ({} frames from frame 0): \
             not a view of a scene generated from this preset",
            full.frames.len()
        ),
    )
}

/// Adds to the generated scene in `out` the images of every warm-up view (view_1…view_4) at
/// every training frame `0..p.train_frames` that the scene lacks, rendered from the particles
/// the scene stores (`view_1/train/particles/NNNN.npz`) by the very code `generate` renders
/// with; writes each view's particle files beside its images, rewrites the warm-up views'
/// `transforms_train.json` with all their frames, and last rewrites `scene.json` with
/// `warmup.frames = 0..train_frames`. The result is, file for file and byte for byte, the scene
/// `generate` writes with `warmup_every_frame = true`. Every write is atomic and the manifest
/// comes last, so an interrupted run leaves a valid scene whose warm-up frames are still 0..1;
/// running again finishes it. A scene that already has every frame is left untouched (0
/// images).
///
/// The identity check: `scene.json` must equal (as JSON values) the manifest `generate` writes
/// for `p` with `warmup_every_frame` false — a scene to extend — or true — a finished scene; the
/// flag of `p` itself does not matter. The flag is compared only together with the warm-up
/// frame range it produces, because it changes which views were rendered, not what was
/// simulated or how it looks (so are the validation views: the scene's own are kept, whatever
/// `p.validation_views` says); every other preset setting (shape, seed, material, sizes, frame
/// counts, cameras, …) must match, as must each warm-up view's transforms file (a prefix of the
/// full one: the same intrinsics and cameras) and view_1's particle file at every training
/// frame. Anything else is refused before any file is written, with an error naming the file and
/// the differing fields.
pub fn render_warmup_frames(
    p: &Preset,
    out: &Path,
    progress: bool,
) -> Result<WarmupReport, SceneError> {
    let mut time = Timings::default();
    let t_read = std::time::Instant::now();

    // the manifest: the one `generate` writes for this preset, with or without the flag
    let mpath = out.join(MANIFEST_FILE);
    let text = neurofluid_core::input_file::read_string(&mpath).map_err(|e| {
        SceneError::io(
            &mpath,
            std::io::Error::new(
                e.kind(),
                format!(
                    "{e}: not a generated scene (render_warmup_frames extends a scene folder \
                     written by `generate`)"
                ),
            ),
        )
    })?;
    let found: Value = serde_json::from_str(&text).map_err(|e| SceneError::Parse {
        path: mpath.clone(),
        message: e.to_string(),
    })?;
    // the validation views as the scene has them, whatever `p` says (they add views only)
    let validation_views = found.get("validation").is_some_and(|v| !v.is_null());
    let without = Preset {
        warmup_every_frame: false,
        validation_views,
        ..p.clone()
    };
    let with = Preset {
        warmup_every_frame: true,
        ..without.clone()
    };
    let value = |m: SceneManifest| reparsed::<_, Value>(&m, &mpath);
    let target = value(scene_manifest(&with))?;
    let manifest_done = found == target;
    if !manifest_done {
        let before = value(scene_manifest(&without))?;
        if found != before {
            return Err(foreign_manifest(&mpath, p, &found, &[before, target]));
        }
    }

    // the warm-up views' transforms files: each a prefix of the full one
    let (warm, _) = views(p);
    let mut rewrite: Vec<(PathBuf, TransformsFile)> = Vec::new();
    for v in &warm {
        let path = transforms_path(out, &v.name, "train");
        let found = TransformsFile::read(&path)?;
        let entries = (0..p.train_frames)
            .map(|t| frame_entry(v, "train", t))
            .collect();
        let full = transforms_file(p, entries);
        let expected: TransformsFile = reparsed(&full, &path)?;
        let n = found.frames.len();
        let prefix = TransformsFile {
            frames: expected.frames[..n.min(expected.frames.len())].to_vec(),
            ..expected.clone()
        };
        if n == 0 || found != prefix {
            return Err(foreign_transforms(&path, &found, &expected));
        }
        if found != expected {
            rewrite.push((path, full));
        }
    }

    // the source particles (view_1's, as `generate` wrote them) and the missing renders
    let view_dir = |v: &ViewSpec| out.join(&v.name);
    let source = |t: usize| {
        let rel = frame_entry(&warm[0], "train", t).particle_path;
        particle_path(
            &view_dir(&warm[0]),
            "train",
            rel.as_deref().unwrap_or_default(),
        )
    };
    let mut plan: Vec<(usize, Vec<(&ViewSpec, &str)>)> = Vec::new();
    for t in 0..p.train_frames {
        let src = source(t);
        if !src.is_file() {
            return Err(SceneError::io(
                &src,
                std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    format!(
                        "the training view's particles of frame {t} (the source of the warm-up \
                         renders) are missing: not a complete generated scene"
                    ),
                ),
            ));
        }
        let jobs: Vec<(&ViewSpec, &str)> = warm
            .iter()
            .enumerate()
            .filter(|&(i, v)| {
                let e = frame_entry(v, "train", t);
                let rel = e.particle_path.as_deref().unwrap_or_default();
                has_warm_view(&with, i, t)
                    && !(image_path(&view_dir(v), &e).is_file()
                        && particle_path(&view_dir(v), "train", rel).is_file())
            })
            .map(|(_, v)| (v, "train"))
            .collect();
        if !jobs.is_empty() {
            plan.push((t, jobs));
        }
    }
    time.write_s += t_read.elapsed().as_secs_f64();

    // render, then the transforms files, then the manifest
    let pb = bar(plan.len() as u64, "warm-up", progress);
    let mut images = 0;
    for (t, jobs) in &plan {
        let tr = std::time::Instant::now();
        let particles = Particles::read(&source(*t))?;
        time.write_s += tr.elapsed().as_secs_f64();
        images += render_frame(p, out, *t, &particles, jobs, &mut time)?.len();
        pb.inc(1);
    }
    pb.finish_and_clear();
    let tw = std::time::Instant::now();
    for (path, file) in &rewrite {
        file.write(path)?;
    }
    if !manifest_done {
        scene_manifest(&with).write(&mpath)?;
    }
    time.write_s += tw.elapsed().as_secs_f64();
    let report = WarmupReport {
        out: out.to_path_buf(),
        images,
        frames: plan.len(),
        transforms: rewrite.len(),
        manifest: !manifest_done,
        render_s: time.render_s,
        write_s: time.write_s,
    };
    info!(
        images = report.images,
        frames = report.frames,
        render_s = format!("{:.1}", report.render_s),
        write_s = format!("{:.1}", report.write_s),
        "warm-up views at every training frame in {}",
        out.display()
    );
    Ok(report)
}
