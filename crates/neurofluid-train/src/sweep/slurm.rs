//! A sweep on a Slurm cluster: one job array, array task *i* runs run *i* of the sweep
//! (`sweep FILE --variant <name of run i>`), each in its own run folder.
//!
//! Preemption and time limits: the script asks for `--requeue` and `--signal=B:TERM@<s>` (SIGTERM
//! to the batch shell that many seconds before the time limit). The shell passes SIGTERM on to
//! the trainer, which finishes its step, checkpoints and exits with [`REQUEUE_EXIT_CODE`]; the
//! shell then requeues its own array task, `scontrol requeue <array job>_<task>` (the task's own
//! id: the array job's id alone would requeue every task of the array), but only while Slurm
//! still reports the task RUNNING: after `scancel` it is COMPLETING and stays cancelled, and on
//! preemption Slurm requeues it itself. The requeued task resumes from the checkpoint (Slurm
//! holds a requeued job back for about two minutes before it may start again).
//!
//! Files in the sweep folder: [`SCRIPT_FILE`] (the array script), [`JOB_FILE`] (the latest
//! submission), `submitted/` (the sweep file and base experiment as submitted, which the tasks
//! read: [`Sweep::freeze`]), `logs/task-<i>.out` (each task's output, appended across requeues),
//! `logs/table.out` (the table job's: a job that depends on the array, `afterany`, and gathers
//! the table once every task has ended), `state/<run>.json` (each run's state:
//! [`super::state`]). Each task renames itself `<sweep>/<run>` when it starts, so `squeue -o
//! %j` shows which run it is.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::Context;
use serde::{Deserialize, Serialize};

use super::Sweep;
use super::state::{self, Phase, RunState};
use crate::config::ConfigError;
use neurofluid_core::stop_request::REQUEUE_EXIT_CODE;

/// The array script inside the sweep folder.
pub const SCRIPT_FILE: &str = "sweep.sbatch";
/// The latest submission inside the sweep folder.
pub const JOB_FILE: &str = "slurm-job.json";
/// The tasks' logs inside the sweep folder.
pub const LOG_DIR: &str = "logs";
/// Seconds before the time limit at which Slurm asks a task to stop, by default.
pub const DEFAULT_SIGNAL_BEFORE_S: u32 = 120;

/// How each array task is scheduled: the `[slurm]` table of a sweep file, and the options of
/// `sweep --slurm` (which override it).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize, clap::Args)]
#[serde(deny_unknown_fields, default)]
pub struct SlurmOptions {
    /// Slurm partition of the tasks.
    #[arg(long)]
    pub partition: Option<String>,
    /// Slurm account charged.
    #[arg(long)]
    pub account: Option<String>,
    /// Slurm quality of service.
    #[arg(long)]
    pub qos: Option<String>,
    /// Time limit of each task in Slurm's format (`MM`, `HH:MM:SS`, `D-HH:MM`).
    #[arg(long)]
    pub time: Option<String>,
    /// GPUs per task: a count, or `TYPE:COUNT` (becomes `--gres=gpu:…`).
    #[arg(long)]
    pub gpus: Option<String>,
    /// CPUs per task.
    #[arg(long)]
    pub cpus_per_task: Option<u32>,
    /// Memory per task in Slurm's format (`32G`).
    #[arg(long)]
    pub mem: Option<String>,
    /// At most this many tasks of the array at once (the array's `%N`).
    #[arg(long, value_name = "N")]
    pub max_running: Option<u32>,
    /// Seconds before the time limit at which a task is asked to checkpoint and requeue itself
    /// (default 120).
    #[arg(long, value_name = "SECONDS")]
    pub signal_before: Option<u32>,
    /// A further `#SBATCH` option, e.g. `--sbatch=--constraint=a100` (repeatable).
    #[arg(long = "sbatch", value_name = "OPTION")]
    pub sbatch: Vec<String>,
    /// A script head: its `#SBATCH` lines follow the generated ones (and override them), its
    /// other lines (`module load …`, environment) run before each task's command.
    #[arg(long, value_name = "FILE")]
    pub template: Option<PathBuf>,
}

