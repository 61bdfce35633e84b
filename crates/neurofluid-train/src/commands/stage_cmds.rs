//! `warmup`, `joint`, `refit` and `eval`: the stages of `run`, one at a time.

use crate::stage::Stage;
use crate::stages::{eval, joint, refit, warmup};

use super::experiment_args::ExperimentArgs;

/// Arguments of the single-stage commands.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    exp: ExperimentArgs,
}

/// The renderer warm-up on frame 0.
pub fn run_warmup(args: Args) -> anyhow::Result<()> {
    let run = args.exp.prepare(&[Stage::Warmup])?;
    let mut log = run.open_log()?;
    warmup::run(&run, &mut log)?;
    println!(
        "warm-up checkpoint in {}",
        run.stage_dir(warmup::STAGE).display()
    );
    Ok(())
}

/// Joint grounding (needs a finished warm-up).
pub fn run_joint(args: Args) -> anyhow::Result<()> {
    let run = args.exp.prepare(&[Stage::Joint])?;
    let mut log = run.open_log()?;
    joint::run(&run, &mut log)?;
    println!(
        "joint checkpoint in {}",
        run.stage_dir(joint::STAGE).display()
    );
    Ok(())
}

/// The renderer refit to the grounded rollout (needs a finished joint stage and
/// `refit.enabled`).
pub fn run_refit(args: Args) -> anyhow::Result<()> {
    // before the run folder is touched (`--fresh` would remove `refit/` and `eval/`)
    anyhow::ensure!(
        args.exp.load()?.refit.enabled,
        "refit.enabled is false in {}: set it (e.g. `--set refit.enabled=true`) to fit a second \
         renderer to the grounded rollout",
        args.exp.experiment.display()
    );
    let run = args.exp.prepare(&[Stage::Refit])?;
    let mut log = run.open_log()?;
    let grounded = joint::load_trained(&run)?;
    refit::run(&run, &mut log, &grounded.dlf)?;
    println!(
        "refit checkpoint in {}",
        run.stage_dir(refit::STAGE).display()
    );
    Ok(())
}

/// Evaluation of a finished joint stage (reads the scene and checkpoints; simulates nothing;
/// `--fresh` replaces an earlier evaluation).
pub fn run_eval(args: Args) -> anyhow::Result<()> {
    let run = args.exp.prepare(&[Stage::Eval])?;
    let grounded = refit::for_views(&run, joint::load_trained(&run)?)?;
    let summary = eval::run(&run, &grounded)?;
    println!("{}", summary.markdown());
    Ok(())
}
