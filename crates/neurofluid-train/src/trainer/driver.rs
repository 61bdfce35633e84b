//! The one loop: resume, step, log, evaluate, checkpoint, stop.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::checkpoint::{self, CheckpointState};
use super::guard::Guard;
use super::{Event, EventSink, StepStats, Trainer};
use crate::config::Settings;
use crate::metrics_log::MetricsRow;

/// When the driver logs, evaluates and checkpoints (every this many steps; 0 = never, and
/// for checkpoints: only at the end).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cadence {
    /// A metrics row every this many steps (and after the last one).
    pub log_every: u64,
    /// An evaluation every this many steps.
    pub evaluate_every: u64,
    /// A checkpoint every this many steps (and always after the last step run).
    pub checkpoint_every: u64,
}

/// Runs a [`Trainer`] in a stage folder, telling its sinks what happens.
pub struct Driver<'s> {
    stage_dir: PathBuf,
    cadence: Cadence,
    settings: Settings,
    sinks: Vec<&'s mut dyn EventSink>,
}

/// Rays and time since the previous metrics row, for the throughput column.
struct Throughput {
    started: Instant,
    window: Instant,
    rays: usize,
}

impl Throughput {
    fn new() -> Self {
        Self {
            started: Instant::now(),
            window: Instant::now(),
            rays: 0,
        }
    }

    fn elapsed(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    /// Rays per second since the previous call (`None` for stages that render none).
    fn take_rate(&mut self) -> Option<f64> {
        let secs = self.window.elapsed().as_secs_f64().max(1e-9);
        let rate = (self.rays > 0).then(|| self.rays as f64 / secs);
        self.window = Instant::now();
        self.rays = 0;
        rate
    }
}

impl<'s> Driver<'s> {
    /// A driver for the stage folder `stage_dir`. `settings` are the settings that shape the
    /// stage's state: a checkpoint made under other settings is not resumed.
    pub fn new(stage_dir: impl Into<PathBuf>, cadence: Cadence, settings: Settings) -> Self {
        Self {
            stage_dir: stage_dir.into(),
            cadence,
            settings,
            sinks: Vec::new(),
        }
    }

    /// Adds a sink.
    pub fn with_sink(mut self, sink: &'s mut dyn EventSink) -> Self {
        self.sinks.push(sink);
        self
    }

    /// The stage folder.
    pub fn stage_dir(&self) -> &Path {
        &self.stage_dir
    }

    fn emit(&mut self, event: Event<'_>) -> anyhow::Result<()> {
        for sink in &mut self.sinks {
            sink.on_event(&event)?;
        }
        Ok(())
    }

