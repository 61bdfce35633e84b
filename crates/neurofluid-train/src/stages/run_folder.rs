//! A run: the resolved experiment, its run folder, the device and the opened scene.
//!
//! Side effects have their own names: [`Run::prepare`] (in `prepare.rs`; before the stages run: locks the run
//! folder, may generate the scene, checks every input of the stages, then for [`Start::Fresh`]
//! removes what those stages and the ones after them left, and writes the resolved config) and
//! [`Run::open_existing`] (reads only).

use neurofluid_core::choice::Choice;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;
use burn::prelude::*;
use neurofluid_core::scene::Scene;
use neurofluid_dlf::{DlfConfig, DlfNet};
use neurofluid_physnerf::PhysNerfConfig;

use crate::config::{Experiment, RESOLVED_FILE, Settings};
use crate::stage::Stage;
use crate::trainer::checkpoint;
use neurofluid_core::folder_lock::{FolderLock, LOCK_FILE};
use neurofluid_outputs::metrics_log::{CSV_FILE, JSONL_FILE, MetricsLog};

/// The loss and PSNR curves inside a run folder.
pub const CURVES_FILE: &str = "curves.png";

/// File in the run folder that records each setting changed between sessions.
pub const HISTORY_FILE: &str = "config.history";

/// What a run folder holds (and `--fresh` removes): stage folders and run-level files.
const RUN_CONTENTS: &[&str] = &[
    Stage::Initial.folder(),
    Stage::Nerf.folder(),
    Stage::NerfT.folder(),
    Stage::Warmup.folder(),
    Stage::Joint.folder(),
    Stage::Refit.folder(),
    Stage::Eval.folder(),
    CSV_FILE,
    JSONL_FILE,
    CURVES_FILE,
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
    pub(super) lock: Option<FolderLock>,
}

