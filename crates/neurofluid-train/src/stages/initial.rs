//! Initial particles from images (NeuroFluid, Table 5 row 2): a NeRF trained on the warm-up
//! views of frame 0, its density sampled on a grid over the box, the surface extracted by
//! marching cubes and the enclosed volume filled with particles on DLF's 2r lattice, at rest.
//! Writes `initial/particles.npz` (the frame-0 state the later stages start from), the surface
//! (`surface.ply`), a picture beside the truth and `initial.json` with how far the result is
//! from the true particles.

use std::path::PathBuf;

use anyhow::Context;
use neurofluid_core::camera::Camera;
use neurofluid_core::metrics::gt_to_pred_distance;
use neurofluid_core::scene::{Image, Particles, Role};
use serde::{Deserialize, Serialize};

use super::nerf::{self, NerfKind};
use super::run_folder::Run;
use super::views::load_particles;
use crate::config::{InitialParticles, Settings, SurfaceThreshold};
use crate::stage::Stage;
use neurofluid_outputs::geometry::silhouette_iso::{Coverage, silhouette_iso, usable_views};
use neurofluid_outputs::geometry::volume_fill::{DensityGrid, FillSettings, surface_and_fill};
use neurofluid_outputs::metrics_log::MetricsLog;
use neurofluid_outputs::scoring::{at_least_wide, particle_row};

/// Folder of the recovered initial state inside the run folder.
pub const STAGE: Stage = Stage::Initial;
/// The recovered frame-0 particles.
pub const PARTICLES_FILE: &str = "particles.npz";
/// What was recovered and how far it is from the truth.
pub const REPORT_FILE: &str = "initial.json";

/// How the recovered initial particles compare with the true ones.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InitialReport {
    /// Recovered particles.
    pub particles: usize,
    /// True particles of frame 0.
    pub true_particles: usize,
    /// d (× 1000): mean distance from each true particle to the nearest recovered one.
    pub d: f64,
    /// The same from each recovered particle to the nearest true one (false fluid).
    pub d_reverse: f64,
    /// Volume enclosed by the surface (world units³).
    pub surface_volume: f64,
    /// The true particles' volume, count × (2r)³.
    pub true_volume: f64,
    /// Connected bodies found above the threshold (before keeping the largest).
    pub components: usize,
    /// The density threshold σ_iso.
    pub iso: f64,
    /// With `initial.threshold = "silhouette"`: the chosen iso's mean intersection over union
    /// with the warm-up views' coverage.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub silhouette_iou: Option<f64>,
    /// The grid spacing of the density samples.
    pub cell: f64,
    /// Digest of the settings it was made with (`[nerf]`, `[initial]`, seed, scene).
    pub settings: String,
}

impl InitialReport {
    /// A one-line summary.
    pub fn line(&self) -> String {
        format!(
            "initial particles from images: {} (truth {}), d {:.2}, reverse d {:.2}, surface \
             volume {:.4} (truth {:.4}), {} bodies above σ = {:.1}",
            self.particles,
            self.true_particles,
            self.d,
            self.d_reverse,
            self.surface_volume,
            self.true_volume,
            self.components,
            self.iso
        ) + &self
            .silhouette_iou
            .map(|iou| format!(" (the views' silhouettes matched at IoU {iou:.3})"))
            .unwrap_or_default()
    }
}

/// The recovered particles' file of `run`.
pub fn particles_path(run: &Run) -> PathBuf {
    run.stage_dir(STAGE).join(PARTICLES_FILE)
}

/// The particles the stages start from at frame `t`: the recovered ones when the experiment
/// asks for initial particles from images (for the first frame), else the scene's.
pub fn starting_particles(
    run: &Run,
    role: Role,
    t: usize,
    what: &str,
) -> anyhow::Result<Particles> {
    let first = run.scene.frames(Role::Warmup).start;
    if run.exp.scene.initial == InitialParticles::FromImages && t == first {
        let path = particles_path(run);
        let p = Particles::read(&path).with_context(|| {
            format!(
                "{what}: the initial particles from images, {}: run `init-particles` first",
                path.display()
            )
        })?;
        super::views::check_particles(&p, what)?;
        return Ok(p);
    }
    load_particles(&run.scene, role, t, what)
}

/// The digest of what the recovery depends on: the NeRF's settings and `[initial]`.
fn settings_digest(run: &Run) -> String {
    let mut s = run.settings(Stage::Nerf);
    s.0.extend(
        Settings::all(&run.exp)
            .0
            .into_iter()
            .filter(|(k, _)| k.starts_with("initial.") || k == "nerf.iters"),
    );
    s.digest()
}

