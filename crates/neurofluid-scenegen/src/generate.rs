//! Scene generation: simulate the preset, render every view that needs each frame, and write
//! the NeuroFluid layout (`neurofluid_core::scene`).

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::DVec3;
use indicatif::{ProgressBar, ProgressStyle};
use neurofluid_core::camera::{Camera, focal_from_angle_x};
use neurofluid_core::scene::{
    Aabb, BoxParticles, FrameEntry, FrameRange, Intrinsics, MANIFEST_FILE, Particles, SceneError,
    SceneManifest, TransformsFile, UpAxis, ViewSet, transforms_path, write_png_rgba,
};
use rand::{Rng, SeedableRng};
use tracing::info;

use crate::presets::Preset;
use crate::render::field::DensityField;
use crate::render::trace::render;
use crate::sph::{FrameStats, Solver, SolverParams};
use crate::walls::{WALL_SPACING, box_walls};

/// A simulated particle sequence.
#[derive(Debug, Clone)]
pub struct Simulation {
    /// Particles of frames 0, 1, … (frame t at time t/fps).
    pub frames: Vec<Particles>,
    /// The box walls with inward normals.
    pub walls: BoxParticles,
    /// Per-frame solver statistics (entry t describes the step from t to t + 1).
    pub stats: Vec<FrameStats>,
    /// Kinetic energy per unit rest density at each frame (½ Σ V₀|v|²).
    pub kinetic_energy: Vec<f64>,
}

pub(crate) fn bar(len: u64, what: &str, show: bool) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template("{msg:>9} [{bar:30}] {pos}/{len} frames {elapsed}<{eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    pb.set_message(what.to_string());
    pb
}

/// The initial particles of a preset: the shape sampled at 2r with a seeded lattice jitter and
/// a seeded horizontal placement offset.
pub fn initial_particles(p: &Preset) -> Vec<DVec3> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(p.seed);
    let offset = DVec3::new(
        rng.random_range(-0.04..=0.04),
        0.0,
        rng.random_range(-0.04..=0.04),
    );
    p.shape.translated(offset).sample(p.radius, 0.05, &mut rng)
}

/// Simulates `frames` frames of the preset (frame 0 is the initial state).
pub fn simulate(p: &Preset, frames: usize, progress: bool) -> Simulation {
    let pos = initial_particles(p);
    let vel = vec![DVec3::ZERO; pos.len()];
    let walls = box_walls(p.box_lo, p.box_hi, WALL_SPACING);
    let wall_pts: Vec<DVec3> = walls
        .points
        .iter()
        .map(|q| DVec3::from(q.map(f64::from)))
        .collect();
    let params = SolverParams {
        radius: p.radius,
        gravity: [0.0, -p.gravity, 0.0],
        ..Default::default()
    };
    let mut solver = Solver::new(
        pos,
        vel,
        &wall_pts,
        DVec3::from(p.box_lo),
        DVec3::from(p.box_hi),
        p.fluid(),
        params,
    );
    let snapshot = |s: &Solver| Particles {
        pos: s.pos.iter().map(|x| x.as_vec3().to_array()).collect(),
        vel: s.vel.iter().map(|v| v.as_vec3().to_array()).collect(),
    };
    let mut out = vec![snapshot(&solver)];
    let mut energy = vec![solver.kinetic_energy()];
    let mut stats = Vec::new();
    let pb = bar(frames.saturating_sub(1) as u64, "simulate", progress);
    for _ in 1..frames {
        let s = solver.advance(1.0 / p.fps);
        stats.push(s);
        out.push(snapshot(&solver));
        energy.push(solver.kinetic_energy());
        pb.inc(1);
    }
    pb.finish_and_clear();
    Simulation {
        frames: out,
        walls,
        stats,
        kinetic_energy: energy,
    }
}