impl Run {
    /// For evaluation and inspection: the scene must exist; nothing is written.
    pub fn open_existing(mut exp: Experiment) -> anyhow::Result<Self> {
        let device = neurofluid_core::device::parse_device(&exp.device)
            .with_context(|| format!("the experiment's device `{}`", exp.device))?
            .autodiff();
        if let Some(half) = exp.matmul.half()
            && !neurofluid_core::device::is_host(&device)
        {
            anyhow::ensure!(
                device.supports_dtype(half),
                "matmul = \"{}\": the device `{}` has no {half:?} type; use \"f32\" there",
                exp.matmul.name(),
                exp.device
            );
        }
        neurofluid_core::half_matmul::set_matmul_operands(exp.matmul);
        neurofluid_core::device_search::set_neighbour_search(exp.neighbour_search);
        let scene_dir = exp.scene.scene_dir();
        anyhow::ensure!(
            scene_dir.is_dir(),
            "the scene folder {} does not exist; `neurofluid-train run` or `generate` makes a \
             built-in scene",
            scene_dir.display()
        );
        let scene = Scene::open(&scene_dir)
            .with_context(|| format!("opening the scene {}", scene_dir.display()))?;
        if let Some(problem) = exp.scene_problem(&scene) {
            anyhow::bail!("{problem}");
        }
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
    pub(super) fn record_config(&self) -> anyhow::Result<()> {
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
        let resumed = [
            Stage::Warmup,
            Stage::Joint,
            Stage::Refit,
            Stage::Nerf,
            Stage::NerfT,
        ]
        .map(|s| (s, checkpoint::saved_step(&self.stage_dir(s))));
        let log = MetricsLog::open_resumed(&self.dir, |row| {
            let stage = Stage::of_folder(
                row.stage
                    .trim_end_matches("-preview")
                    .trim_end_matches("-validation"),
            );
            resumed
                .iter()
                .find(|(s, _)| Some(*s) == stage)
                .is_none_or(|(_, saved)| row.step <= *saved)
        })?;
        Ok(log)
    }

    /// The folder of one stage inside the run folder.
    pub fn stage_dir(&self, stage: Stage) -> PathBuf {
        self.dir.join(stage.folder())
    }

    /// The latest checkpoint of `stage`, which another stage or the evaluation starts from;
    /// the error says to run that stage first.
    pub fn latest_checkpoint(&self, stage: Stage) -> anyhow::Result<PathBuf> {
        let dir = self.stage_dir(stage);
        crate::trainer::checkpoint::latest(&dir).with_context(|| {
            format!(
                "no {} checkpoint in {}: run the `{}` stage first",
                stage.folder(),
                dir.display(),
                stage.folder()
            )
        })
    }

    /// The settings that shape a stage's state (checked when a checkpoint is resumed).
    pub fn settings(&self, stage: Stage) -> Settings {
        Settings::of_stage(&self.exp, stage)
    }

    /// PhysNeRF's config: the experiment's `[physnerf]` with the scene's ray segment.
    pub fn physnerf_config(&self) -> PhysNerfConfig {
        self.on_ray_segment(self.exp.physnerf.clone())
    }

    /// The refitted renderer's config: [`Experiment::refit_physnerf`] with the scene's ray
    /// segment.
    pub fn refit_physnerf_config(&self) -> PhysNerfConfig {
        self.on_ray_segment(self.exp.refit_physnerf())
    }

    /// `config` with the scene's ray segment.
    fn on_ray_segment(&self, config: PhysNerfConfig) -> PhysNerfConfig {
        let (near, far) = {
            let m = self.scene.manifest();
            self.exp.scene.bounds(m.near, m.far)
        };
        PhysNerfConfig {
            near: near as f64,
            far: far as f64,
            ..config
        }
    }

    /// DLF's config: gravity along the scene's up axis, the frame rotation that lets the y-up
    /// public weights run on a z-up scene, the scene's time step, and the experiment's `[dlf]`
    /// geometry mode and rules.
    pub fn dlf_config(&self) -> DlfConfig {
        let mut cfg = DlfConfig::for_up_axis(self.scene.up_axis());
        cfg.dt = 1.0 / self.scene.manifest().fps;
        cfg.geometry = self.exp.dlf.geometry;
        let interior = self.scene.manifest().box_interior;
        cfg.with_rules(self.exp.dlf.rules, Some(interior))
            .expect("a scene has a box, and the experiment's rules were validated")
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
    pub(super) fn reset(&self, stages: &[Stage]) -> anyhow::Result<()> {
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
            Stage::BASELINES
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
/// holds files of other names and no resolved config (a user's folder given as `out_dir`), one
/// whose stage folders, logs or lock are symbolic links (what the tool writes there would land
/// wherever the links point, outside the run folder), and, under `--fresh`, one that is a
/// symbolic link itself (its removals would reach the link's target).
pub(super) fn check_ours(dir: &Path, start: Start) -> anyhow::Result<()> {
    let Ok(meta) = std::fs::symlink_metadata(dir) else {
        return Ok(());
    };
    anyhow::ensure!(
        !(start == Start::Fresh && meta.file_type().is_symlink()),
        "the run folder {} is a symbolic link: --fresh removes only from a real folder (give \
         the link's target as the run folder)",
        dir.display()
    );
    for name in RUN_CONTENTS.iter().chain([&LOCK_FILE]) {
        let path = dir.join(name);
        let linked = std::fs::symlink_metadata(&path).is_ok_and(|m| m.file_type().is_symlink());
        anyhow::ensure!(
            !linked,
            "{} is a symbolic link: the tool writes only into the run folder itself, not through \
             links in it (remove the link, or give its target as a run folder of its own)",
            path.display()
        );
    }
    if dir.join(RESOLVED_FILE).is_file() {
        return Ok(());
    }
    let entries = std::fs::read_dir(dir)
        .with_context(|| format!("reading the run folder {}", dir.display()))?;
    let foreign: Vec<String> = entries
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n != LOCK_FILE && !RUN_CONTENTS.contains(&n.as_str()))
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
