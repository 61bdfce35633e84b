//! The stages `run` chains: PhysNeRF's warm-up, joint grounding, evaluation; and supervised
//! DLF training (`pretrain-dlf`). Each training stage is a [`crate::trainer::Trainer`] that the
//! [`crate::trainer::Driver`] runs.

pub mod baseline;
pub mod eval;
pub mod initial;
pub mod joint;
pub mod nerf;
pub mod preflight;
pub mod run_folder;
pub mod scene_source;
pub mod supervised_dlf;
pub mod views;
pub mod warmup;

pub use run_folder::{Run, Start};

/// The loss and PSNR curves inside a run folder.
pub const CURVES_FILE: &str = "curves.png";

use crate::config::StageKind;
use crate::metrics_log::MetricsLog;
use crate::trainer::sinks::{CurvesPlot, MetricsSink, PreviewWriter, ProgressBars};
use crate::trainer::{Cadence, Driver, Trainer};

/// Every stage of `run` in order (the initial particles from images first, when asked for),
/// resuming where the run folder says; returns the evaluation.
pub fn run_all(run: &Run, log: &mut MetricsLog) -> anyhow::Result<crate::report::EvalReport> {
    if run.exp.scene.initial == crate::config::InitialParticles::FromImages {
        initial::recover(run, log)?;
    }
    warmup::run(run, log)?;
    let grounded = joint::run(run, log)?;
    eval::run(run, &grounded)
}

/// Runs `trainer` in its stage folder of `run` up to `stop`, with the sinks of the CLI: a
/// progress bar, the run's metrics log, the preview pictures and the curves.
fn drive(
    run: &Run,
    log: &mut MetricsLog,
    trainer: &mut impl Trainer,
    kind: StageKind,
    cadence: Cadence,
    stop: Option<u64>,
) -> anyhow::Result<u64> {
    let mut bars = ProgressBars::new();
    let mut metrics = MetricsSink(log);
    let mut previews = PreviewWriter::new(&run.dir);
    let mut curves = CurvesPlot::new(metrics.0.jsonl_path(), run.dir.join(CURVES_FILE));
    Driver::new(run.stage_dir(trainer.stage()), cadence, run.settings(kind))
        .with_sink(&mut bars)
        .with_sink(&mut metrics)
        .with_sink(&mut previews)
        .with_sink(&mut curves)
        .run(trainer, stop)
}
