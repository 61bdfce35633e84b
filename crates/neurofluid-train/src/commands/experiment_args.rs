//! The arguments every training stage shares: the experiment TOML and its overrides.

use std::path::PathBuf;

use anyhow::Context;

use crate::config::Experiment;
use crate::stage::Stage;
use crate::stages::{Run, Start};

/// An experiment file plus command-line overrides.
#[derive(Debug, Clone, clap::Args)]
pub struct ExperimentArgs {
    /// The experiment TOML (see experiments/).
    pub experiment: PathBuf,
    /// Device to run on (cpu, flex, ndarray, wgpu, cuda, cuda:N); overrides `device` in the TOML.
    #[arg(long)]
    pub device: Option<String>,
    /// Override a key of the experiment, e.g. `--set joint.epochs=2` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Start over: delete what this stage and the later ones left in the run folder (for `run`
    /// and `warmup`: everything it holds) instead of resuming from it.
    #[arg(long)]
    pub fresh: bool,
}

impl ExperimentArgs {
    /// Loads the experiment and applies `--device` and `--set`.
    pub fn load(&self) -> anyhow::Result<Experiment> {
        let mut exp = Experiment::load(&self.experiment)?;
        exp.apply_overrides(&self.set)
            .with_context(|| format!("applying --set to {}", self.experiment.display()))?;
        if let Some(d) = &self.device {
            exp.device = d.clone();
        }
        exp.validate(&self.experiment)?;
        Ok(exp)
    }

    /// Loads the experiment and prepares its run for `stages` (locked, inputs checked; with
    /// `--fresh`, what those stages and the later ones left is removed).
    pub fn prepare(&self, stages: &[Stage]) -> anyhow::Result<Run> {
        let start = if self.fresh {
            Start::Fresh
        } else {
            Start::Resume
        };
        Run::prepare(self.load()?, start, stages)
    }
}
