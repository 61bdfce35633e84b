//! Checkpoints that resume exactly: every file of a checkpoint is written into a fresh temporary
//! folder that is renamed into place, so a crash never leaves a partial checkpoint behind.
//!
//! A checkpoint folder holds the models (burnpack), the optimiser states (burnpack), the carried
//! particle state where there is one (`.npz`) and `state.json` ([`CheckpointState`]: stage, step,
//! the settings that shaped the state with their digest, and the stage's own small state such as
//! its random stream). The learning-rate schedules are pure functions of the step, so the step
//! restores them.

use std::path::{Path, PathBuf};

use anyhow::Context;
use burn::module::Module;
use burn::optim::ModuleOptimizer;
use serde::{Deserialize, Serialize, de::DeserializeOwned};

use crate::config::Settings;

/// What `state.json` holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CheckpointState {
    /// The stage that wrote it.
    #[serde(default)]
    pub stage: String,
    /// Steps done.
    pub step: u64,
    /// Digest of `settings` (absent in checkpoints of the first release).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub settings_digest: Option<String>,
    /// The settings that shaped the state (absent in checkpoints of the first release).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub settings: Option<Settings>,
    /// The stage's own state (e.g. `"rng": …`), kept at the top level of the file.
    #[serde(flatten)]
    pub trainer: super::StageState,
}

/// Name of the current checkpoint folder inside a stage folder.
const CURRENT: &str = "checkpoint";
/// Name of the previous checkpoint while a new one replaces it.
const PREVIOUS: &str = "checkpoint.old";

/// The checkpoint folder of a stage (`<run>/<stage>/checkpoint`), if one is complete.
///
/// A crash between the two renames of [`write`] leaves only the previous checkpoint, which is
/// then the one returned.
pub fn latest(stage_dir: &Path) -> Option<PathBuf> {
    [CURRENT, PREVIOUS]
        .iter()
        .map(|n| stage_dir.join(n))
        .find(|p| p.join("state.json").is_file())
}

/// Writes a checkpoint of a stage: `fill` writes the files into a temporary folder, which then
/// replaces the stage's checkpoint.
pub fn write(
    stage_dir: &Path,
    fill: impl FnOnce(&Path) -> anyhow::Result<()>,
) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(stage_dir)
        .with_context(|| format!("creating {}", stage_dir.display()))?;
    let tmp = stage_dir.join(format!("{CURRENT}.{}.tmp", std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp)?;
    }
    std::fs::create_dir_all(&tmp)?;
    if let Err(e) = fill(&tmp) {
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(e);
    }
    let current = stage_dir.join(CURRENT);
    let previous = stage_dir.join(PREVIOUS);
    if previous.exists() {
        std::fs::remove_dir_all(&previous)?;
    }
    if current.exists() {
        std::fs::rename(&current, &previous)?;
    }
    std::fs::rename(&tmp, &current)
        .with_context(|| format!("moving the checkpoint into {}", current.display()))?;
    if previous.exists() {
        std::fs::remove_dir_all(&previous)?;
    }
    Ok(current)
}

/// The first of `names` that exists in `dir` (files of an earlier release keep loading), or the
/// first name when none does (so the error names the current file).
pub fn first_existing(dir: &Path, names: &[&str]) -> PathBuf {
    names
        .iter()
        .map(|n| dir.join(n))
        .find(|p| p.is_file())
        .unwrap_or_else(|| dir.join(names[0]))
}

/// Saves a module's parameters as burnpack.
pub fn save_module<M: Module>(module: &M, path: &Path) -> anyhow::Result<()> {
    module
        .clone()
        .save_file(path)
        .map_err(|e| anyhow::anyhow!("{}: {e:?}", path.display()))
}

/// Loads a module's parameters from burnpack into `module` (same architecture).
pub fn load_module<M: Module>(module: M, path: &Path) -> anyhow::Result<M> {
    module
        .try_load_file(path)
        .map_err(|e| anyhow::anyhow!("{}: not a checkpoint of this model: {e:?}", path.display()))
}

/// Saves an optimiser's state (Adam moments and step counts).
pub fn save_optimizer(opt: &ModuleOptimizer, path: &Path) -> anyhow::Result<()> {
    opt.save(path)
        .map_err(|e| anyhow::anyhow!("{}: {e:?}", path.display()))
}

/// Loads an optimiser's state into a freshly built optimiser of the same kind.
pub fn load_optimizer(opt: ModuleOptimizer, path: &Path) -> anyhow::Result<ModuleOptimizer> {
    opt.load(path)
        .map_err(|e| anyhow::anyhow!("{}: {e:?}", path.display()))
}

/// Writes `state.json`.
pub fn save_state<S: Serialize>(state: &S, dir: &Path) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(state)?;
    std::fs::write(dir.join("state.json"), text)?;
    Ok(())
}

/// Reads `state.json`, naming the file on error.
pub fn load_state<S: DeserializeOwned>(dir: &Path) -> anyhow::Result<S> {
    let path = dir.join("state.json");
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text)
        .with_context(|| format!("{}: malformed checkpoint state", path.display()))
}

/// The step recorded by a stage's latest checkpoint (0 without one).
pub fn saved_step(stage_dir: &Path) -> u64 {
    #[derive(serde::Deserialize)]
    struct Step {
        step: u64,
    }
    latest(stage_dir)
        .and_then(|dir| load_state::<Step>(&dir).ok())
        .map_or(0, |s| s.step)
}