/// Trains (or resumes) the NeRF of frame 0 and recovers the initial particles, unless they were
/// recovered before.
pub fn recover(run: &Run, log: &mut MetricsLog) -> anyhow::Result<InitialReport> {
    let dir = run.stage_dir(STAGE);
    let report_path = dir.join(REPORT_FILE);
    let digest = settings_digest(run);
    if report_path.is_file() && particles_path(run).is_file() {
        let text = neurofluid_core::input_file::read_string(&report_path)
            .with_context(|| format!("reading {}", report_path.display()))?;
        let done: InitialReport = serde_json::from_str(&text)
            .with_context(|| format!("parsing {}", report_path.display()))?;
        if done.settings == digest {
            return Ok(done);
        }
        tracing::info!(
            "the initial particles were recovered with other settings: recovering again"
        );
        std::fs::remove_file(particles_path(run))
            .with_context(|| format!("removing {}", particles_path(run).display()))?;
    }
    // what the images and settings decide is checked before the NeRF's fit (a minute or more)
    let scene = &run.scene;
    let m = scene.manifest();
    let radius = f64::from(m.particle_radius);
    let cfg = &run.exp.initial;
    let (lo, hi) = (
        m.box_interior.min.map(f64::from),
        m.box_interior.max.map(f64::from),
    );
    let cell = cfg.cell_radii * radius;
    let dims = [0, 1, 2].map(|k| ((hi[k] - lo[k]) / cell).ceil() as usize + 1);
    anyhow::ensure!(
        dims.iter()
            .try_fold(1usize, |n, &d| n.checked_mul(d))
            .is_some_and(|n| n <= 64_000_000),
        "initial.cell_radii = {} gives a density grid of {dims:?} points over the box; use a \
         coarser grid",
        cfg.cell_radii
    );
    let t0 = scene.frames(Role::Warmup).start;
    let truth = load_particles(scene, Role::Warmup, t0, "true particles of frame 0")?;
    let views = warmup_views(run, t0)?;
    anyhow::ensure!(
        views
            .iter()
            .any(|(_, _, image)| image.rgb.iter().any(|&c| c < WHITE)),
        "the warm-up views of frame 0 ({}) are white: they show no fluid to recover the initial \
         particles from",
        views
            .iter()
            .map(|(name, ..)| name.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    );
    if cfg.threshold == SurfaceThreshold::Silhouette {
        usable_views(&coverage(&views))?;
    }
    let nerf = nerf::train(run, log, NerfKind::Nerf)?;
    let mut grid = DensityGrid::new(lo, cell, dims, vec![0.0; dims.iter().product()])?;
    tracing::info!(?dims, cell, "sampling the NeRF's density over the box");
    grid.values = nerf.density_at(&grid.points(), None)?;
    let max = grid.values.iter().copied().fold(0.0f32, f32::max);
    let (iso, silhouette_iou) = match cfg.iso(radius, f64::from(max)) {
        Some(iso) => (iso, None),
        None => {
            // the iso whose body's silhouettes best match the views the NeRF was trained on
            let choice = silhouette_iso(&grid, &coverage(&views))?;
            (choice.iso, Some(choice.iou))
        }
    };
    tracing::info!(max_density = max, iso, ?silhouette_iou, "surface threshold");
    let settings = FillSettings {
        iso,
        spacing: 2.0 * radius,
        largest_only: cfg.largest_only,
    };
    let filled = surface_and_fill(&grid, &settings, (lo, hi)).with_context(|| {
        format!(
            "recovering the initial particles from the NeRF of frame 0 (σ_iso = {iso:.2}, \
             initial.threshold = {:?})",
            cfg.threshold
        )
    })?;
    let n = filled.particles.len();
    let recovered = Particles {
        pos: filled.particles.clone(),
        vel: vec![[0.0; 3]; n],
    };
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    filled.mesh.write(&dir.join("surface.ply"))?;
    if let Some(view) = scene.views(Role::Test).first() {
        let camera = at_least_wide(&scene.camera(Role::Test, view, t0)?, 240);
        let row = particle_row(
            &camera,
            m.particle_radius,
            t0,
            &truth.pos,
            &[("from images", &recovered.pos)],
        );
        neurofluid_physnerf::save_png(dir.join("particles.png"), row.width, row.height, &row.rgb)?;
    }
    let report = InitialReport {
        particles: n,
        true_particles: truth.pos.len(),
        d: gt_to_pred_distance(&truth.pos, &recovered.pos).mean,
        d_reverse: gt_to_pred_distance(&recovered.pos, &truth.pos).mean,
        surface_volume: filled.mesh.volume(),
        true_volume: truth.pos.len() as f64 * (2.0 * radius).powi(3),
        components: filled.components,
        iso,
        silhouette_iou,
        cell,
        settings: digest,
    };
    // the particles last: their presence marks a finished recovery
    neurofluid_core::atomic::write_bytes(
        &report_path,
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )
    .with_context(|| format!("writing {}", report_path.display()))?;
    recovered
        .write(&particles_path(run))
        .with_context(|| format!("writing {}", particles_path(run).display()))?;
    tracing::info!("{}", report.line());
    Ok(report)
}

/// A colour channel below this is not white background.
const WHITE: f32 = 0.98;

/// The warm-up views of frame `t0` (the NeRF's): name, camera and image.
fn warmup_views(run: &Run, t0: usize) -> anyhow::Result<Vec<(String, Camera, Image)>> {
    let scene = &run.scene;
    run.exp
        .warmup
        .views(scene)
        .into_iter()
        .map(|name| {
            let camera = scene.camera(Role::Warmup, &name, t0)?;
            let image = scene.image(Role::Warmup, &name, t0)?;
            Ok((name, camera, image))
        })
        .collect()
}

/// The views' coverage (their alpha) for the silhouette rule.
fn coverage(views: &[(String, Camera, Image)]) -> Vec<Coverage<'_>> {
    views
        .iter()
        .map(|(name, camera, image)| Coverage {
            camera,
            alpha: &image.alpha,
            name,
        })
        .collect()
}
