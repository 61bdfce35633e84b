//! `run`: the whole pipeline of an experiment — scene (generated if missing), warm-up, joint
//! grounding, evaluation — then the summary table.

use crate::stages::preflight::Stage;
use crate::stages::{eval, joint, warmup};

use super::experiment_args::ExperimentArgs;

/// Arguments of `run`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    exp: ExperimentArgs,
}

/// Runs every stage, resuming from the checkpoints of an interrupted run.
pub fn run(args: Args) -> anyhow::Result<()> {
    let run = args.exp.prepare(&Stage::ALL)?;
    tracing::info!("run folder {}", run.dir.display());
    let mut log = run.open_log()?;
    warmup::run(&run, &mut log)?;
    let grounded = joint::run(&run, &mut log)?;
    let summary = eval::run(&run, &grounded)?;
    println!("{}", summary.markdown());
    println!("results in {}", run.dir.display());
    Ok(())
}