impl SlurmOptions {
    /// These options over `defaults` (the sweep file's): each one given here wins; `#SBATCH`
    /// lines add up, the file's first.
    pub fn over(&self, defaults: &SlurmOptions) -> SlurmOptions {
        let pick = |a: &Option<String>, b: &Option<String>| a.clone().or_else(|| b.clone());
        SlurmOptions {
            partition: pick(&self.partition, &defaults.partition),
            account: pick(&self.account, &defaults.account),
            qos: pick(&self.qos, &defaults.qos),
            time: pick(&self.time, &defaults.time),
            gpus: pick(&self.gpus, &defaults.gpus),
            cpus_per_task: self.cpus_per_task.or(defaults.cpus_per_task),
            mem: pick(&self.mem, &defaults.mem),
            max_running: self.max_running.or(defaults.max_running),
            signal_before: self.signal_before.or(defaults.signal_before),
            sbatch: defaults
                .sbatch
                .iter()
                .chain(&self.sbatch)
                .cloned()
                .collect(),
            template: self.template.clone().or_else(|| defaults.template.clone()),
        }
    }

    /// The first bad option: its key and what was expected.
    fn problem(&self) -> Option<(String, String)> {
        let words = [
            ("partition", &self.partition),
            ("account", &self.account),
            ("qos", &self.qos),
            ("time", &self.time),
            ("gpus", &self.gpus),
            ("mem", &self.mem),
        ];
        for (key, value) in words {
            if let Some(v) = value
                && let Err(why) = sbatch_word(v)
            {
                return Some((key.into(), format!("`{v}`: {why}")));
            }
        }
        let counts = [
            ("cpus_per_task", self.cpus_per_task),
            ("max_running", self.max_running),
            ("signal_before", self.signal_before),
        ];
        for (key, value) in counts {
            if value == Some(0) {
                return Some((key.into(), "expected a positive number".into()));
            }
        }
        if let Some(s) = self.signal_before.filter(|&s| s > 65535) {
            return Some((
                "signal_before".into(),
                format!("{s}: Slurm takes at most 65535 seconds"),
            ));
        }
        for (i, line) in self.sbatch.iter().enumerate() {
            if let Err(why) = sbatch_option(line) {
                return Some((format!("sbatch[{i}]"), format!("`{line}`: {why}")));
            }
        }
        None
    }

    /// Checks the `[slurm]` table of the sweep file `origin`.
    pub fn validate(&self, origin: &Path) -> Result<(), ConfigError> {
        match self.problem() {
            None => Ok(()),
            Some((key, message)) => Err(ConfigError::Invalid {
                path: origin.to_path_buf(),
                location: None,
                key: format!("slurm.{key}"),
                message,
            }),
        }
    }

    /// Checks options given on the command line.
    pub fn validate_args(&self) -> anyhow::Result<()> {
        match self.problem() {
            None => Ok(()),
            Some((key, message)) => {
                let flag = key.split('[').next().unwrap_or(&key).replace('_', "-");
                anyhow::bail!("--{flag}: {message}")
            }
        }
    }

    /// Where a job runs and who pays: partition, account, QOS (the tasks' and the table job's
    /// `#SBATCH` options alike).
    fn placement(&self) -> [(&'static str, &Option<String>); 3] {
        [
            ("partition", &self.partition),
            ("account", &self.account),
            ("qos", &self.qos),
        ]
    }

    /// Whether no option is set.
    pub fn is_empty(&self) -> bool {
        *self == Self::default()
    }
}

/// A value that fits on an `#SBATCH` line as one word.
fn sbatch_word(v: &str) -> Result<(), &'static str> {
    if v.is_empty() {
        return Err("expected a value, got an empty one");
    }
    if v.chars()
        .any(|c| c.is_whitespace() || c.is_control() || "'\"\\`$#".contains(c))
    {
        return Err("expected one word without spaces, quotes, `\\`, `$` or `#`");
    }
    Ok(())
}

/// An `#SBATCH` option: `--name[=value]` or `-x value`, one line (an `#SBATCH ` prefix is
/// accepted).
fn sbatch_option(line: &str) -> Result<(), &'static str> {
    let opt = line.trim().trim_start_matches("#SBATCH").trim();
    if !opt.starts_with('-') {
        return Err("expected an sbatch option such as `--constraint=a100`");
    }
    if opt.chars().any(char::is_control) {
        return Err("expected one line");
    }
    Ok(())
}

