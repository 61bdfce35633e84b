//! `sweep`: runs every variant of a sweep file (the four encoding switches by default, the
//! paper's Table 5) through the whole pipeline, then writes the table (markdown and CSV). Or:
//! one run alone (`--variant`, what each Slurm array task runs), the whole sweep submitted as a
//! Slurm job array (`--slurm`), the table of whatever has finished (`--table`), or each run's
//! state (`--status`), both from the sweep folder's files alone.

use std::path::{Path, PathBuf};

use anyhow::Context;

use crate::config::Experiment;
use crate::stage::Stage;
use crate::stages::{Run, Start, run_all};
use crate::sweep::slurm::{self, ArrayScript, SlurmOptions};
use crate::sweep::state::{self, Phase, RunState};
use crate::sweep::{ResolvedVariant, Sweep};
use neurofluid_core::folder_lock::FolderLock;
use neurofluid_core::stop_request;
use neurofluid_outputs::report::{EvalReport, JSON_FILE};
use neurofluid_outputs::sweep_table::{DONE, TableRow, write_table};

/// Arguments of `sweep`.
#[derive(Debug, Default, clap::Args)]
#[command(group(clap::ArgGroup::new("mode").multiple(false)))]
pub struct Args {
    /// The sweep TOML (see experiments/sweep-encodings.toml).
    pub sweep: PathBuf,
    /// Device for every variant; overrides the base experiment's.
    #[arg(long)]
    pub device: Option<String>,
    /// Keep going when a variant fails (its row stays empty); by default the sweep stops.
    #[arg(long)]
    pub keep_going: bool,
    /// Run nothing: tabulate the reports the runs' folders already hold (a run whose joint stage
    /// is unfinished or was trained under other settings, or that has no report or one that
    /// scored an earlier checkpoint, gets an empty row marked with its state); needs no scheduler
    #[arg(long, alias = "table-only", group = "mode")]
    pub table: bool,
    /// Run nothing: print each run's state (pending, running, stopped, done, failed and why)
    /// from the sweep folder's `state/` files; needs no scheduler
    #[arg(long, group = "mode")]
    pub status: bool,
    /// Run one run alone: its index (0-based, file order; Slurm's array task id) or its name.
    /// Its state goes to the sweep folder's `state/<run>.json`; it resumes from its checkpoints
    #[arg(long, value_name = "I", group = "mode")]
    pub variant: Option<String>,
    /// Submit the runs that are not done as one Slurm job array (task i runs run i): writes
    /// `sweep.sbatch` into the sweep folder, submits it with sbatch and records the runs as
    /// pending
    #[arg(long, group = "mode")]
    pub slurm: bool,
    /// With --slurm: write the script only, submit nothing (`sbatch <script>` submits it)
    #[arg(long, requires = "slurm")]
    pub dry_run: bool,
    /// Start the runs over: their run folders' checkpoints and results are deleted first (with
    /// --slurm, once, when submitting: the tasks then resume as usual, and done runs are
    /// submitted again)
    #[arg(long, conflicts_with_all = ["table", "status"])]
    pub fresh: bool,
    /// Scheduling of each task (with --slurm; the sweep file's `[slurm]` table gives defaults).
    #[command(flatten)]
    pub slurm_options: SlurmOptions,
}

impl Args {
    /// How the runs start: over (`--fresh`) or from their checkpoints.
    fn start(&self) -> Start {
        if self.fresh {
            Start::Fresh
        } else {
            Start::Resume
        }
    }

    /// Whether this invocation trains (and so stops between steps on SIGTERM or SIGINT).
    pub fn trains(&self) -> bool {
        !(self.table || self.status || self.slurm)
    }
}