/// A camera on the ring around the box.
#[derive(Debug, Clone)]
pub struct ViewSpec {
    /// Directory name, `view_k`.
    pub name: String,
    /// Azimuth around the up axis (degrees).
    pub azimuth_deg: f32,
    /// The camera.
    pub camera: Camera,
}

/// Ring geometry: look-at target, distance, and near/far bracketing the whole box.
#[derive(Debug, Clone, Copy)]
pub struct Ring {
    /// Point the cameras look at.
    pub target: [f32; 3],
    /// Camera distance from the target.
    pub distance: f32,
    /// Near bound.
    pub near: f32,
    /// Far bound.
    pub far: f32,
}

/// The camera ring of a preset: the lower 55 % of the box (where the fluid lives) fills the
/// field of view; near/far bracket the whole box.
pub fn ring(p: &Preset) -> Ring {
    let lo = DVec3::from(p.box_lo);
    let hi = DVec3::from(p.box_hi);
    let height = hi.y - lo.y;
    let fit_hi = DVec3::new(hi.x, lo.y + 0.55 * height, hi.z);
    let target = DVec3::new(
        0.5 * (lo.x + hi.x),
        lo.y + 0.27 * height,
        0.5 * (lo.z + hi.z),
    );
    let corners = |a: DVec3, b: DVec3| {
        (0..8).map(move |c| {
            DVec3::new(
                if c & 1 == 0 { a.x } else { b.x },
                if c & 2 == 0 { a.y } else { b.y },
                if c & 4 == 0 { a.z } else { b.z },
            )
        })
    };
    let r_fit = corners(lo, fit_hi)
        .map(|c| (c - target).length())
        .fold(0.0, f64::max);
    let r_all = corners(lo, hi)
        .map(|c| (c - target).length())
        .fold(0.0, f64::max);
    let half = 0.5 * p.camera_angle_x as f64;
    let distance = (r_fit / half.sin()).max(r_all * 1.05);
    Ring {
        target: target.as_vec3().to_array(),
        distance: distance as f32,
        near: (distance - r_all) as f32,
        far: (distance + r_all) as f32,
    }
}

/// The view `view_{k}` on the preset's ring at azimuth `az` degrees (at the ring's elevation).
fn ring_view(p: &Preset, k: usize, az: f32) -> ViewSpec {
    let rg = ring(p);
    let el = p.elevation_deg.to_radians();
    let a = az.to_radians();
    let t = glam::Vec3::from(rg.target);
    let eye = t + rg.distance * glam::Vec3::new(el.cos() * a.sin(), el.sin(), el.cos() * a.cos());
    ViewSpec {
        name: format!("view_{k}"),
        azimuth_deg: az,
        camera: Camera::look_at(
            p.image_size,
            p.image_size,
            p.camera_angle_x,
            eye.to_array(),
            rg.target,
            [0.0, 1.0, 0.0],
        ),
    }
}

/// Azimuths (degrees) of the warm-up views view_1…view_4.
const WARM_AZIMUTHS: [f32; 4] = [30.0, 120.0, 210.0, 300.0];

/// Azimuth (degrees) of test view `i` of `n`.
fn test_azimuth(i: usize, n: usize) -> f32 {
    75.0 + 360.0 * i as f32 / n as f32
}

/// The validation views' azimuths for `test_views` test views: the midpoints between
/// neighbouring warm-up azimuths (75°, 165°, 255°, 345°; the first test view sits on 75°) that
/// no test view takes (none within 1°), in increasing order.
pub fn validation_azimuths(test_views: usize) -> Vec<f32> {
    let taken = |az: f32| {
        (0..test_views).any(|i| {
            let d = (test_azimuth(i, test_views) - az).rem_euclid(360.0);
            d.min(360.0 - d) < 1.0
        })
    };
    WARM_AZIMUTHS
        .iter()
        .map(|a| a + 45.0)
        .filter(|&az| !taken(az))
        .collect()
}

