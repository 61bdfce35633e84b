//! `sweep`: runs every variant of a sweep file (the four encoding switches by default, the
//! paper's Table 5) through the whole pipeline, then writes the table (markdown and CSV).

use std::path::PathBuf;

use anyhow::Context;

use crate::config::Experiment;
use crate::report::{EvalReport, JSON_FILE};
use crate::stages::preflight::Stage;
use crate::stages::{Run, Start, run_all};
use crate::sweep::{Sweep, table_rows, write_table};

/// Arguments of `sweep`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The sweep TOML (see experiments/sweep-encodings.toml).
    pub sweep: PathBuf,
    /// Device for every variant; overrides the base experiment's.
    #[arg(long)]
    pub device: Option<String>,
    /// Keep going when a variant fails (its row stays empty); by default the sweep stops.
    #[arg(long)]
    pub keep_going: bool,
    /// Run nothing: tabulate the reports the variants' folders already hold (a variant whose
    /// joint stage is unfinished or was trained under other settings, or that has no report or
    /// one that scored an earlier checkpoint, gets an empty row)
    #[arg(long)]
    pub table_only: bool,
}

/// Runs the variants one after another (each resumes from its own checkpoints).
pub fn run(args: Args) -> anyhow::Result<()> {
    let sweep = Sweep::load(&args.sweep)?;
    tracing::info!(
        variants = sweep.variants.len(),
        "sweep {} into {}",
        sweep.name,
        sweep.out_dir.display()
    );
    let _lock = crate::trainer::lock::FolderLock::acquire(&sweep.out_dir)?;
    let mut results = Vec::new();
    for variant in &sweep.variants {
        if args.table_only {
            let report = saved_report(&variant.experiment);
            if let Err(e) = &report {
                tracing::warn!("variant {}: no row: {e:#}", variant.name);
            }
            results.push((variant.label.clone(), report.ok()));
            continue;
        }
        let mut exp = variant.experiment.clone();
        if let Some(d) = &args.device {
            exp.device = d.clone();
        }
        tracing::info!("variant {} ({})", variant.name, variant.label);
        let outcome = (|| -> anyhow::Result<_> {
            let run = Run::prepare(exp, Start::Resume, &Stage::ALL)?;
            let mut log = run.open_log()?;
            run_all(&run, &mut log)
        })();
        match outcome {
            Ok(report) => results.push((variant.label.clone(), Some(report))),
            Err(e) if args.keep_going => {
                tracing::error!("variant {} failed: {e:#}", variant.name);
                results.push((variant.label.clone(), None));
            }
            Err(e) => return Err(e).with_context(|| format!("variant {}", variant.name)),
        }
    }
    let table = write_table(&sweep.out_dir, &sweep.name, &table_rows(&results))?;
    println!("{table}");
    println!("table written to {}", sweep.out_dir.display());
    Ok(())
}

/// The evaluation report in `exp`'s run folder, provided the folder holds `exp`'s finished joint
/// stage (every step, made with `exp`'s settings: the row is the variant's, not that of an
/// earlier or unfinished run in its folder).
fn saved_report(exp: &Experiment) -> anyhow::Result<EvalReport> {
    let run = Run::open_existing(exp.clone())?;
    crate::stages::preflight::check(&run, &[Stage::Eval], Start::Resume)?;
    let report = EvalReport::read_json(&run.stage_dir(Stage::Eval.folder()).join(JSON_FILE))?;
    crate::stages::eval::check_current(&run, &report)?;
    Ok(report)
}
