//! `rollout`: one DLF (the experiment's `dlf.weights`, or `--weights`) rolled out from the first
//! test frame under the experiment's `[dlf]` rules and scored by d and d′ over both windows, with
//! nothing trained and nothing written. It scores a rule of the model, or a weights file, on a
//! scene before any run, on the same rollout and the same measures as `eval`'s DLF row.

use std::path::PathBuf;

use serde::Serialize;

use super::experiment_args::ExperimentArgs;
use crate::stages::Run;
use crate::stages::eval::rollouts;
use neurofluid_core::scene::Role;
use neurofluid_outputs::report::{DistanceRow, EvalReport, Rollout, Sequence, Windows};

/// Arguments of `rollout`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    exp: ExperimentArgs,
    /// The DLF weights to roll out (`.pt`, `.safetensors`, `.bpk`). Default: `dlf.weights`.
    #[arg(long)]
    weights: Option<PathBuf>,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
}

/// What `rollout` prints.
#[derive(Debug, Serialize)]
pub struct Scores {
    /// The weights rolled out.
    pub weights: PathBuf,
    /// The `[dlf]` rules beyond the reference's.
    pub rules: Vec<String>,
    /// d (truth → prediction).
    pub d: DistanceRow,
    /// d′ (prediction → truth).
    pub d_reverse: DistanceRow,
    /// (d + d′)/2, frame by frame.
    pub symmetric: DistanceRow,
    /// The most particles outside the box over the rollout's frames.
    pub outside: usize,
    /// The mechanical energy each particle gained (J/kg, the mean of their gains) over the
    /// grounding and the prediction window: the rollout's, then the truth's.
    pub energy_per_particle: [[f64; 2]; 2],
}

/// Rolls the DLF out under `run`'s rules and scores it.
pub fn score(run: &Run, weights: PathBuf) -> anyhow::Result<Scores> {
    let net = run.load_dlf(&weights)?;
    let rollouts = rollouts::of_one(run, &net, "DLF")?;
    let scene = &run.scene;
    let windows = Windows::from_lengths(
        scene.frames(Role::Train).len(),
        scene.frames(Role::Test).len(),
    );
    let mut report = EvalReport::new(&run.exp.name, &scene.manifest().name, "", windows);
    let dlf = run.dlf_config();
    rollouts.measure(&mut report, scene.manifest(), 1.0, dlf.dt, dlf.gravity);
    let energy = |model: Sequence| {
        report
            .energy
            .iter()
            .find(|e| e.model == model)
            .map_or([f64::NAN; 2], |e| {
                [e.grounding_per_particle, e.prediction_per_particle]
            })
    };
    let energy_per_particle = [
        energy(Sequence::Rollout(Rollout::NeuroFluid.label().into())),
        energy(Sequence::Truth),
    ];
    let row = |r: Option<DistanceRow>| {
        r.ok_or_else(|| {
            anyhow::anyhow!(
                "{}: the test split has no frame after its first, so there is nothing to roll out",
                run.scene.root().display()
            )
        })
    };
    let m = scene.manifest();
    let outside = rollouts
        .escaped(&m.box_interior, m.particle_radius)
        .first()
        .map_or(0, |(_, n)| *n);
    Ok(Scores {
        weights,
        rules: run.exp.dlf.rules.describe(),
        d: row(report.distance_row(Rollout::NeuroFluid))?,
        d_reverse: row(report.reverse_row(Rollout::NeuroFluid))?,
        symmetric: row(report.symmetric_row(Rollout::NeuroFluid))?,
        outside,
        energy_per_particle,
    })
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    let run = Run::open_existing(args.exp.load()?)?;
    let weights = args.weights.unwrap_or_else(|| run.exp.dlf.weights.clone());
    let s = score(&run, weights)?;
    if args.json {
        println!("{}", serde_json::to_string(&s)?);
        return Ok(());
    }
    let f = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{v:.2}"));
    println!(
        "{} on {}: {}",
        s.weights.display(),
        run.scene.manifest().name,
        if s.rules.is_empty() {
            "DLF's step as published".to_string()
        } else {
            s.rules.join(", ")
        }
    );
    println!("| ({}) | t < 50 | t ≥ 50 |\n|---|---|---|", run.exp.name);
    for (label, row) in [
        ("d", &s.d),
        ("d′", &s.d_reverse),
        ("(d + d′)/2", &s.symmetric),
    ] {
        println!(
            "| {label} | {} | {} |",
            f(row.grounding_mean),
            f(row.prediction_mean)
        );
    }
    let [e, truth] = s.energy_per_particle;
    println!(
        "| energy gained per particle (J/kg; the truth's) | {:.3} ({:.3}) | {:.3} ({:.3}) |",
        e[0], truth[0], e[1], truth[1]
    );
    println!("most particles outside the box in a frame: {}", s.outside);
    Ok(())
}