/// Runs the mode the arguments choose.
pub fn run(args: Args) -> anyhow::Result<()> {
    if !args.slurm && !args.slurm_options.is_empty() {
        anyhow::bail!("the scheduling options (--partition, --time, …) go with --slurm");
    }
    let sweep = Sweep::load(&args.sweep)?;
    if args.table || args.status {
        // reading a sweep folder creates nothing: one that is not there was started elsewhere
        anyhow::ensure!(
            sweep.out_dir.is_dir(),
            "sweep {}: no sweep folder {} (relative to the working directory {}): nothing has \
             run yet, or the sweep was started from another folder (run this there, or give the \
             sweep an absolute out_dir)",
            sweep.name,
            sweep.out_dir.display(),
            std::env::current_dir()
                .map(|d| d.display().to_string())
                .unwrap_or_default()
        );
    }
    if args.table {
        table(&sweep, args.device.as_deref())
    } else if args.status {
        status(&sweep)
    } else if args.slurm {
        submit(&sweep, &args)
    } else if let Some(key) = &args.variant {
        let (index, variant) = sweep.find(key)?;
        let report = run_variant(&sweep, index, variant, args.device.as_deref(), args.start())?;
        println!("{}", report.markdown());
        println!("results in {}", variant.experiment.out_dir().display());
        Ok(())
    } else {
        run_all_variants(&sweep, &args)
    }
}

/// Runs the variants one after another (each resumes from its own checkpoints).
fn run_all_variants(sweep: &Sweep, args: &Args) -> anyhow::Result<()> {
    tracing::info!(
        runs = sweep.variants.len(),
        "sweep {} into {}",
        sweep.name,
        sweep.out_dir.display()
    );
    let _lock = FolderLock::acquire(&sweep.out_dir)?;
    let mut rows = Vec::new();
    let mut failed = Vec::new();
    for (index, variant) in sweep.variants.iter().enumerate() {
        let outcome = run_variant(sweep, index, variant, args.device.as_deref(), args.start());
        let (state, report) = match outcome {
            Ok(report) => (DONE.to_string(), Some(report)),
            Err(e) if stop_request::stopped(e.as_ref()).is_some() => return Err(e),
            Err(e) if args.keep_going => {
                tracing::error!("run {} failed: {e:#}", variant.name);
                failed.push(variant.name.as_str());
                (Phase::Failed.as_str().to_string(), None)
            }
            Err(e) => return Err(e).with_context(|| format!("run {}", variant.name)),
        };
        rows.push(row(variant, state, report));
    }
    let table = write_table(&sweep.out_dir, &sweep.name, &rows)?;
    println!("{table}");
    println!("table written to {}", sweep.out_dir.display());
    some_failed(sweep, &failed)
}

/// The state of a run whose state file cannot be read.
const UNREADABLE: &str = "unreadable";

/// Whether a run's state (as `--table` and `--status` name it) is a failure: `failed`, or a
/// state file that cannot be read.
fn is_failure(state: &str) -> bool {
    state == Phase::Failed.as_str() || state == UNREADABLE
}

/// An error when runs of the sweep failed (the programs then exit with status 1: a script or a
/// dependent job sees it), naming them.
fn some_failed(sweep: &Sweep, failed: &[&str]) -> anyhow::Result<()> {
    anyhow::ensure!(
        failed.is_empty(),
        "{} of the {} runs of sweep {} failed: {} (`sweep {} --status` shows why)",
        failed.len(),
        sweep.variants.len(),
        sweep.name,
        failed.join(", "),
        sweep.name
    );
    Ok(())
}

