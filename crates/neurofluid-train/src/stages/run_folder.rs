//! A run: the resolved experiment, its run folder, the device and the opened scene.
//!
//! Side effects have their own names: [`Run::prepare`] (before the stages run: locks the run
//! folder, may generate the scene, checks every input of the stages, then for [`Start::Fresh`]
//! removes what those stages and the ones after them left, and writes the resolved config) and
//! [`Run::open_existing`] (reads only).

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;
use burn::prelude::*;
use neurofluid_core::scene::{Scene, UpAxis};
use neurofluid_dlf::{DlfConfig, DlfNet};
use neurofluid_physnerf::PhysNerfConfig;

use super::nerf::NerfKind;
use super::preflight::{self, Stage};
use super::scene_source::generate_scene_if_missing;
use crate::config::{Containment, Experiment, RESOLVED_FILE, Settings, StageKind};
use crate::metrics_log::{CSV_FILE, JSONL_FILE, MetricsLog};
use crate::trainer::checkpoint;
use crate::trainer::lock::FolderLock;

/// File in the run folder that records each setting changed between sessions.
pub const HISTORY_FILE: &str = "config.history";

/// What a run folder holds (and `--fresh` removes): stage folders and run-level files.
const RUN_CONTENTS: &[&str] = &[
    super::initial::STAGE,
    "nerf",
    "nerf-t",
    super::warmup::STAGE,
    super::joint::STAGE,
    super::eval::STAGE,
    CSV_FILE,
    JSONL_FILE,
    super::CURVES_FILE,
    RESOLVED_FILE,
    HISTORY_FILE,
];

/// Whether a training run continues what its run folder holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Start {
    /// Resume from the stages' checkpoints, if there are any.
    Resume,
    /// Remove what the run folder holds first (`--fresh`).
    Fresh,
}

/// An experiment ready to run.
#[derive(Debug)]
pub struct Run {
    /// The resolved experiment (the ray segment filled in from the scene).
    pub exp: Experiment,
    /// `runs/<name>` (or the configured folder).
    pub dir: PathBuf,
    /// The device with autodiff enabled.
    pub device: Device,
    /// The scene the experiment trains on.
    pub scene: Scene,
    /// The run folder's lock, once taken.
    lock: Option<FolderLock>,
}

impl Run {
    /// Everything before `stages` run: locks the run folder (one process per folder),
    /// generates the built-in scene if its folder holds none (for the training stages; an
    /// evaluation never simulates), checks every input of the stages
    /// ([`preflight`]); for [`Start::Fresh`] then removes what those stages and the ones after
    /// them left (nothing of a folder the tool did not make); writes the resolved config and
    /// appends any setting that changed since the previous session to `config.history`.
    pub fn prepare(exp: Experiment, start: Start, stages: &[Stage]) -> anyhow::Result<Self> {
        check_ours(&exp.out_dir(), start)?;
        let lock = FolderLock::acquire(&exp.out_dir())?;
        Self::prepare_locked(exp, start, stages, lock)
    }

    /// [`Run::prepare`] with the run folder's lock already held (`lock`, on `exp`'s folder).
    pub fn prepare_locked(
        exp: Experiment,
        start: Start,
        stages: &[Stage],
        lock: FolderLock,
    ) -> anyhow::Result<Self> {
        if stages.iter().any(|s| *s != Stage::Eval) {
            generate_scene_if_missing(&exp)?;
        }
        let mut run = Self::open_existing(exp)?;
        run.lock = Some(lock);
        preflight::check(&run, stages, start)?;
        if start == Start::Fresh {
            run.reset(stages)?;
        }
        run.record_config()?;
        Ok(run)
    }

    /// For evaluation and inspection: the scene must exist; nothing is written.
    pub fn open_existing(mut exp: Experiment) -> anyhow::Result<Self> {
        let device = neurofluid_core::device::parse_device(&exp.device)
            .with_context(|| format!("the experiment's device `{}`", exp.device))?
            .autodiff();
        let scene_dir = exp.scene.scene_dir();
        anyhow::ensure!(
            scene_dir.is_dir(),
            "the scene folder {} does not exist; `neurofluid-train run` or `generate` makes a \
             built-in scene",
            scene_dir.display()
        );
        let scene = Scene::open(&scene_dir)
            .with_context(|| format!("opening the scene {}", scene_dir.display()))?;
        let m = scene.manifest();
        let (near, far) = exp.scene.bounds(m.near, m.far);
        exp.scene.near = Some(near);
        exp.scene.far = Some(far);
        let dir = exp.out_dir();
        Ok(Self {
            exp,
            dir,
            device,
            scene,
            lock: None,
        })
    }

    /// Writes the resolved config; settings that differ from the previous session's go to
    /// `config.history` with the time (seconds since the Unix epoch).
    fn record_config(&self) -> anyhow::Result<()> {
        let path = self.dir.join(RESOLVED_FILE);
        if path.is_file() {
            match Experiment::load(&path) {
                Ok(before) => {
                    let changes =
                        Settings::all(&self.exp).changes_since(&Settings::all(&before.resolved()));
                    if !changes.is_empty() {
                        let now = std::time::SystemTime::now()
                            .duration_since(std::time::UNIX_EPOCH)
                            .map_or(0, |d| d.as_secs());
                        let history = self.dir.join(HISTORY_FILE);
                        let mut f = std::fs::OpenOptions::new()
                            .create(true)
                            .append(true)
                            .open(&history)
                            .with_context(|| format!("opening {}", history.display()))?;
                        for c in &changes {
                            tracing::info!("setting changed since the last session: {c}");
                            writeln!(f, "{now} {c}")
                                .with_context(|| format!("writing {}", history.display()))?;
                        }
                    }
                }
                Err(e) => tracing::warn!("the previous resolved config is unreadable: {e}"),
            }
        }
        self.exp.save_resolved(&self.dir)?;
        Ok(())
    }

