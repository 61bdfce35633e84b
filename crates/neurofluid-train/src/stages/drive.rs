//! How the CLI drives a training stage: the [`crate::trainer::Driver`] with its sinks.

use super::run_folder::{CURVES_FILE, Run};
use crate::config::Cadence;
use crate::stage::Stage;
use crate::trainer::sinks::{CurvesPlot, MetricsSink, PreviewWriter, ProgressBars};
use crate::trainer::{Driver, Trainer};
use neurofluid_outputs::metrics_log::MetricsLog;

/// Runs `trainer` in its stage folder of `run` up to `stop`, with the sinks of the CLI: a
/// progress bar, the run's metrics log, the preview pictures and the curves.
pub(super) fn drive(
    run: &Run,
    log: &mut MetricsLog,
    trainer: &mut impl Trainer,
    stage: Stage,
    cadence: Cadence,
    stop: Option<u64>,
) -> anyhow::Result<u64> {
    let mut bars = ProgressBars::new();
    let mut metrics = MetricsSink(log);
    let mut previews = PreviewWriter::new(&run.dir);
    let mut curves = CurvesPlot::new(metrics.0.jsonl_path(), run.dir.join(CURVES_FILE));
    debug_assert_eq!(trainer.stage(), stage.folder());
    Driver::new(run.stage_dir(stage), cadence, run.settings(stage))
        .with_sink(&mut bars)
        .with_sink(&mut metrics)
        .with_sink(&mut previews)
        .with_sink(&mut curves)
        .run(trainer, stop)
}
