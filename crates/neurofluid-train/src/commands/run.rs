//! `run`: the whole pipeline of an experiment — scene (generated if missing), the initial
//! particles from images when asked for, warm-up, joint grounding, evaluation — then the summary
//! table.

use crate::stage::Stage;
use crate::stages::run_all;

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
    let summary = run_all(&run, &mut log)?;
    println!("{}", summary.markdown());
    println!("results in {}", run.dir.display());
    Ok(())
}
