//! The one loop: resume, step, log, evaluate, checkpoint, stop.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use super::checkpoint::{self, CheckpointState};
use super::guard::Guard;
use super::{Event, EventSink, StepStats, Trainer};
use crate::config::{Cadence, Settings};
use neurofluid_core::stop_request::{self, Stopped};
use neurofluid_core::transfer::{self, Counts};
use neurofluid_outputs::metrics_log::MetricsRow;

/// Runs a [`Trainer`] in a stage folder, telling its sinks what happens.
pub struct Driver<'s> {
    stage_dir: PathBuf,
    cadence: Cadence,
    settings: Settings,
    sinks: Vec<&'s mut dyn EventSink>,
    stop: Arc<AtomicBool>,
}

/// Rays, time and host–device copies since the previous metrics row, for the throughput, step-time
/// and transfer columns.
struct Throughput {
    started: Instant,
    window: Instant,
    rays: usize,
    steps: u64,
    /// Wall seconds inside the steps (checkpoints, previews and evaluations outside them).
    step_wall: f64,
    transfers: Counts,
}

/// Means per step over a metrics row's window.
struct PerStep {
    /// Wall seconds of a step.
    wall: f64,
    transfers: [f64; 4],
}

impl Throughput {
    fn new() -> Self {
        Self {
            started: Instant::now(),
            window: Instant::now(),
            rays: 0,
            steps: 0,
            step_wall: 0.0,
            transfers: Counts::default(),
        }
    }