/// Warm-up views (view_1…view_4, view_1 also trains) and test views (view_5, …).
pub fn views(p: &Preset) -> (Vec<ViewSpec>, Vec<ViewSpec>) {
    let warm = WARM_AZIMUTHS
        .iter()
        .enumerate()
        .map(|(i, &az)| ring_view(p, i + 1, az))
        .collect();
    let test = (0..p.test_views)
        .map(|i| ring_view(p, 5 + i, test_azimuth(i, p.test_views)))
        .collect();
    (warm, test)
}

/// The validation views of a preset with `validation_views` (none without): on the ring, where
/// the built-in test views sit, at [`validation_azimuths`], named after the test views
/// (`view_{5 + test_views}`, …). What the test view measures, at azimuths it does not take.
pub fn validation_views(p: &Preset) -> Vec<ViewSpec> {
    if !p.validation_views {
        return Vec::new();
    }
    validation_azimuths(p.test_views)
        .into_iter()
        .enumerate()
        .map(|(i, az)| ring_view(p, 5 + p.test_views + i, az))
        .collect()
}

/// What a generation run produced and how long it took.
#[derive(Debug, Clone)]
pub struct Report {
    /// The scene directory.
    pub out: PathBuf,
    /// Fluid particles.
    pub particles: usize,
    /// Wall particles.
    pub wall_particles: usize,
    /// Simulated frames.
    pub frames: usize,
    /// Images written.
    pub images: usize,
    /// Their width and height in pixels.
    pub image_size: u32,
    /// Seconds spent simulating.
    pub simulate_s: f64,
    /// Seconds spent building fields and rendering.
    pub render_s: f64,
    /// Seconds spent writing files.
    pub write_s: f64,
    /// Total solver substeps.
    pub substeps: usize,
    /// Total position clamps at the walls (safety net, ideally 0).
    pub clamped: usize,
}

impl std::fmt::Display for Report {
    /// One line: what was written, where, and the time of each phase.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} particles, {} wall particles, {} frames ({} substeps, {} clamps), {} images of \
             {}×{} → {} [simulate {:.1} s, render {:.1} s, write {:.1} s]",
            self.particles,
            self.wall_particles,
            self.frames,
            self.substeps,
            self.clamped,
            self.images,
            self.image_size,
            self.image_size,
            self.out.display(),
            self.simulate_s,
            self.render_s,
            self.write_s
        )
    }
}

/// Seconds spent rendering (density fields and rays) and writing files.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Timings {
    /// Building density fields and rendering.
    pub render_s: f64,
    /// Writing images and particle files.
    pub write_s: f64,
}

/// The file stem of frame `t` (`0007`).
fn frame_stem(t: usize) -> String {
    format!("{t:04}")
}

/// Whether a scene of preset `p` holds warm-up view `i` (0: view_1, which also trains) at frame
/// `t`: every warm-up view at frame 0, view_1 at every training frame, and with
/// `warmup_every_frame` every warm-up view at every training frame.
pub(crate) fn has_warm_view(p: &Preset, i: usize, t: usize) -> bool {
    t == 0 || ((i == 0 || p.warmup_every_frame) && t < p.train_frames)
}

/// The transforms entry of view `v` at frame `t` of `split`.
pub(crate) fn frame_entry(v: &ViewSpec, split: &str, t: usize) -> FrameEntry {
    let name = frame_stem(t);
    FrameEntry {
        file_path: format!("{split}/{name}"),
        transform_matrix: v.camera.c2w,
        particle_path: Some(format!("particles/{name}.npz")),
        intrinsics: Intrinsics::default(),
    }
}

