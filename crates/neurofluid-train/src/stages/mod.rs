//! The stages `run` chains: PhysNeRF's warm-up, joint grounding, the optional renderer refit,
//! evaluation; and supervised DLF training (`pretrain-dlf`). Each training stage is a
//! [`crate::trainer::Trainer`] that the [`crate::trainer::Driver`] runs.

pub mod baseline;
mod drive;
pub mod eval;
pub mod initial;
pub mod joint;
pub mod nerf;
pub mod orbit;
pub mod preflight;
mod prepare;
pub mod refit;
pub mod run_folder;
pub mod scene_source;
pub mod supervised_dlf;
pub mod views;
pub mod warmup;

pub use run_folder::{CURVES_FILE, Run, Start};

use neurofluid_outputs::metrics_log::MetricsLog;

/// Every stage of `run` in order (the initial particles from images first, when asked for),
/// resuming where the run folder says; returns the evaluation.
pub fn run_all(
    run: &Run,
    log: &mut MetricsLog,
) -> anyhow::Result<neurofluid_outputs::report::EvalReport> {
    if run.exp.scene.initial == crate::config::InitialParticles::FromImages {
        initial::recover(run, log)?;
    }
    warmup::run(run, log)?;
    let mut grounded = joint::run(run, log)?;
    if run.exp.refit.enabled {
        grounded.physnerf = refit::run(run, log, &grounded.dlf)?;
    }
    eval::run(run, &grounded)
}