    /// The means per step since the previous call (`None` before any step).
    fn take_per_step(&mut self) -> Option<PerStep> {
        let n = std::mem::take(&mut self.steps);
        let c = std::mem::take(&mut self.transfers);
        let wall = std::mem::take(&mut self.step_wall);
        (n > 0).then(|| {
            let per = |v: f64| v / n as f64;
            PerStep {
                wall: per(wall),
                transfers: [
                    per(c.reads as f64),
                    per(c.read_bytes as f64),
                    per(c.uploads as f64),
                    per(c.upload_bytes as f64),
                ],
            }
        })
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
            stop: stop_request::process_flag(),
        }
    }

    /// Stops between steps once `flag` is set (by default the process's flag, which SIGTERM and
    /// SIGINT set once [`stop_request::install_signal_handlers`] ran).
    pub fn with_stop(mut self, flag: Arc<AtomicBool>) -> Self {
        self.stop = flag;
        self
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
        let state = checkpoint::load_matching(&dir, trainer.stage(), &self.settings)?;
        trainer.load(&dir, state.step, state.trainer)?;
        // the files the stage read without its own check (carried particle state) too
        neurofluid_core::checksums::verify(&dir)?;
        Ok((state.step, Some(dir)))
    }

    /// A checkpoint; a model that cannot be saved (non-finite parameters) stops the stage as a
    /// divergence.
    fn checkpoint_or_stop<T: Trainer>(
        &mut self,
        trainer: &T,
        done: u64,
        unconfirmed: bool,
    ) -> anyhow::Result<()> {
        match self.checkpoint(trainer, done) {
            Err(e) if e.downcast_ref::<checkpoint::NonFiniteParameter>().is_some() => {
                Err(self.diverged(trainer.stage(), done, format!("{e:#}"), unconfirmed))
            }
            other => other,
        }
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
        let last = match checkpoint::latest(&self.stage_dir) {
            None => "there is no checkpoint of this stage yet".to_string(),
            Some(dir) => match neurofluid_core::checksums::verify(&dir) {
                Ok(()) => format!(
                    "the last good checkpoint is {} (after {} steps)",
                    dir.display(),
                    checkpoint::saved_step(&self.stage_dir)
                ),
                Err(e) => format!("there is no good checkpoint: {:#}", anyhow::Error::from(e)),
            },
        };
        let message = format!(
            "{stage} stopped at step {step}: {what}; {last}{discarded}. Resuming replays the same \
             steps: change what diverged (a learning rate, an input) and rerun with --fresh"
        );
        if let Err(e) = self.emit(Event::Diverged {
            stage,
            step,
            message: &message,
        }) {
            tracing::warn!("while reporting the divergence: {e:#}");
        }
        anyhow::anyhow!(message)
    }

    /// Tells the sinks the stage stopped on request after `done` steps (checkpointed).
    fn stopped(&mut self, stage: &'static str, done: u64) -> anyhow::Error {
        tracing::info!("{stage}: stop requested; stopping after step {done}, checkpointed");
        if let Err(e) = self.emit(Event::Stopped { stage, done }) {
            tracing::warn!("while reporting the stop: {e:#}");
        }
        Stopped { stage, done }.into()
    }

    fn row(stage: &str, done: u64, stats: &StepStats, throughput: &mut Throughput) -> MetricsRow {
        let mut row = MetricsRow::new(stage, done, stats.loss, throughput.elapsed());
        for (name, v) in stats.named() {
            row.set(&name, v);
        }
        row.set_some("rays_per_s", throughput.take_rate());
        if let Some(per) = throughput.take_per_step() {
            let [r, rb, u, ub] = per.transfers;
            row.set("step_s", per.wall);
            row.set("reads_per_step", r);
            row.set("read_bytes_per_step", rb);
            row.set("uploads_per_step", u);
            row.set("upload_bytes_per_step", ub);
        }
        row
    }

    /// Runs (or resumes) `trainer` up to step `stop` (its end for `None`), checkpointing after
    /// the last step run. Returns the steps done.
    ///
    /// A stop request (see [`Driver::with_stop`]) ends the stage after the update it is in: the
    /// driver checkpoints there (unless the cadence just did) and returns [`Stopped`].
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
        // a checkpoint is confirmed by the first healthy update after it (one left unconfirmed
        // by an earlier session still has its predecessor beside it)
        let mut unconfirmed = checkpoint::has_previous(&self.stage_dir);
        let mut saved = start;
        if start < end && stop_request::requested(&self.stop) {
            return Err(self.stopped(stage, start));
        }
        for step in start..end {
            let (copies, wall) = (transfer::counts(), Instant::now());
            let stats = trainer.step(step)?;
            throughput.step_wall += wall.elapsed().as_secs_f64();
            let done = step + 1;
            if let Some(what) = guard.check(&stats).or_else(|| trainer.check_state().err()) {
                return Err(self.diverged(stage, done, what, unconfirmed));
            }
            throughput.steps += 1;
            throughput.transfers = throughput.transfers.plus(transfer::counts().since(copies));
            // the step's end, for tools that split a log by step (scripts/kernel-launches.sh)
            tracing::trace!(target: "neurofluid_train::step", stage, done, "step finished");
            if stats.updated && std::mem::take(&mut unconfirmed) {
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
                self.checkpoint_or_stop(trainer, done, unconfirmed)?;
                unconfirmed = true;
                saved = done;
            }
            if done < end && stop_request::requested(&self.stop) {
                if saved < done {
                    // left unconfirmed, as at the end of any session
                    self.checkpoint_or_stop(trainer, done, unconfirmed)?;
                }
                return Err(self.stopped(stage, done));
            }
        }
        if let Some(what) = guard.at_end() {
            return Err(self.diverged(stage, end, what, unconfirmed));
        }
        if start < end {
            // left unconfirmed: the next session's first update confirms it
            self.checkpoint_or_stop(trainer, end, unconfirmed)?;
        }
        self.emit(Event::Finished { stage, done: end })?;
        Ok(end.max(start))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trainer::{Evaluation, StageState};

    /// A trainer whose step `s` reports `losses[s]`.
    struct Scripted {
        losses: Vec<f64>,
    }

    impl Trainer for Scripted {
        fn stage(&self) -> &'static str {
            "scripted"
        }
        fn total_steps(&self) -> u64 {
            self.losses.len() as u64
        }
        fn step(&mut self, step: u64) -> anyhow::Result<StepStats> {
            Ok(StepStats {
                loss: self.losses[step as usize],
                grad_norms: vec![("model", 1.0)],
                updated: true,
                ..StepStats::default()
            })
        }
        fn evaluate(&mut self, _done: u64) -> anyhow::Result<Option<Evaluation>> {
            Ok(None)
        }
        fn save(&self, _dir: &Path) -> anyhow::Result<StageState> {
            Ok(StageState::new())
        }
        fn load(&mut self, _dir: &Path, _done: u64, _state: StageState) -> anyhow::Result<()> {
            Ok(())
        }
    }

    const EVERY_2: Cadence = Cadence {
        log_every: 1,
        evaluate_every: 0,
        checkpoint_every: 2,
    };

    fn run(dir: &Path, losses: &[f64], stop: Option<u64>) -> anyhow::Result<u64> {
        let mut t = Scripted {
            losses: losses.to_vec(),
        };
        Driver::new(dir, EVERY_2, Settings::default()).run(&mut t, stop)
    }

    /// The checkpoint written just before a bad step holds the parameters that made it: it is
    /// discarded for the one before, which a healthy update had confirmed.
    #[test]
    fn a_checkpoint_followed_by_a_bad_step_is_rolled_back() {
        let tmp = tempfile::tempdir().unwrap();
        let err = run(tmp.path(), &[1.0, 1.0, 1.0, 1.0, f64::NAN, 1.0], None)
            .unwrap_err()
            .to_string();
        assert!(err.contains("stopped at step 5"), "{err}");
        assert!(
            err.contains("after step 4") && err.contains("discarded"),
            "{err}"
        );
        assert_eq!(checkpoint::saved_step(tmp.path()), 2);
        assert!(!checkpoint::has_previous(tmp.path()));
    }

    /// A healthy update confirms the checkpoint before it; a bad step later keeps it.
    #[test]
    fn a_confirmed_checkpoint_is_kept() {
        let tmp = tempfile::tempdir().unwrap();
        let err = run(tmp.path(), &[1.0, 1.0, 1.0, 1.0, 1.0, f64::NAN], None)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("stopped at step 6") && !err.contains("discarded"),
            "{err}"
        );
        assert_eq!(checkpoint::saved_step(tmp.path()), 4);
    }

    /// A session's last checkpoint stays unconfirmed across sessions: when the next session's
    /// first step is bad, the one before comes back.
    #[test]
    fn the_last_checkpoint_of_a_session_is_confirmed_by_the_next() {
        let tmp = tempfile::tempdir().unwrap();
        let losses = [1.0, 1.0, 1.0, 1.0, f64::NAN, 1.0];
        assert_eq!(run(tmp.path(), &losses, Some(4)).unwrap(), 4);
        assert!(checkpoint::has_previous(tmp.path()));
        let err = run(tmp.path(), &losses, None).unwrap_err().to_string();
        assert!(err.contains("stopped at step 5"), "{err}");
        assert_eq!(checkpoint::saved_step(tmp.path()), 2);
        // and a healthy next session confirms it
        let tmp = tempfile::tempdir().unwrap();
        let healthy = [1.0; 6];
        run(tmp.path(), &healthy, Some(4)).unwrap();
        run(tmp.path(), &healthy, None).unwrap();
        assert_eq!(checkpoint::saved_step(tmp.path()), 6);
    }

    /// A trainer that sums its losses (its state), updating every `window` steps, and raises
    /// `stop` during step `stop_at`.
    struct Summing {
        window: u64,
        total: f64,
        stop_at: Option<u64>,
        stop: Arc<AtomicBool>,
    }

    impl Trainer for Summing {
        fn stage(&self) -> &'static str {
            "summing"
        }
        fn total_steps(&self) -> u64 {
            12
        }
        fn step(&mut self, step: u64) -> anyhow::Result<StepStats> {
            if self.stop_at == Some(step) {
                self.stop.store(true, std::sync::atomic::Ordering::SeqCst);
            }
            self.total += (step as f64 + 1.0).sqrt();
            Ok(StepStats {
                loss: 1.0,
                grad_norms: vec![("model", 1.0)],
                updated: (step + 1).is_multiple_of(self.window),
                ..StepStats::default()
            })
        }
        fn evaluate(&mut self, _done: u64) -> anyhow::Result<Option<Evaluation>> {
            Ok(None)
        }
        fn save(&self, _dir: &Path) -> anyhow::Result<StageState> {
            let mut s = StageState::new();
            s.insert("total".into(), self.total.into());
            Ok(s)
        }
        fn load(&mut self, _dir: &Path, _done: u64, state: StageState) -> anyhow::Result<()> {
            self.total = state["total"].as_f64().unwrap();
            Ok(())
        }
    }

    /// A stop request ends the stage after the update it is in, with a checkpoint there (none
    /// twice when the cadence just wrote one); resuming ends where an uninterrupted run ends.
    #[test]
    fn a_stop_request_checkpoints_after_the_update_and_resumes_exactly() {
        let cadence = Cadence {
            log_every: 1,
            evaluate_every: 0,
            checkpoint_every: 4,
        };
        let drive = |dir: &Path, window: u64, stop_at: Option<u64>| {
            let stop = Arc::new(AtomicBool::new(false));
            let mut t = Summing {
                window,
                total: 0.0,
                stop_at,
                stop: Arc::clone(&stop),
            };
            let out = Driver::new(dir, cadence, Settings::default())
                .with_stop(stop)
                .run(&mut t, None);
            (out, t.total)
        };
        for (window, stop_at, stopped_after) in [(1, 4, 5), (1, 3, 4), (3, 3, 6), (3, 6, 9)] {
            let tmp = tempfile::tempdir().unwrap();
            let (straight, expected) = drive(&tmp.path().join("straight"), window, None);
            assert_eq!(straight.unwrap(), 12);
            let dir = tmp.path().join("stopped");
            let (out, _) = drive(&dir, window, Some(stop_at));
            let err = out.unwrap_err();
            let stopped = stop_request::stopped(err.as_ref()).expect("a Stopped error");
            assert_eq!(
                (stopped.stage, stopped.done),
                ("summing", stopped_after),
                "window {window}, stop during step {stop_at}"
            );
            assert_eq!(checkpoint::saved_step(&dir), stopped_after);
            let (resumed, total) = drive(&dir, window, None);
            assert_eq!(resumed.unwrap(), 12);
            assert_eq!(total.to_bits(), expected.to_bits(), "window {window}");
        }
        // a request standing before the first step stops the stage without a step
        let tmp = tempfile::tempdir().unwrap();
        let stop = Arc::new(AtomicBool::new(true));
        let mut t = Summing {
            window: 1,
            total: 0.0,
            stop_at: None,
            stop: Arc::clone(&stop),
        };
        let err = Driver::new(tmp.path(), cadence, Settings::default())
            .with_stop(stop)
            .run(&mut t, None)
            .unwrap_err();
        assert_eq!(stop_request::stopped(err.as_ref()).unwrap().done, 0);
        assert_eq!(t.total, 0.0);
    }

    /// Orphans of a killed process go; a crash between the two renames of a checkpoint write
    /// leaves the previous checkpoint, which is then the latest.
    #[test]
    fn interrupted_writes_leave_a_whole_checkpoint() {
        let tmp = tempfile::tempdir().unwrap();
        run(tmp.path(), &[1.0; 2], None).unwrap();
        std::fs::rename(
            tmp.path().join("checkpoint"),
            tmp.path().join("checkpoint.old"),
        )
        .unwrap();
        std::fs::create_dir_all(tmp.path().join("checkpoint.4242.tmp")).unwrap();
        assert_eq!(checkpoint::saved_step(tmp.path()), 2);
        assert_eq!(run(tmp.path(), &[1.0; 4], None).unwrap(), 4);
        assert!(!tmp.path().join("checkpoint.4242.tmp").exists());
        assert_eq!(checkpoint::saved_step(tmp.path()), 4);
    }
}