/// The array's index list (`0-3,5,7-8`) with its throttle (`%N`).
pub fn array_spec(indices: &[usize], max_running: Option<u32>) -> String {
    let mut spec = String::new();
    let mut i = 0;
    while i < indices.len() {
        let mut j = i;
        while j + 1 < indices.len() && indices[j + 1] == indices[j] + 1 {
            j += 1;
        }
        if !spec.is_empty() {
            spec.push(',');
        }
        if j > i {
            let _ = write!(spec, "{}-{}", indices[i], indices[j]);
        } else {
            let _ = write!(spec, "{}", indices[i]);
        }
        i = j + 1;
    }
    if let Some(n) = max_running {
        let _ = write!(spec, "%{n}");
    }
    spec
}

/// `s` quoted for bash.
fn quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

/// The log of array task `index` in the sweep folder `sweep_dir`.
pub fn log_path(sweep_dir: &Path, index: usize) -> PathBuf {
    sweep_dir.join(LOG_DIR).join(format!("task-{index}.out"))
}

/// Everything the array script is made of. Paths are absolute: the tasks start wherever Slurm
/// puts them.
#[derive(Debug, Clone)]
pub struct ArrayScript<'a> {
    /// The sweep.
    pub sweep: &'a Sweep,
    /// The sweep file.
    pub sweep_file: PathBuf,
    /// The sweep folder.
    pub sweep_dir: PathBuf,
    /// The folder the tasks run in (relative paths of the sweep and its experiments start
    /// there).
    pub workdir: PathBuf,
    /// The `neurofluid-train` binary.
    pub exe: PathBuf,
    /// `--device` for every task.
    pub device: Option<String>,
    /// The runs to submit (indices into the sweep's runs).
    pub indices: Vec<usize>,
    /// The scheduling options (the file's `[slurm]` with the command line's over it).
    pub options: SlurmOptions,
    /// The template's text.
    pub template: Option<String>,
}