/// The transforms file of one view of the preset holding `frames`.
pub(crate) fn transforms_file(p: &Preset, frames: Vec<FrameEntry>) -> TransformsFile {
    // NeRF's and nerfstudio's intrinsics of the same camera (nerfstudio's principal point sits
    // on pixel centres)
    let size = p.image_size;
    let focal = focal_from_angle_x(size, p.camera_angle_x);
    TransformsFile {
        camera_angle_x: Some(p.camera_angle_x),
        intrinsics: Intrinsics {
            fl_x: Some(focal),
            fl_y: Some(focal),
            cx: Some(size as f32 / 2.0 + 0.5),
            cy: Some(size as f32 / 2.0 + 0.5),
            w: Some(size),
            h: Some(size),
            ..Intrinsics::default()
        },
        bounding_box: Some("box.pt".into()),
        frames,
    }
}

/// The manifest of a scene generated from `p` (its warm-up frames are 0..1, or every training
/// frame with `warmup_every_frame`; `generator` holds the preset's serialisation).
pub fn scene_manifest(p: &Preset) -> SceneManifest {
    let (warm, test) = views(p);
    let validation = validation_views(p);
    let rg = ring(p);
    let r = p.radius as f32;
    SceneManifest {
        name: p.name.clone(),
        up_axis: UpAxis::Y,
        particle_radius: r,
        fps: p.fps as f32,
        warmup: ViewSet {
            views: warm.iter().map(|v| v.name.clone()).collect(),
            split: "train".into(),
            frames: FrameRange {
                start: 0,
                end: if p.warmup_every_frame {
                    p.train_frames
                } else {
                    1
                },
            },
        },
        train: ViewSet {
            views: vec![warm[0].name.clone()],
            split: "train".into(),
            frames: FrameRange {
                start: 0,
                end: p.train_frames,
            },
        },
        test: ViewSet {
            views: test.iter().map(|v| v.name.clone()).collect(),
            split: "test".into(),
            frames: FrameRange {
                start: 0,
                end: p.test_frames,
            },
        },
        validation: (!validation.is_empty()).then(|| ViewSet {
            views: validation.iter().map(|v| v.name.clone()).collect(),
            split: "test".into(),
            frames: FrameRange {
                start: 0,
                end: p.test_frames,
            },
        }),
        box_file: "box.npz".into(),
        box_interior: Aabb {
            min: p.box_lo.map(|v| v as f32 + r),
            max: p.box_hi.map(|v| v as f32 - r),
        },
        near: rg.near,
        far: rg.far,
        generator: serde_json::to_value(p).ok(),
    }
}

/// Renders frame `t` (its particles `particles`) from each `(view, split)` of `jobs` and writes
/// `view/split/NNNN.png` and the frame's particles `view/split/particles/NNNN.npz`; returns the
/// views' transforms entries in the order of `jobs`. The frame's density field is built once
/// and shared by its views. This is the one way the generator renders a view at a frame:
/// [`generate`] and [`crate::warmup::render_warmup_frames`] both call it.
pub(crate) fn render_frame(
    p: &Preset,
    out: &Path,
    t: usize,
    particles: &Particles,
    jobs: &[(&ViewSpec, &str)],
    time: &mut Timings,
) -> Result<Vec<FrameEntry>, SceneError> {
    if jobs.is_empty() {
        return Ok(Vec::new());
    }
    let volume = (2.0 * p.radius as f32).powi(3);
    let support = p.surface_support * p.radius as f32;
    let tr = Instant::now();
    let field = DensityField::build(&particles.pos, volume, support, p.voxel, p.iso);
    let rendered: Vec<Vec<u8>> = jobs
        .iter()
        .map(|(v, _)| render(&v.camera, &field, p.appearance, p.samples_per_axis))
        .collect();
    time.render_s += tr.elapsed().as_secs_f64();
    let tw = Instant::now();
    let name = frame_stem(t);
    let mut entries = Vec::with_capacity(jobs.len());
    for ((v, split), rgba) in jobs.iter().zip(rendered) {
        let dir = out.join(&v.name).join(split);
        write_png_rgba(
            &dir.join(format!("{name}.png")),
            p.image_size,
            p.image_size,
            &rgba,
        )?;
        particles.write(&dir.join("particles").join(format!("{name}.npz")))?;
        entries.push(frame_entry(v, split, t));
    }
    time.write_s += tw.elapsed().as_secs_f64();
    Ok(entries)
}

