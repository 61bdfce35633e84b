//! `init-particles` (the particles at t = 0 from the warm-up images of frame 0) and `baseline`
//! (NeRF and NeRF-T, the paper's novel-view baselines).

use crate::stage::Stage;
use crate::stages::nerf::{self, NerfKind};
use crate::stages::{baseline, eval, initial};
use neurofluid_outputs::report::EvalReport;

use super::experiment_args::ExperimentArgs;

/// Arguments of `init-particles`.
#[derive(Debug, clap::Args)]
pub struct InitArgs {
    #[command(flatten)]
    exp: ExperimentArgs,
}

/// Trains the NeRF of frame 0 (or resumes it) and writes the recovered particles.
pub fn run_init(args: InitArgs) -> anyhow::Result<()> {
    let run = args.exp.prepare(&[Stage::Nerf])?;
    let mut log = run.open_log()?;
    let report = initial::recover(&run, &mut log)?;
    println!("{}", report.line());
    println!(
        "particles, surface and picture in {}",
        run.stage_dir(initial::STAGE).display()
    );
    Ok(())
}

/// Arguments of `baseline`.
#[derive(Debug, clap::Args)]
pub struct BaselineArgs {
    /// Which baseline.
    #[arg(value_enum)]
    kind: NerfKind,
    #[command(flatten)]
    exp: ExperimentArgs,
}

/// Trains (or resumes) a baseline, scores it on the test views and prints the novel-view table
/// beside NeuroFluid's evaluation when the run has one.
pub fn run_baseline(args: BaselineArgs) -> anyhow::Result<()> {
    let run = args.exp.prepare(&[args.kind.stage()])?;
    let mut log = run.open_log()?;
    let model = nerf::train(&run, &mut log, args.kind)?;
    let scores = baseline::evaluate(&run, &model, args.kind)?;
    let report_path = run
        .stage_dir(eval::STAGE)
        .join(neurofluid_outputs::report::JSON_FILE);
    let validation = run.exp.eval.novel_views == crate::config::NovelViews::Validation;
    // NeuroFluid's report, where it scored the same set of views (test or validation)
    let mut report = match EvalReport::read_json(&report_path) {
        Ok(r) if r.validation_views == validation => r,
        _ => {
            let test = run.scene.frames(neurofluid_core::scene::Role::Test);
            let train = run.scene.frames(neurofluid_core::scene::Role::Train);
            let mut r = EvalReport::new(
                &run.exp.name,
                &run.scene.manifest().name,
                "no NeuroFluid evaluation yet",
                neurofluid_outputs::report::Windows::from_lengths(train.len(), test.len()),
            );
            r.validation_views = validation;
            r
        }
    };
    report.nvs_baselines.retain(|b| b.model != scores.model);
    report.nvs_baselines.push(scores);
    println!("{}", report.nvs_markdown());
    println!(
        "scores and renders in {}",
        run.stage_dir(args.kind.stage()).display()
    );
    Ok(())
}