impl ArrayScript<'_> {
    /// The array's job name: the sweep's name, in the characters Slurm shows as they are.
    pub fn job_name(&self) -> String {
        self.sweep
            .name
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || "-_.".contains(c) {
                    c
                } else {
                    '_'
                }
            })
            .collect()
    }

    /// The script's text.
    pub fn text(&self) -> anyhow::Result<String> {
        let o = &self.options;
        let output = log_path(&self.sweep_dir, 0)
            .with_file_name("task-%a.out")
            .display()
            .to_string();
        if let Err(why) = sbatch_word(&output).and_then(|()| {
            if output.matches('%').count() > 1 {
                Err("expected no `%`")
            } else {
                Ok(())
            }
        }) {
            anyhow::bail!(
                "the sweep folder {} cannot be named on an #SBATCH line ({why}): give the sweep \
                 an `out_dir` without such characters",
                self.sweep_dir.display()
            );
        }
        let job_name = self.job_name();
        let mut s = String::from("#!/bin/bash\n");
        let _ = writeln!(
            s,
            "# Written by `neurofluid-train sweep {} --slurm`: array task i runs run i of the \
             sweep.",
            self.sweep_file.display()
        );
        let mut directive = |opt: String| {
            let _ = writeln!(s, "#SBATCH {opt}");
        };
        directive(format!("--job-name={job_name}"));
        directive(format!(
            "--array={}",
            array_spec(&self.indices, o.max_running)
        ));
        directive(format!("--output={output}"));
        directive("--open-mode=append".into());
        directive("--requeue".into());
        directive(format!(
            "--signal=B:TERM@{}",
            o.signal_before.unwrap_or(DEFAULT_SIGNAL_BEFORE_S)
        ));
        let words = o
            .placement()
            .into_iter()
            .chain([("time", &o.time), ("mem", &o.mem)]);
        for (name, value) in words {
            if let Some(v) = value {
                directive(format!("--{name}={v}"));
            }
        }
        if let Some(g) = &o.gpus {
            directive(format!("--gres=gpu:{g}"));
        }
        if let Some(c) = o.cpus_per_task {
            directive(format!("--cpus-per-task={c}"));
        }
        for line in &o.sbatch {
            directive(line.trim().trim_start_matches("#SBATCH").trim().to_string());
        }
        let mut setup = String::new();
        for line in self.template.iter().flat_map(|t| t.lines()) {
            if line.starts_with("#SBATCH") {
                let _ = writeln!(s, "{line}");
            } else if !line.starts_with("#!") {
                let _ = writeln!(setup, "{line}");
            }
        }
        if !setup.trim().is_empty() {
            let _ = write!(s, "\n# from the template {}\n{setup}", display_template(o));
        }
        let runs: Vec<String> = self.sweep.variants.iter().map(|v| quote(&v.name)).collect();
        let mut command = format!(
            "{} sweep {} --variant \"$run\"",
            quote(&self.exe.display().to_string()),
            quote(&self.sweep_file.display().to_string())
        );
        if let Some(d) = &self.device {
            let _ = write!(command, " --device {}", quote(d));
        }
        let _ = write!(
            s,
            r#"
# the runs of the sweep by array index, as they were when this script was written
runs=({runs})
run=${{runs[$SLURM_ARRAY_TASK_ID]}}
task="${{SLURM_ARRAY_JOB_ID}}_${{SLURM_ARRAY_TASK_ID}}"
cd {workdir} || exit 1
echo "== $(date -u '+%F %T') UTC: run $run, task $task on $(hostname), start $((${{SLURM_RESTART_COUNT:-0}} + 1))"
# the task's name in squeue: the sweep's and the run's (best effort: some sites forbid it)
scontrol update JobId="$task" JobName={job_name}/"$run" >/dev/null 2>&1 || true

# SIGTERM (preemption, or --signal before the time limit) and SIGINT go to the trainer, which
# finishes its step, writes a checkpoint and exits with {code}.
forward() {{ signalled=1; [ -n "${{child:-}}" ] && kill -TERM "$child" 2>/dev/null; }}
trap forward TERM INT
signalled=0
{command} &
child=$!
[ "$signalled" = 1 ] && kill -TERM "$child" 2>/dev/null
status=127
while :; do
    signalled=0
    wait "$child"
    code=$?
    [ "$code" -ne 127 ] && status=$code
    [ "$signalled" = 1 ] || break
done
if [ "$status" -eq {code} ]; then
    # requeue this task alone (its own id) while Slurm still runs it; otherwise Slurm is
    # requeueing it itself (preemption, `scontrol requeue`) or ending it (scancel)
    state=$(scontrol show job "$task" 2>/dev/null | grep -o 'JobState=[A-Z_]*' | head -n 1)
    state=${{state#JobState=}}
    case "$state" in
    RUNNING)
        echo "== $(date -u '+%F %T') UTC: stopped with a checkpoint; requeueing $task"
        scontrol requeue "$task" ;;
    REQUEUE*|PENDING|PREEMPTED|SUSPENDED)
        echo "== $(date -u '+%F %T') UTC: stopped with a checkpoint; Slurm requeues $task itself ($state)" ;;
    *)
        echo "== $(date -u '+%F %T') UTC: stopped with a checkpoint; $task is ending (${{state:-state unknown}}), not requeued" ;;
    esac
fi
exit "$status"
"#,
            runs = runs.join(" "),
            workdir = quote(&self.workdir.display().to_string()),
            code = REQUEUE_EXIT_CODE,
            job_name = quote(&job_name),
        );
        Ok(s)
    }
}

fn display_template(o: &SlurmOptions) -> String {
    o.template
        .as_ref()
        .map_or_else(String::new, |p| p.display().to_string())
}

/// The latest submission of a sweep (`slurm-job.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Submission {
    /// Slurm's id of the array job.
    pub job: String,
    /// The array's index list.
    pub array: String,
    /// The runs submitted, by index.
    pub runs: Vec<(usize, String)>,
    /// The script.
    pub script: PathBuf,
    /// When (seconds since the Unix epoch).
    pub submitted: u64,
    /// The job that gathers the table once every task has ended (`afterany`), if it could be
    /// submitted.
    #[serde(default)]
    pub table_job: Option<String>,
}

/// A Slurm time limit (`MM`, `MM:SS`, `HH:MM:SS`, `D-HH`, `D-HH:MM`, `D-HH:MM:SS`) in seconds;
/// `None` for `infinite`/`UNLIMITED` or text of another form.
pub fn time_seconds(time: &str) -> Option<u64> {
    let (days, rest) = match time.split_once('-') {
        Some((d, rest)) => (d.parse::<u64>().ok()?, rest),
        None => (0, time),
    };
    let parts: Vec<u64> = rest
        .split(':')
        .map(|p| p.parse::<u64>().ok())
        .collect::<Option<_>>()?;
    let (h, m, s) = match (time.contains('-'), parts.as_slice()) {
        (false, [m]) => (0, *m, 0),
        (false, [m, s]) => (0, *m, *s),
        (_, [h, m, s]) => (*h, *m, *s),
        (true, [h]) => (*h, 0, 0),
        (true, [h, m]) => (*h, *m, 0),
        _ => return None,
    };
    Some(((days * 24 + h) * 60 + m) * 60 + s)
}

