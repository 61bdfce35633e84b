//! Checkpoints that resume exactly: every file of a checkpoint is written into a fresh temporary
//! folder that is renamed into place, so a crash never leaves a partial checkpoint behind.
//!
//! A checkpoint folder holds the models (burnpack), the optimiser states (burnpack), the carried
//! particle state where there is one (`.npz`), `state.json` ([`CheckpointState`]: stage, step,
//! the settings that shaped the state with their digest, and the stage's own small state such as
//! its random stream) and the seal of them all ([`neurofluid_core::checksums`]), checked on every load. The learning-rate schedules are pure functions of the step, so the step
//! restores them.

use std::path::{Path, PathBuf};

use anyhow::Context;
use burn::module::Module;
use burn::optim::ModuleOptimizer;
use serde::{Deserialize, Serialize, de::DeserializeOwned};

use crate::config::Settings;
use crate::optim::{Group, OptimDefaults};

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
/// replaces the stage's checkpoint. The replaced one is kept until [`confirm`] (the next step was
/// healthy) or brought back by [`roll_back`] (it was not).
pub fn write(
    stage_dir: &Path,
    fill: impl FnOnce(&Path) -> anyhow::Result<()>,
) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(stage_dir)
        .with_context(|| format!("creating {}", stage_dir.display()))?;
    let tmp = stage_dir.join(format!("{CURRENT}.{}.tmp", std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).with_context(|| format!("removing {}", tmp.display()))?;
    }
    std::fs::create_dir_all(&tmp).with_context(|| format!("creating {}", tmp.display()))?;
    if let Err(e) = fill(&tmp).and_then(|()| Ok(neurofluid_core::checksums::seal(&tmp)?)) {
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(e);
    }
    let current = stage_dir.join(CURRENT);
    let previous = stage_dir.join(PREVIOUS);
    if current.join("state.json").is_file() {
        if previous.exists() {
            std::fs::remove_dir_all(&previous)
                .with_context(|| format!("removing {}", previous.display()))?;
        }
        std::fs::rename(&current, &previous)
            .with_context(|| format!("moving {} aside", current.display()))?;
    } else if current.exists() {
        std::fs::remove_dir_all(&current)
            .with_context(|| format!("removing {}", current.display()))?;
    }
    std::fs::rename(&tmp, &current)
        .with_context(|| format!("moving the checkpoint into {}", current.display()))?;
    Ok(current)
}

/// The newest checkpoint proved good (a healthy step followed it): the one it replaced goes.
pub fn confirm(stage_dir: &Path) -> anyhow::Result<()> {
    let previous = stage_dir.join(PREVIOUS);
    if previous.exists() && stage_dir.join(CURRENT).join("state.json").is_file() {
        std::fs::remove_dir_all(&previous)
            .with_context(|| format!("removing {}", previous.display()))?;
    }
    Ok(())
}

/// The newest checkpoint is suspect (the step after it diverged): the one it replaced comes
/// back, if it is still there. Returns the stage's checkpoint afterwards.
pub fn roll_back(stage_dir: &Path) -> anyhow::Result<Option<PathBuf>> {
    let current = stage_dir.join(CURRENT);
    let previous = stage_dir.join(PREVIOUS);
    if previous.join("state.json").is_file() {
        if current.exists() {
            std::fs::remove_dir_all(&current)
                .with_context(|| format!("removing {}", current.display()))?;
        }
        std::fs::rename(&previous, &current)
            .with_context(|| format!("restoring {}", previous.display()))?;
    } else if current.exists() {
        // no earlier checkpoint to fall back on: the stage starts over
        std::fs::remove_dir_all(&current)
            .with_context(|| format!("removing {}", current.display()))?;
    }
    Ok(latest(stage_dir))
}

/// Removes temporary checkpoint folders a killed process left in `stage_dir` (the caller owns
/// the folder: its run folder is locked).
pub fn remove_orphans(stage_dir: &Path) -> anyhow::Result<()> {
    let Ok(entries) = std::fs::read_dir(stage_dir) else {
        return Ok(());
    };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if name.starts_with(&format!("{CURRENT}.")) && name.ends_with(".tmp") {
            let path = entry.path();
            tracing::info!("removing {}, left by an interrupted run", path.display());
            std::fs::remove_dir_all(&path)
                .with_context(|| format!("removing {}", path.display()))?;
        }
    }
    Ok(())
}

/// A model that cannot be saved: a parameter holds NaN or infinite values.
#[derive(Debug, thiserror::Error)]
#[error("{}: not written: parameter `{param}` holds NaN or infinite values", path.display())]
pub struct NonFiniteParameter {
    /// The file that was not written.
    pub path: PathBuf,
    /// The parameter's path in the model.
    pub param: String,
}

/// Whether a checkpoint precedes the current one (it is kept until the current one is
/// confirmed).
pub fn has_previous(stage_dir: &Path) -> bool {
    stage_dir.join(PREVIOUS).join("state.json").is_file()
        && stage_dir.join(CURRENT).join("state.json").is_file()
}

/// Saves a module's parameters as burnpack; refuses (writing nothing, with
/// [`NonFiniteParameter`]) when a parameter holds a NaN or an infinity, so no weights file ever
/// holds a diverged model.
pub fn save_module<M: Module>(module: &M, path: &Path) -> anyhow::Result<()> {
    if let Some(param) = neurofluid_core::params::first_non_finite(module) {
        return Err(NonFiniteParameter {
            path: path.to_path_buf(),
            param,
        }
        .into());
    }
    module
        .clone()
        .save_file(path)
        .map_err(|e| anyhow::anyhow!("{}: {e:?}", path.display()))
}

