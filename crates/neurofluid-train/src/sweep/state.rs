//! Each run's state in the sweep folder, `state/<run>.json`, so a sweep's progress is known from
//! files alone (no `squeue`): `pending` (submitted), `running`, `stopped` (stopped on request
//! with a checkpoint, waiting to be requeued or rerun), `done`, `failed` (with the reason). The
//! submitter writes `pending`; the process that runs the run writes the others, only while it
//! holds the run folder's lock. Every write is atomic (temporary file, then rename).

use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::{Deserialize, Serialize};

/// Folder of the state files inside the sweep folder.
pub const STATE_DIR: &str = "state";

/// Where a run is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Phase {
    /// Submitted, not started.
    Pending,
    /// A process runs it.
    Running,
    /// Stopped on request (SIGTERM, SIGINT) with its checkpoint written.
    Stopped,
    /// Its evaluation report is written.
    Done,
    /// It ended with an error (see `reason`).
    Failed,
}

impl Phase {
    /// The word in tables and state files.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Pending => "pending",
            Self::Running => "running",
            Self::Stopped => "stopped",
            Self::Done => "done",
            Self::Failed => "failed",
        }
    }
}

/// What `state/<run>.json` holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunState {
    /// The run's name.
    pub run: String,
    /// Where it is.
    pub state: Phase,
    /// Why it failed or stopped.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// The Slurm array task (`<array job id>_<task id>`), when it is one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub job: Option<String>,
    /// Which start this is (1 + the times Slurm requeued the task).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub attempt: Option<u32>,
    /// The machine it runs on.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub host: Option<String>,
    /// The task's log file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub log: Option<PathBuf>,
    /// When the state was recorded (seconds since the Unix epoch).
    pub since: u64,
}

impl RunState {
    /// `run` in `state`, now, with nothing else known.
    pub fn new(run: &str, state: Phase) -> Self {
        Self {
            run: run.into(),
            state,
            reason: None,
            job: None,
            attempt: None,
            host: None,
            log: None,
            since: now(),
        }
    }

    /// `run` in `state` inside the Slurm task this process runs in (if it does).
    pub fn of_this_task(run: &str, state: Phase) -> Self {
        Self::of_task(run, state, |name| std::env::var(name).ok())
    }

    /// `run` in `state` inside the Slurm task the environment `env` describes.
    fn of_task(run: &str, state: Phase, env: impl Fn(&str) -> Option<String>) -> Self {
        let var = |name: &str| env(name).filter(|v| !v.is_empty());
        let mut s = Self::new(run, state);
        s.job = var("SLURM_ARRAY_JOB_ID")
            .zip(var("SLURM_ARRAY_TASK_ID"))
            .map(|(job, task)| format!("{job}_{task}"))
            .or_else(|| var("SLURM_JOB_ID"));
        s.attempt = s.job.as_ref().map(|_| {
            1 + var("SLURM_RESTART_COUNT")
                .and_then(|n| n.parse::<u32>().ok())
                .unwrap_or(0)
        });
        s.host = var("SLURMD_NODENAME").or_else(|| var("HOSTNAME"));
        s
    }

    /// With `reason`.
    pub fn because(mut self, reason: impl Into<String>) -> Self {
        self.reason = Some(reason.into());
        self
    }
}

/// Seconds since the Unix epoch.
pub fn now() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

/// The state file of `run` in the sweep folder `sweep_dir`.
pub fn path(sweep_dir: &Path, run: &str) -> PathBuf {
    sweep_dir.join(STATE_DIR).join(format!("{run}.json"))
}

/// Records `state` atomically.
pub fn write(sweep_dir: &Path, state: &RunState) -> anyhow::Result<()> {
    let path = path(sweep_dir, &state.run);
    let text = serde_json::to_string_pretty(state).context("serialising a run state")?;
    neurofluid_core::atomic::write_bytes(&path, format!("{text}\n").as_bytes())
        .with_context(|| format!("writing {}", path.display()))
}

/// The recorded state of `run` (`None` when none is recorded); a malformed file is an error
/// naming it.
pub fn read(sweep_dir: &Path, run: &str) -> anyhow::Result<Option<RunState>> {
    let path = path(sweep_dir, run);
    let text = match neurofluid_core::input_file::read_string(&path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e).with_context(|| format!("reading {}", path.display())),
    };
    let state: RunState = serde_json::from_str(&text).with_context(|| {
        format!(
            "{}: not a run state (expected the fields run, state = pending|running|stopped|done|\
             failed, since, and optionally reason, job, attempt, host, log)",
            path.display()
        )
    })?;
    anyhow::ensure!(
        state.run == run,
        "{}: records the run `{}`, expected `{run}`",
        path.display(),
        state.run
    );
    Ok(Some(state))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn states_round_trip_atomically_and_bad_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(read(dir.path(), "a").unwrap(), None);
        let mut s = RunState::new("a", Phase::Failed).because("the loss is NaN");
        s.job = Some("17_3".into());
        s.attempt = Some(2);
        write(dir.path(), &s).unwrap();
        assert_eq!(read(dir.path(), "a").unwrap(), Some(s.clone()));
        let text = std::fs::read_to_string(path(dir.path(), "a")).unwrap();
        let json: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(json["state"], "failed");
        assert_eq!(json["reason"], "the loss is NaN");
        assert_eq!(json["job"], "17_3");
        // no temporary file is left beside it
        let names: Vec<String> = std::fs::read_dir(dir.path().join(STATE_DIR))
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, ["a.json"]);

        for (bad, expect) in [
            (
                "{\"run\": \"a\", \"state\": \"sleeping\", \"since\": 1}",
                "not a run state",
            ),
            (
                "{\"run\": \"b\", \"state\": \"done\", \"since\": 1}",
                "expected `a`",
            ),
            ("{\"run\": \"a\"", "not a run state"),
        ] {
            std::fs::write(path(dir.path(), "a"), bad).unwrap();
            let err = format!("{:#}", read(dir.path(), "a").unwrap_err());
            assert!(
                err.contains("a.json") && err.contains(expect),
                "{bad}: {err}"
            );
        }
    }

    #[test]
    fn a_slurm_task_is_named_by_its_array_job_and_task() {
        let env = |vars: &'static [(&'static str, &'static str)]| {
            move |name: &str| {
                vars.iter()
                    .find(|(k, _)| *k == name)
                    .map(|(_, v)| v.to_string())
            }
        };
        let requeued = RunState::of_task(
            "a",
            Phase::Running,
            env(&[
                ("SLURM_JOB_ID", "45"),
                ("SLURM_ARRAY_JOB_ID", "42"),
                ("SLURM_ARRAY_TASK_ID", "3"),
                ("SLURM_RESTART_COUNT", "1"),
                ("SLURMD_NODENAME", "gpu07"),
            ]),
        );
        assert_eq!(requeued.job.as_deref(), Some("42_3"));
        assert_eq!(requeued.attempt, Some(2));
        assert_eq!(requeued.host.as_deref(), Some("gpu07"));
        let plain = RunState::of_task("a", Phase::Running, env(&[("SLURM_JOB_ID", "7")]));
        assert_eq!((plain.job.as_deref(), plain.attempt), (Some("7"), Some(1)));
        let by_hand = RunState::of_task("a", Phase::Running, env(&[]));
        assert_eq!((by_hand.job, by_hand.attempt), (None, None));
    }
}