/// A warning when each task's time limit leaves it little time to train: the trainer is asked
/// to stop `signal_before` seconds before the limit, so a limit that is not well above it gives
/// each start of a task seconds of work before it checkpoints and requeues.
pub fn short_time_warning(options: &SlurmOptions) -> Option<String> {
    let time = options.time.as_deref()?;
    let limit = time_seconds(time)?;
    let lead = u64::from(options.signal_before.unwrap_or(DEFAULT_SIGNAL_BEFORE_S));
    (limit < 2 * lead).then(|| {
        format!(
            "--time {time} ({limit} s) is less than twice the signal's lead ({lead} s, \
             --signal-before): each start of a task trains for {} s before it is asked to \
             checkpoint and requeue; give a longer --time or a shorter --signal-before",
            limit.saturating_sub(lead)
        )
    })
}

/// The state Slurm gives the job or array task `job` (`1234_5`): `Some("PENDING")`,
/// `Some("RUNNING")`, …, or `None` when Slurm no longer lists it (ended, cancelled, or never
/// there).
pub fn queued_state(job: &str) -> anyhow::Result<Option<String>> {
    let out = slurm_command("squeue", &["--noheader", "--jobs", job, "--format=%T"]);
    match out {
        Ok(text) => Ok(text
            .lines()
            .map(str::trim)
            .find(|l| !l.is_empty())
            .map(str::to_string)),
        // squeue refuses a job id it no longer knows
        Err(e) if e.to_string().contains("Invalid job id") => Ok(None),
        Err(e) => Err(e),
    }
}

/// Submits the job that gathers the sweep's table (`sweep <file> --table`) once every task of
/// the array `job` has ended, however it ended (`afterany`); its output goes to
/// `logs/table.out`. Scheduled as the tasks are (partition, account, QOS) on one CPU.
pub fn submit_table_job(job: &str, script: &ArrayScript<'_>) -> anyhow::Result<String> {
    let o = &script.options;
    let output = script.sweep_dir.join(LOG_DIR).join("table.out");
    let command = format!(
        "cd {} && {} sweep {} --table",
        quote(&script.workdir.display().to_string()),
        quote(&script.exe.display().to_string()),
        quote(&script.sweep_file.display().to_string())
    );
    let mut args: Vec<String> = vec![
        "--parsable".into(),
        format!("--dependency=afterany:{job}"),
        format!("--job-name={}/table", script.job_name()),
        format!("--output={}", output.display()),
        "--ntasks=1".into(),
        "--cpus-per-task=1".into(),
        "--time=30".into(),
    ];
    for (name, value) in o.placement() {
        if let Some(v) = value {
            args.push(format!("--{name}={v}"));
        }
    }
    args.push(format!("--wrap={command}"));
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    let out = slurm_command("sbatch", &refs)?;
    job_id(&out)
}

/// The job id in `sbatch --parsable`'s answer (`1234` or `1234;cluster`).
fn job_id(out: &str) -> anyhow::Result<String> {
    out.trim()
        .split(';')
        .next()
        .filter(|id| !id.is_empty() && id.chars().all(|c| c.is_ascii_digit()))
        .map(str::to_string)
        .with_context(|| format!("sbatch answered `{}`, expected a job id", out.trim()))
}

