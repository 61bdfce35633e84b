//! [`Run::prepare`]: what happens before the stages of a run start.

use super::preflight;
use super::run_folder::{Run, Start, check_ours};
use super::scene_source::generate_scene_if_missing;
use crate::config::Experiment;
use crate::stage::Stage;
use neurofluid_core::folder_lock::FolderLock;

impl Run {
    /// Everything before `stages` run: locks the run folder (one process per folder),
    /// generates the built-in scene if its folder holds none (for the training stages; an
    /// evaluation never simulates), checks every input of the stages
    /// ([`preflight`]); for [`Start::Fresh`] then removes what those stages and the ones after
    /// them left (nothing of a folder the tool did not make); when the refit runs, removes its
    /// checkpoints if they were made under other settings (it starts over); writes the resolved
    /// config and appends any setting that changed since the previous session to
    /// `config.history`.
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
        if run.exp.refit.enabled && stages.contains(&Stage::Refit) {
            super::refit::start_over_if_stale(&run)?;
        }
        run.record_config()?;
        Ok(run)
    }
}
