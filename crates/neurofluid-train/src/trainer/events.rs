//! What the driver tells the outside world.

use std::path::Path;

use super::{Evaluation, StepStats};
use neurofluid_outputs::metrics_log::MetricsRow;

/// One thing that happened in a stage.
#[derive(Debug)]
pub enum Event<'a> {
    /// The stage starts at step `start` (0, or where a checkpoint left it) of `total`.
    Started {
        /// The stage.
        stage: &'static str,
        /// First step to run.
        start: u64,
        /// Steps of the whole stage.
        total: u64,
        /// The checkpoint resumed from, if any.
        resumed_from: Option<&'a Path>,
    },
    /// A step finished; `done` steps are done.
    Step {
        /// The stage.
        stage: &'static str,
        /// Steps done.
        done: u64,
        /// What the step did.
        stats: &'a StepStats,
    },
    /// A metrics row is due (the log cadence).
    Logged(&'a MetricsRow),
    /// The model was evaluated after `done` steps.
    Evaluated {
        /// The stage.
        stage: &'static str,
        /// Steps done.
        done: u64,
        /// Seconds since the stage started in this process.
        time_s: f64,
        /// The evaluation.
        evaluation: &'a Evaluation,
    },
    /// A checkpoint after `done` steps is complete in `dir`.
    Checkpointed {
        /// The stage.
        stage: &'static str,
        /// Steps done.
        done: u64,
        /// The checkpoint folder.
        dir: &'a Path,
    },
    /// The stage diverged at step `step`; the run stops.
    Diverged {
        /// The stage.
        stage: &'static str,
        /// The step that diverged (1-based, as in the metrics log).
        step: u64,
        /// What was not finite, and the last good checkpoint.
        message: &'a str,
    },
    /// A stop was requested (SIGTERM, SIGINT): the stage stopped after `done` steps, which its
    /// checkpoint holds, before its end.
    Stopped {
        /// The stage.
        stage: &'static str,
        /// Steps done.
        done: u64,
    },
    /// The stage ran up to `done` steps in this call (its end, or the requested stop).
    Finished {
        /// The stage.
        stage: &'static str,
        /// Steps done.
        done: u64,
    },
}

/// Something that listens to a stage: a progress bar, a log, a picture writer.
pub trait EventSink {
    /// Handles one event; an error stops the stage.
    fn on_event(&mut self, event: &Event<'_>) -> anyhow::Result<()>;
}