    /// The run's metrics log, without the rows a resumed stage will log again (those after its
    /// latest checkpoint), so an interrupted run leaves no duplicate steps.
    pub fn open_log(&self) -> anyhow::Result<MetricsLog> {
        let warmup = checkpoint::saved_step(&self.stage_dir(super::warmup::STAGE));
        let joint = checkpoint::saved_step(&self.stage_dir(super::joint::STAGE));
        let nerf = checkpoint::saved_step(&self.stage_dir(NerfKind::Nerf.stage()));
        let nerf_t = checkpoint::saved_step(&self.stage_dir(NerfKind::NerfT.stage()));
        let log = MetricsLog::open_resumed(&self.dir, |row| {
            match row.stage.trim_end_matches("-preview") {
                s if s == super::warmup::STAGE => row.step <= warmup,
                s if s == super::joint::STAGE => row.step <= joint,
                s if s == NerfKind::Nerf.stage() => row.step <= nerf,
                s if s == NerfKind::NerfT.stage() => row.step <= nerf_t,
                _ => true,
            }
        })?;
        Ok(log)
    }

    /// The folder of one stage inside the run folder.
    pub fn stage_dir(&self, stage: &str) -> PathBuf {
        self.dir.join(stage)
    }

    /// The settings that shape a stage's state (checked when a checkpoint is resumed).
    pub fn settings(&self, stage: StageKind) -> Settings {
        Settings::of_stage(&self.exp, stage)
    }

    /// PhysNeRF's config: the experiment's `[physnerf]` with the scene's ray segment.
    pub fn physnerf_config(&self) -> PhysNerfConfig {
        let (near, far) = {
            let m = self.scene.manifest();
            self.exp.scene.bounds(m.near, m.far)
        };
        PhysNerfConfig {
            near: near as f64,
            far: far as f64,
            ..self.exp.physnerf.clone()
        }
    }

    /// DLF's config: gravity along the scene's up axis, the frame rotation that lets the y-up
    /// public weights run on a z-up scene, the scene's time step, the experiment's geometry.
    pub fn dlf_config(&self) -> DlfConfig {
        let mut cfg = match self.scene.up_axis() {
            UpAxis::Z => DlfConfig::z_up(),
            _ => DlfConfig::default(),
        };
        cfg.dt = 1.0 / self.scene.manifest().fps;
        cfg.geometry = self.exp.dlf.geometry;
        if self.exp.dlf.containment == Containment::Box {
            cfg.container = Some(self.scene.manifest().box_interior);
        }
        cfg
    }

    /// Loads DLF from `path` (`.pt`, `.safetensors` or one of our checkpoints).
    pub fn load_dlf(&self, path: &Path) -> anyhow::Result<DlfNet> {
        neurofluid_dlf::load_dlf(path, self.dlf_config(), &self.device)
            .with_context(|| format!("loading DLF weights {}", path.display()))
    }
}

impl Run {
    /// Removes what `stages` and the stages after them left in the run folder (all of it when
    /// the warm-up starts over), and only from a folder this tool made (one holding its resolved
    /// config).
    fn reset(&self, stages: &[Stage]) -> anyhow::Result<()> {
        if !self.dir.join(RESOLVED_FILE).is_file() {
            return Ok(());
        }
        let first = Stage::ALL.iter().position(|s| stages.contains(s));
        let mut names: Vec<&str> = match first {
            Some(0) => RUN_CONTENTS.to_vec(),
            Some(first) => Stage::ALL[first..].iter().map(|s| s.folder()).collect(),
            None => Vec::new(),
        };
        // a baseline starts over alone
        names.extend(
            [Stage::Nerf, Stage::NerfT]
                .into_iter()
                .filter(|s| stages.contains(s))
                .map(Stage::folder),
        );
        for name in names {
            let p = self.dir.join(name);
            if p.is_dir() {
                std::fs::remove_dir_all(&p).with_context(|| format!("removing {}", p.display()))?;
            } else if p.is_file() {
                std::fs::remove_file(&p).with_context(|| format!("removing {}", p.display()))?;
            }
        }
        Ok(())
    }
}

/// Refuses a run folder this tool did not make before anything is written to it: one that
/// holds files of other names and no resolved config (a user's folder given as `out_dir`), and,
/// under `--fresh`, one that is a symbolic link (its removals would reach the link's target).
fn check_ours(dir: &Path, start: Start) -> anyhow::Result<()> {
    let Ok(meta) = std::fs::symlink_metadata(dir) else {
        return Ok(());
    };
    anyhow::ensure!(
        !(start == Start::Fresh && meta.file_type().is_symlink()),
        "the run folder {} is a symbolic link: --fresh removes only from a real folder (give \
         the link's target as the run folder)",
        dir.display()
    );
    if dir.join(RESOLVED_FILE).is_file() {
        return Ok(());
    }
    let entries = std::fs::read_dir(dir)
        .with_context(|| format!("reading the run folder {}", dir.display()))?;
    let foreign: Vec<String> = entries
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n != crate::trainer::lock::LOCK_FILE && !RUN_CONTENTS.contains(&n.as_str()))
        .collect();
    anyhow::ensure!(
        foreign.is_empty(),
        "{} is not a run folder of this tool (no {RESOLVED_FILE}) and holds other files ({}): \
         choose a new or empty folder as the run folder",
        dir.display(),
        foreign.join(", ")
    );
    Ok(())
}