/// Loads a module's parameters from burnpack into `module` (same architecture); refuses
/// parameters that are not finite.
pub fn load_module<M: Module>(module: M, path: &Path) -> anyhow::Result<M> {
    anyhow::ensure!(path.is_file(), "{}: no such file", path.display());
    neurofluid_core::checksums::verify_file(path)?;
    let loaded = module
        .try_load_file(path)
        .map_err(|e| anyhow::anyhow!("{}: not a checkpoint of this model: {e}", path.display()))?;
    if let Some(param) = neurofluid_core::params::first_non_finite(&loaded) {
        anyhow::bail!(
            "{}: parameter `{param}` holds NaN or infinite values (a diverged model)",
            path.display()
        );
    }
    Ok(loaded)
}

/// Where a stage's `state.json` keeps its groups' update counts.
const UPDATES_KEY: &str = "updates";

/// Saves `group`'s Adam to `path` and its update count as `name` in the stage's `state`.
pub fn save_group<G: OptimDefaults>(
    group: &Group<G>,
    path: &Path,
    name: &str,
    state: &mut super::StageState,
) -> anyhow::Result<()> {
    save_optimizer(group.adam(), path)?;
    let counts = state
        .entry(UPDATES_KEY)
        .or_insert_with(|| serde_json::Value::Object(Default::default()));
    if let serde_json::Value::Object(counts) = counts {
        counts.insert(name.into(), group.updates().into());
    }
    Ok(())
}

/// Loads the Adam of `owner`'s `group` from `path` and its update count `name` from `state`;
/// for a checkpoint written before groups counted their updates, `implied` gives the count its
/// steps imply.
pub fn load_group<G: OptimDefaults, M: Module>(
    group: &mut Group<G>,
    owner: &M,
    path: &Path,
    name: &str,
    state: &super::StageState,
    implied: impl FnOnce() -> u64,
) -> anyhow::Result<()> {
    let adam = load_optimizer(group.fresh_adam(), owner, path)?;
    let updates = state
        .get(UPDATES_KEY)
        .and_then(|c| c.get(name))
        .and_then(serde_json::Value::as_u64)
        .unwrap_or_else(implied);
    group.restore(adam, updates);
    Ok(())
}

/// Saves an optimiser's state (Adam moments and step counts).
pub fn save_optimizer(opt: &ModuleOptimizer, path: &Path) -> anyhow::Result<()> {
    opt.save(path)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// Loads the state of `owner`'s optimiser into a freshly built optimiser of the same kind. The
/// file must hold the state of `owner`'s parameters: a file of another parameter group (say
/// PhysNeRF's Adam given to DLF) is refused rather than silently dropped.
pub fn load_optimizer<M: Module>(
    opt: ModuleOptimizer,
    owner: &M,
    path: &Path,
) -> anyhow::Result<ModuleOptimizer> {
    anyhow::ensure!(path.is_file(), "{}: no such file", path.display());
    let reader = burn_pack::Reader::from_file(path)
        .map_err(|e| anyhow::anyhow!("{}: not an optimiser state: {e}", path.display()))?;
    let ours: std::collections::HashSet<u64> =
        neurofluid_core::params::ids(owner).into_iter().collect();
    let foreign = reader
        .scalars()
        .keys()
        .filter_map(|k| k.split_once('.').and_then(|(id, _)| id.parse::<u64>().ok()))
        .filter(|id| !ours.contains(id))
        .count();
    anyhow::ensure!(
        foreign == 0,
        "{}: holds optimiser state for {foreign} parameters this model does not have (the file \
         belongs to another parameter group or another model)",
        path.display()
    );
    // what the file is for is checked first (a clearer message for a swapped file), then
    // that it holds the bytes it was written with
    neurofluid_core::checksums::verify_file(path)?;
    opt.load(path)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// Writes `state.json`.
pub fn save_state<S: Serialize>(state: &S, dir: &Path) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(state)?;
    let path = dir.join("state.json");
    std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// Reads `state.json`, naming the file on error.
pub fn load_state<S: DeserializeOwned>(dir: &Path) -> anyhow::Result<S> {
    let path = dir.join("state.json");
    let text = neurofluid_core::input_file::read_string(&path)
        .with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text)
        .with_context(|| format!("{}: malformed checkpoint state", path.display()))
}

/// Reads the checkpoint state in `dir` of `stage`, refusing one made under settings other than
/// `settings` (every changed key is named, with the way out).
pub fn load_matching(
    dir: &Path,
    stage: &str,
    settings: &Settings,
) -> anyhow::Result<CheckpointState> {
    neurofluid_core::checksums::verify_file(&dir.join("state.json"))?;
    let state: CheckpointState = load_state(dir)?;
    match &state.settings {
        Some(saved) => {
            let changes = settings.changes_since(saved);
            if !changes.is_empty() {
                let list: Vec<String> = changes.iter().map(|c| format!("  {c}")).collect();
                anyhow::bail!(
                    "the {stage} checkpoint in {} was made with other settings, and resuming it \
                     would continue a different experiment:\n{}\nput these settings back, or \
                     start the run over with --fresh (which deletes the run folder's checkpoints)",
                    dir.display(),
                    list.join("\n")
                );
            }
        }
        None => tracing::warn!(
            "{}: this checkpoint records no settings; resuming it unchecked",
            dir.display()
        ),
    }
    Ok(state)
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