/// Runs (or resumes) run `index` of the sweep in its folder, recording its state. The folder is
/// locked first: a second process on the same run is refused and records nothing.
fn run_variant(
    sweep: &Sweep,
    index: usize,
    variant: &ResolvedVariant,
    device: Option<&str>,
    start: Start,
) -> anyhow::Result<EvalReport> {
    let mut exp = variant.experiment.clone();
    if let Some(d) = device {
        exp.device = d.to_string();
    }
    tracing::info!(
        "run {} ({}, seed {})",
        variant.name,
        variant.label,
        variant.seed
    );
    let lock = FolderLock::acquire(&exp.out_dir())?;
    let in_slurm = std::env::var_os("SLURM_ARRAY_TASK_ID").is_some();
    let record = |phase: Phase, reason: Option<String>| {
        let mut s = RunState::of_this_task(&variant.name, phase);
        s.reason = reason;
        s.log = in_slurm.then(|| slurm::log_path(&sweep.out_dir, index));
        if let Err(e) = state::write(&sweep.out_dir, &s) {
            tracing::warn!("recording the state of run {}: {e:#}", variant.name);
        }
    };
    record(Phase::Running, None);
    let outcome = (|| {
        let run = Run::prepare_locked(exp, start, &Stage::ALL, lock)?;
        let mut log = run.open_log()?;
        run_all(&run, &mut log)
    })();
    match &outcome {
        Ok(_) => record(Phase::Done, None),
        Err(e) if stop_request::stopped(e.as_ref()).is_some() => {
            record(Phase::Stopped, Some(format!("{e:#}")))
        }
        Err(e) => record(Phase::Failed, Some(format!("{e:#}"))),
    }
    outcome
}

fn row(variant: &ResolvedVariant, state: String, report: Option<EvalReport>) -> TableRow {
    TableRow {
        label: variant.label.clone(),
        seed: variant.seed,
        state,
        summary: report.as_ref().map(EvalReport::summary),
    }
}

/// Writes and prints the table of whatever has finished; the other runs are marked with their
/// recorded state (`missing` without one).
fn table(sweep: &Sweep, device: Option<&str>) -> anyhow::Result<()> {
    let mut rows = Vec::new();
    let mut failed = Vec::new();
    for variant in &sweep.variants {
        let mut exp = variant.experiment.clone();
        // reading reports computes nothing: any device will do
        exp.device = device.unwrap_or("cpu").to_string();
        let (state, report) = match saved_report(&exp) {
            Ok(report) => (DONE.to_string(), Some(report)),
            Err(e) => {
                let recorded = state::read(&sweep.out_dir, &variant.name);
                let state = match &recorded {
                    Ok(Some(s)) if s.state != Phase::Done => s.state.as_str(),
                    Ok(_) => "missing",
                    Err(_) => UNREADABLE,
                };
                if state != Phase::Pending.as_str() && state != Phase::Running.as_str() {
                    tracing::warn!("run {}: no row: {e:#}", variant.name);
                }
                if is_failure(state) {
                    failed.push(variant.name.as_str());
                }
                (state.to_string(), None)
            }
        };
        rows.push(row(variant, state, report));
    }
    let table = write_table(&sweep.out_dir, &sweep.name, &rows)?;
    println!("{table}");
    println!("table written to {}", sweep.out_dir.display());
    some_failed(sweep, &failed)
}

/// The evaluation report in `exp`'s run folder, provided the folder holds `exp`'s finished joint
/// stage (every step, made with `exp`'s settings: the row is the variant's, not that of an
/// earlier or unfinished run in its folder).
fn saved_report(exp: &Experiment) -> anyhow::Result<EvalReport> {
    let run = Run::open_existing(exp.clone())?;
    crate::stages::preflight::check(&run, &[Stage::Eval], Start::Resume)?;
    let report = EvalReport::read_json(&run.stage_dir(Stage::Eval).join(JSON_FILE))?;
    crate::stages::eval::check_current(&run, &report)?;
    Ok(report)
}