/// Generates the preset into `out` (created if needed): simulation, renders, particles,
/// transforms, box and manifest. Existing files of the same names are replaced atomically.
/// With `p.warmup_every_frame` every warm-up view is rendered at every training frame, in the
/// same frame loop: the same files as generating without it and then
/// [`crate::render_warmup_frames`]. With `p.validation_views` the validation views are rendered
/// beside the test views; every other file is the same.
pub fn generate(p: &Preset, out: &Path, progress: bool) -> Result<Report, SceneError> {
    std::fs::create_dir_all(out).map_err(|e| SceneError::io(out, e))?;
    let n_frames = p.train_frames.max(p.test_frames);
    info!(scene = %p.name, scale = p.scale.name(), frames = n_frames, "simulating");
    let t0 = Instant::now();
    let sim = simulate(p, n_frames, progress);
    let simulate_s = t0.elapsed().as_secs_f64();
    let (warm, mut test) = views(p);
    // the validation views render and write as test views do (split `test`, the test frames)
    test.extend(validation_views(p));

    let mut time = Timings::default();
    let mut images = 0;
    let pb = bar(n_frames as u64, "render", progress);
    let mut warm_frames: Vec<Vec<FrameEntry>> = vec![Vec::new(); warm.len()];
    let mut test_frames: Vec<Vec<FrameEntry>> = vec![Vec::new(); test.len()];
    for (t, particles) in sim.frames.iter().enumerate() {
        // (view, split) to render, and where its entry goes (warm-up or test view i)
        let mut jobs: Vec<(&ViewSpec, &str)> = Vec::new();
        let mut slots: Vec<(bool, usize)> = Vec::new();
        for (i, v) in warm.iter().enumerate() {
            if has_warm_view(p, i, t) {
                jobs.push((v, "train"));
                slots.push((true, i));
            }
        }
        for (i, v) in test.iter().enumerate() {
            if t < p.test_frames {
                jobs.push((v, "test"));
                slots.push((false, i));
            }
        }
        let entries = render_frame(p, out, t, particles, &jobs, &mut time)?;
        images += entries.len();
        for ((is_warm, i), entry) in slots.into_iter().zip(entries) {
            if is_warm {
                warm_frames[i].push(entry);
            } else {
                test_frames[i].push(entry);
            }
        }
        pb.inc(1);
    }
    pb.finish_and_clear();

    let tw = Instant::now();
    for (specs, frames, split) in [(&warm, warm_frames, "train"), (&test, test_frames, "test")] {
        for (v, frames) in specs.iter().zip(frames) {
            transforms_file(p, frames).write(&transforms_path(out, &v.name, split))?;
        }
    }
    sim.walls.write(&out.join("box.npz"))?;
    sim.walls.write_pickle(&out.join("box.pt"))?;
    scene_manifest(p).write(&out.join(MANIFEST_FILE))?;
    let render_s = time.render_s;
    let write_s = time.write_s + tw.elapsed().as_secs_f64();
    let report = Report {
        out: out.to_path_buf(),
        particles: sim.frames[0].len(),
        wall_particles: sim.walls.len(),
        frames: n_frames,
        images,
        image_size: p.image_size,
        simulate_s,
        render_s,
        write_s,
        substeps: sim.stats.iter().map(|s| s.substeps).sum(),
        clamped: sim.stats.iter().map(|s| s.clamped).sum(),
    };
    info!(
        particles = report.particles,
        images = report.images,
        simulate_s = format!("{:.1}", report.simulate_s),
        render_s = format!("{:.1}", report.render_s),
        write_s = format!("{:.1}", report.write_s),
        clamped = report.clamped,
        "scene written to {}",
        out.display()
    );
    Ok(report)
}