/// Runs `program` with `args`; its stdout, or an error with its stderr.
fn slurm_command(program: &str, args: &[&str]) -> anyhow::Result<String> {
    let out = Command::new(program).args(args).output().map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            anyhow::anyhow!(
                "`{program}` not found: Slurm's commands are missing on this machine (submit from \
                 a login node, or write the script alone with --dry-run)"
            )
        } else {
            anyhow::Error::new(e).context(format!("running {program}"))
        }
    })?;
    anyhow::ensure!(
        out.status.success(),
        "`{program} {}` failed ({}): {}",
        args.join(" "),
        out.status,
        String::from_utf8_lossy(&out.stderr).trim()
    );
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// Submits the array script `script`, written at `path`, held; records every submitted run as
/// pending (with its task id and log) and the submission in [`JOB_FILE`]; releases the job (no
/// task can start, and record `running`, before its `pending` is written); then submits the
/// job that gathers the table after the array ([`submit_table_job`]; a failure there is a
/// warning: the runs are queued).
pub fn submit(script: &ArrayScript<'_>, path: &Path) -> anyhow::Result<Submission> {
    let sweep_dir = &script.sweep_dir;
    let script_arg = path.display().to_string();
    let out = slurm_command("sbatch", &["--parsable", "--hold", &script_arg])?;
    let job = job_id(&out)?;
    let runs: Vec<(usize, String)> = script
        .indices
        .iter()
        .map(|&i| (i, script.sweep.variants[i].name.clone()))
        .collect();
    for (i, name) in &runs {
        let mut pending = RunState::new(name, Phase::Pending);
        pending.job = Some(format!("{job}_{i}"));
        pending.log = Some(log_path(sweep_dir, *i));
        state::write(sweep_dir, &pending)?;
    }
    let mut submission = Submission {
        job: job.clone(),
        array: array_spec(&script.indices, None),
        runs,
        script: path.to_path_buf(),
        submitted: state::now(),
        table_job: None,
    };
    let record = |submission: &Submission| -> anyhow::Result<()> {
        let text = serde_json::to_string_pretty(submission)?;
        let file = sweep_dir.join(JOB_FILE);
        neurofluid_core::atomic::write_bytes(&file, format!("{text}\n").as_bytes())
            .with_context(|| format!("writing {}", file.display()))
    };
    record(&submission)?;
    slurm_command("scontrol", &["release", &job]).with_context(|| {
        format!("job {job} was submitted held; release it with `scontrol release {job}`")
    })?;
    match submit_table_job(&job, script) {
        Ok(table) => {
            submission.table_job = Some(table);
            record(&submission)?;
        }
        Err(e) => tracing::warn!(
            "the job that gathers the table after the array was not submitted ({e:#}); gather \
             it by hand when the tasks end: sweep --table"
        ),
    }
    Ok(submission)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Experiment, from_toml_str};
    use crate::sweep::SweepFile;

    fn sweep(text: &str) -> Sweep {
        let base = Experiment::from_toml_str(
            "name = \"quick\"\n[scene]\nbuiltin = \"watercube\"\n",
            Path::new("base.toml"),
        )
        .unwrap();
        let file: SweepFile = from_toml_str(text, Path::new("s.toml")).unwrap();
        Sweep::resolve("enc", Path::new("s.toml"), &file, &base).unwrap()
    }

    #[test]
    fn array_specs_are_ranges_with_a_throttle() {
        assert_eq!(array_spec(&[0, 1, 2, 3], None), "0-3");
        assert_eq!(array_spec(&[0, 1, 2, 3], Some(2)), "0-3%2");
        assert_eq!(array_spec(&[1, 3, 4, 5, 8], Some(1)), "1,3-5,8%1");
        assert_eq!(array_spec(&[7], None), "7");
    }

    #[test]
    fn the_script_runs_run_i_in_task_i_and_requeues_itself_on_75() {
        let s = sweep(
            "base = \"b\"\nseeds = [1, 2]\n[[variant]]\nname = \"full\"\n[[variant]]\nname = \"no_pc\"\n\
             [slurm]\npartition = \"gpu\"\ntime = \"4:00:00\"\nsbatch = [\"--constraint=a100\"]\n",
        );
        let cli = SlurmOptions {
            time: Some("8:00:00".into()),
            gpus: Some("1".into()),
            max_running: Some(2),
            sbatch: vec!["#SBATCH --exclusive".into()],
            ..SlurmOptions::default()
        };
        let script = ArrayScript {
            sweep: &s,
            sweep_file: "/w/experiments/enc.toml".into(),
            sweep_dir: "/w/runs/enc".into(),
            workdir: "/w".into(),
            exe: "/opt/nf it's/neurofluid-train".into(),
            device: Some("cuda".into()),
            indices: vec![0, 2, 3],
            options: cli.over(&s.slurm),
            template: Some("#!/bin/bash\n#SBATCH --mem=64G\nmodule load cuda/12\n".into()),
        }
        .text()
        .unwrap();
        let directives: Vec<&str> = script
            .lines()
            .filter(|l| l.starts_with("#SBATCH"))
            .collect();
        assert_eq!(
            directives,
            [
                "#SBATCH --job-name=enc",
                "#SBATCH --array=0,2-3%2",
                "#SBATCH --output=/w/runs/enc/logs/task-%a.out",
                "#SBATCH --open-mode=append",
                "#SBATCH --requeue",
                "#SBATCH --signal=B:TERM@120",
                "#SBATCH --partition=gpu",
                "#SBATCH --time=8:00:00",
                "#SBATCH --gres=gpu:1",
                "#SBATCH --constraint=a100",
                "#SBATCH --exclusive",
                "#SBATCH --mem=64G",
            ]
        );
        // directives end before the first command: sbatch reads no further
        let lines: Vec<&str> = script.lines().collect();
        let first_command = lines
            .iter()
            .position(|l| !l.is_empty() && !l.starts_with('#'))
            .unwrap();
        let last_directive = lines
            .iter()
            .rposition(|l| l.starts_with("#SBATCH"))
            .unwrap();
        assert!(last_directive < first_command, "{script}");
        assert!(script.contains("module load cuda/12\n"), "{script}");
        assert!(
            script.contains("runs=('full-seed1' 'full-seed2' 'no_pc-seed1' 'no_pc-seed2')"),
            "{script}"
        );
        assert!(
            script.contains("run=${runs[$SLURM_ARRAY_TASK_ID]}"),
            "{script}"
        );
        assert!(
            script.contains(
                "'/opt/nf it'\\''s/neurofluid-train' sweep '/w/experiments/enc.toml' --variant \
                 \"$run\" --device 'cuda' &"
            ),
            "{script}"
        );
        assert!(script.contains("cd '/w' || exit 1"), "{script}");
        assert!(script.contains("trap forward TERM INT"), "{script}");
        assert!(
            script.contains("if [ \"$status\" -eq 75 ]; then"),
            "{script}"
        );
        assert!(
            script.contains("task=\"${SLURM_ARRAY_JOB_ID}_${SLURM_ARRAY_TASK_ID}\""),
            "{script}"
        );
        assert!(script.contains("scontrol requeue \"$task\""), "{script}");
        assert!(script.ends_with("exit \"$status\"\n"), "{script}");
        // bash parses it
        if let Ok(out) = Command::new("bash")
            .arg("-n")
            .arg("-c")
            .arg(&script)
            .output()
        {
            assert!(
                out.status.success(),
                "{}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
    }

    #[test]
    fn bad_options_are_named() {
        let base = Experiment::from_toml_str(
            "name = \"quick\"\n[scene]\nbuiltin = \"watercube\"\n",
            Path::new("base.toml"),
        )
        .unwrap();
        for (slurm, key, expect) in [
            ("partition = \"gpu a100\"", "slurm.partition", "one word"),
            ("max_running = 0", "slurm.max_running", "positive"),
            ("signal_before = 70000", "slurm.signal_before", "65535"),
            (
                "sbatch = [\"constraint=a100\"]",
                "slurm.sbatch[0]",
                "--constraint",
            ),
            ("sbatch = [\"--x\\n--y\"]", "slurm.sbatch[0]", "one line"),
            ("partitoin = \"gpu\"", "partitoin", "unknown field"),
        ] {
            let text = format!("base = \"b\"\n[slurm]\n{slurm}\n");
            let err = from_toml_str::<SweepFile>(&text, Path::new("s.toml"))
                .and_then(|f| Sweep::resolve("s", Path::new("s.toml"), &f, &base))
                .unwrap_err();
            assert!(err.key().contains(key), "{slurm}: {err}");
            assert!(err.to_string().contains(expect), "{slurm}: {err}");
            assert!(err.to_string().contains("s.toml"), "{slurm}: {err}");
        }
        let err = SlurmOptions {
            cpus_per_task: Some(0),
            ..SlurmOptions::default()
        }
        .validate_args()
        .unwrap_err()
        .to_string();
        assert!(err.starts_with("--cpus-per-task:"), "{err}");
        let s = sweep("base = \"b\"\n[[variant]]\nname = \"a\"\n");
        let err = ArrayScript {
            sweep: &s,
            sweep_file: "/w/s.toml".into(),
            sweep_dir: "/w/my runs/s".into(),
            workdir: "/w".into(),
            exe: "/bin/nf".into(),
            device: None,
            indices: vec![0],
            options: SlurmOptions::default(),
            template: None,
        }
        .text()
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("/w/my runs/s") && err.contains("out_dir"),
            "{err}"
        );
    }
}