    /// Resumes `trainer` from the stage's latest checkpoint, if there is one; returns the steps
    /// it holds and its folder.
    fn resume<T: Trainer>(&self, trainer: &mut T) -> anyhow::Result<(u64, Option<PathBuf>)> {
        let Some(dir) = checkpoint::latest(&self.stage_dir) else {
            return Ok((0, None));
        };
        let state: CheckpointState = checkpoint::load_state(&dir)?;
        match &state.settings {
            Some(saved) => {
                let changes = self.settings.changes_since(saved);
                if !changes.is_empty() {
                    let list: Vec<String> = changes.iter().map(|c| format!("  {c}")).collect();
                    anyhow::bail!(
                        "the {} checkpoint in {} was made with other settings, and resuming it \
                         would continue a different experiment:\n{}\nput these settings back, \
                         or start the run over with --fresh (which deletes the run folder's \
                         checkpoints)",
                        trainer.stage(),
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
        trainer.load(&dir, state.step, state.trainer)?;
        Ok((state.step, Some(dir)))
    }

    fn checkpoint<T: Trainer>(&mut self, trainer: &T, done: u64) -> anyhow::Result<()> {
        let settings = self.settings.clone();
        let stage = trainer.stage();
        let dir = checkpoint::write(&self.stage_dir, |dir| {
            let own = trainer.save(dir)?;
            checkpoint::save_state(
                &CheckpointState {
                    stage: stage.to_string(),
                    step: done,
                    settings_digest: Some(settings.digest()),
                    settings: Some(settings),
                    trainer: own,
                },
                dir,
            )
        })?;
        self.emit(Event::Checkpointed {
            stage,
            done,
            dir: &dir,
        })
    }

    /// Stops the stage at `step`. A checkpoint written right before the step (`suspect`) holds
    /// the parameters that produced the bad step: it is discarded for the one before it.
    fn diverged(
        &mut self,
        stage: &'static str,
        step: u64,
        what: String,
        suspect: bool,
    ) -> anyhow::Error {
        let mut discarded = String::new();
        if suspect {
            match checkpoint::roll_back(&self.stage_dir) {
                Ok(_) => {
                    discarded = format!(
                        " (the checkpoint after step {} held the parameters of the bad step \
                         and was discarded)",
                        step - 1
                    );
                }
                Err(e) => tracing::warn!("while discarding the suspect checkpoint: {e:#}"),
            }
        }
        let last = checkpoint::latest(&self.stage_dir).map_or_else(
            || "there is no checkpoint of this stage yet".to_string(),
            |dir| {
                format!(
                    "the last good checkpoint is {} (after {} steps)",
                    dir.display(),
                    checkpoint::saved_step(&self.stage_dir)
                )
            },
        );
        let message = format!("{stage} stopped at step {step}: {what}; {last}{discarded}");
        if let Err(e) = self.emit(Event::Diverged {
            stage,
            step,
            message: &message,
        }) {
            tracing::warn!("while reporting the divergence: {e:#}");
        }
        anyhow::anyhow!(message)
    }

    fn row(stage: &str, done: u64, stats: &StepStats, throughput: &mut Throughput) -> MetricsRow {
        let mut row = MetricsRow::new(stage, done, stats.loss, throughput.elapsed());
        row.psnr = stats.psnr;
        row.lr_physnerf = stats.lr_physnerf;
        row.lr_dlf = stats.lr_dlf;
        row.rays_per_s = throughput.take_rate();
        let norm = |group: &str| {
            stats
                .grad_norms
                .iter()
                .find(|(g, _)| *g == group)
                .map(|(_, n)| *n)
        };
        row.grad_norm_physnerf = norm("physnerf");
        row.grad_norm_dlf = norm("dlf");
        row
    }

    /// Runs (or resumes) `trainer` up to step `stop` (its end for `None`), checkpointing after
    /// the last step run. Returns the steps done.
    pub fn run<T: Trainer>(&mut self, trainer: &mut T, stop: Option<u64>) -> anyhow::Result<u64> {
        let stage = trainer.stage();
        let total = trainer.total_steps();
        checkpoint::remove_orphans(&self.stage_dir)?;
        let (start, resumed_from) = self.resume(trainer)?;
        if let Some(dir) = &resumed_from {
            tracing::info!(step = start, "resuming {stage} from {}", dir.display());
        }
        let end = stop.map_or(total, |s| s.min(total));
        self.emit(Event::Started {
            stage,
            start,
            total,
            resumed_from: resumed_from.as_deref(),
        })?;
        let c = self.cadence;
        let mut throughput = Throughput::new();
        let mut guard = Guard::new();
        // a checkpoint is confirmed by the healthy step after it
        let mut unconfirmed = false;
        for step in start..end {
            let stats = trainer.step(step)?;
            let done = step + 1;
            if let Some(what) = guard
                .check(&stats, total)
                .or_else(|| trainer.check_state().err())
            {
                return Err(self.diverged(stage, done, what, unconfirmed));
            }
            if std::mem::take(&mut unconfirmed) {
                checkpoint::confirm(&self.stage_dir)?;
            }
            throughput.rays += stats.rays;
            self.emit(Event::Step {
                stage,
                done,
                stats: &stats,
            })?;
            if !stats.updated {
                continue;
            }
            if done % c.log_every.max(1) == 0 || done == total {
                let row = Self::row(stage, done, &stats, &mut throughput);
                self.emit(Event::Logged(&row))?;
            }
            if c.evaluate_every > 0
                && done % c.evaluate_every == 0
                && let Some(evaluation) = trainer.evaluate(done)?
            {
                self.emit(Event::Evaluated {
                    stage,
                    done,
                    time_s: throughput.elapsed(),
                    evaluation: &evaluation,
                })?;
            }
            if c.checkpoint_every > 0 && done % c.checkpoint_every == 0 && done < end {
                self.checkpoint(trainer, done)?;
                unconfirmed = true;
            }
        }
        if start < end {
            self.checkpoint(trainer, end)?;
            checkpoint::confirm(&self.stage_dir)?;
        }
        self.emit(Event::Finished { stage, done: end })?;
        Ok(end.max(start))
    }
}