/// Prints each run's recorded state.
fn status(sweep: &Sweep) -> anyhow::Result<()> {
    let now = state::now();
    println!("sweep {} ({})", sweep.name, sweep.out_dir.display());
    if let Ok(text) = neurofluid_core::input_file::read_string(sweep.out_dir.join(slurm::JOB_FILE))
        && let Ok(s) = serde_json::from_str::<slurm::Submission>(&text)
    {
        println!(
            "latest submission: job {} (array {}), {} ago",
            s.job,
            s.array,
            age(now.saturating_sub(s.submitted))
        );
    }
    println!(
        "\n| # | run | state | job | start | since | reason | log |\n|---|---|---|---|---|---|---|---|"
    );
    let mut counts: Vec<(String, usize)> = Vec::new();
    let mut failed = Vec::new();
    let mut reasons = Vec::new();
    for (i, variant) in sweep.variants.iter().enumerate() {
        let (word, cells) = match state::read(&sweep.out_dir, &variant.name) {
            Ok(Some(s)) => {
                let reason = s.reason.clone().unwrap_or_default();
                let first = reason.lines().next().unwrap_or_default().to_string();
                if reason.lines().nth(1).is_some() {
                    reasons.push((variant.name.as_str(), reason));
                }
                (
                    s.state.as_str().to_string(),
                    [
                        s.job.clone().unwrap_or_default(),
                        s.attempt.map(|a| a.to_string()).unwrap_or_default(),
                        format!("{} ago", age(now.saturating_sub(s.since))),
                        neurofluid_outputs::formats::markup::markdown_text(&first),
                        s.log.map(|p| p.display().to_string()).unwrap_or_default(),
                    ],
                )
            }
            Ok(None) => ("not started".to_string(), Default::default()),
            Err(e) => {
                let mut cells: [String; 5] = Default::default();
                cells[3] = format!("{e:#}");
                (UNREADABLE.to_string(), cells)
            }
        };
        println!(
            "| {i} | {} | {word} | {} |",
            variant.name,
            cells.join(" | ")
        );
        if is_failure(&word) {
            failed.push(variant.name.as_str());
        }
        match counts.iter_mut().find(|(w, _)| *w == word) {
            Some((_, n)) => *n += 1,
            None => counts.push((word, 1)),
        }
    }
    let summary: Vec<String> = counts.iter().map(|(w, n)| format!("{n} {w}")).collect();
    println!("\n{} runs: {}", sweep.variants.len(), summary.join(", "));
    for (run, reason) in reasons {
        println!("\nrun {run}, the whole reason:\n{reason}");
    }
    some_failed(sweep, &failed)
}

/// `seconds` for people: `42 s`, `7 min`, `3.5 h`, `2.0 d`.
fn age(seconds: u64) -> String {
    match seconds {
        s if s < 120 => format!("{s} s"),
        s if s < 7200 => format!("{} min", s / 60),
        s if s < 172_800 => format!("{:.1} h", s as f64 / 3600.0),
        s => format!("{:.1} d", s as f64 / 86400.0),
    }
}

/// Writes the array script of the runs that are not done, queued or running and submits it
/// (unless `--dry-run`), with the sweep frozen into the sweep folder for its tasks to read.
fn submit(sweep: &Sweep, args: &Args) -> anyhow::Result<()> {
    args.slurm_options.validate_args()?;
    let options = args.slurm_options.over(&sweep.slurm);
    if let Some(warning) = slurm::short_time_warning(&options) {
        tracing::warn!("{warning}");
    }
    let workdir = std::env::current_dir().context("the working directory")?;
    let absolute = |p: &Path| {
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            workdir.join(p)
        }
    };
    let template = options
        .template
        .as_ref()
        .map(|p| {
            let p = crate::sweep::locate(p, &args.sweep);
            neurofluid_core::input_file::read_string(&p)
                .with_context(|| format!("reading the script template {}", p.display()))
        })
        .transpose()?;
    let mut indices = Vec::new();
    for (i, variant) in sweep.variants.iter().enumerate() {
        let recorded = state::read(&sweep.out_dir, &variant.name)?;
        if let Some(s) = &recorded
            && matches!(s.state, Phase::Pending | Phase::Running | Phase::Stopped)
            && let Some(job) = &s.job
        {
            // one submission per run: a task Slurm still holds (queued, running, or requeued
            // after a stop) is not submitted again
            match slurm::queued_state(job) {
                Ok(Some(queued)) => {
                    println!(
                        "run {} is {} as task {job}: not submitted again",
                        variant.name,
                        queued.to_lowercase()
                    );
                    continue;
                }
                Ok(None) => tracing::warn!(
                    "run {} was recorded {} as task {job}, which Slurm no longer lists (it \
                     ended without a word: cancelled, or its node failed): submitted again",
                    variant.name,
                    s.state.as_str()
                ),
                Err(e) if args.dry_run => tracing::warn!(
                    "run {} is recorded {} as task {job}; Slurm could not be asked whether it \
                     still is ({e:#})",
                    variant.name,
                    s.state.as_str()
                ),
                Err(e) => {
                    return Err(e).with_context(|| {
                        format!(
                            "run {} is recorded {} as task {job}; asking Slurm whether it still \
                             is",
                            variant.name,
                            s.state.as_str()
                        )
                    });
                }
            }
        }
        if !args.fresh
            && let Some(s) = &recorded
            && s.state == Phase::Done
        {
            tracing::info!("run {} is done: not submitted", variant.name);
            continue;
        }
        indices.push(i);
    }
    if indices.is_empty() {
        println!(
            "no run of {} to submit (each is done, queued or running); `sweep --status` shows \
             them, `sweep --table` collects the done ones",
            sweep.name
        );
        return Ok(());
    }
    if args.fresh && !args.dry_run {
        for &i in &indices {
            let variant = &sweep.variants[i];
            Run::prepare(variant.experiment.clone(), Start::Fresh, &Stage::ALL)
                .with_context(|| format!("starting run {} over (--fresh)", variant.name))?;
        }
    }
    let sweep_dir = absolute(&sweep.out_dir);
    let frozen = sweep.freeze(&sweep_dir)?;
    let script = ArrayScript {
        sweep,
        sweep_file: frozen,
        sweep_dir: sweep_dir.clone(),
        workdir: workdir.clone(),
        exe: std::env::current_exe().context("the path of this binary")?,
        device: args.device.clone(),
        indices: indices.clone(),
        options,
        template,
    };
    let text = script.text()?;
    let path = sweep_dir.join(slurm::SCRIPT_FILE);
    std::fs::create_dir_all(sweep_dir.join(slurm::LOG_DIR))
        .with_context(|| format!("creating {}", sweep_dir.join(slurm::LOG_DIR).display()))?;
    neurofluid_core::atomic::write_bytes(&path, text.as_bytes())
        .with_context(|| format!("writing {}", path.display()))?;
    if args.dry_run {
        println!(
            "wrote {} ({} runs); submit it with: sbatch {}",
            path.display(),
            indices.len(),
            path.display()
        );
        return Ok(());
    }
    let submission = slurm::submit(&script, &path)?;
    let table = submission.table_job.as_deref().map_or_else(
        || "not submitted: gather it with --table".to_string(),
        |job| {
            format!(
                "job {job}, when every task has ended: {}/table.out",
                sweep_dir.join(slurm::LOG_DIR).display()
            )
        },
    );
    println!(
        "submitted job {} (array {}): {} runs of {}\n  script  {}\n  sweep   {} (as \
         submitted: edits to the sweep file change nothing queued)\n  logs    {}/task-<i>.out\n  \
         states  {}/<run>.json\n  table   {table}\nprogress: neurofluid-train sweep {} --status \
         (or: squeue --me --format='%.18i %.40j %.8T %.10M %R')",
        submission.job,
        submission.array,
        indices.len(),
        sweep.name,
        path.display(),
        script.sweep_file.display(),
        sweep_dir.join(slurm::LOG_DIR).display(),
        sweep_dir.join(state::STATE_DIR).display(),
        args.sweep.display()
    );
    Ok(())
}
