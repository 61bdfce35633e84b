//! The evaluation's rollouts: from the same starting state (the truth of the first test frame,
//! or the particles from images), the grounded transition model, the DLF it started from and
//! DLF† roll out without feedback. What they are measured by is
//! [`neurofluid_outputs::sequences`]'s.

use anyhow::Context;
use burn::module::Module;
use neurofluid_core::scene::{Particles, Role};
use neurofluid_dlf::rollout::rollout;
use neurofluid_dlf::{DlfNet, StepRules};

use crate::stages::initial::starting_particles;
use crate::stages::joint::Grounded;
use crate::stages::run_folder::Run;
use crate::stages::views::check_sequence;
use neurofluid_outputs::sequences::{Positions, Sequences};

/// Rolls every evaluated model out over the test split of `run`.
pub fn of(run: &Run, models: &Grounded) -> anyhow::Result<Sequences> {
    let cfg = &run.exp.eval;
    let (truth, start, steps) = test_start(run)?;
    let pretrained = run.load_dlf(&run.exp.dlf.weights)?;
    let diagnostics = &run.exp.diagnostics;
    let evaluated = evaluated_dlf(&pretrained, &models.dlf, diagnostics.weight_interpolation)?;
    let grounded = positions(run, &evaluated, &start, steps, "NeuroFluid")?;
    let baseline = if cfg.baseline {
        Some(positions(run, &pretrained, &start, steps, "DLF")?)
    } else {
        None
    };
    // the paper's comparison: the published DLF as the paper steps it, where the rules differ
    let paper_step = StepRules::default();
    let published = if cfg.baseline && pretrained.config.rules != paper_step {
        let mut config = pretrained.config;
        config.rules = paper_step;
        let net = pretrained.clone().with_config(config);
        Some(positions(run, &net, &start, steps, "DLF (paper's step)")?)
    } else {
        None
    };
    let supervised = match &cfg.supervised_dlf {
        Some(path) => {
            let net = run.load_dlf(path).context("eval.supervised_dlf")?;
            Some(positions(run, &net, &start, steps, "DLF†")?)
        }
        None => None,
    };
    let interpolated = diagnostics
        .interpolation_sweep
        .iter()
        .map(|&f| {
            let net = evaluated_dlf(&pretrained, &models.dlf, f)?;
            let what = format!("NeuroFluid at {f}");
            Ok((f, positions(run, &net, &start, steps, &what)?))
        })
        .collect::<anyhow::Result<_>>()?;
    Ok(Sequences {
        truth,
        grounded,
        baseline,
        published,
        supervised,
        interpolated,
    })
}

/// The truth of the test split and one DLF's rollout from its first frame in the grounded
/// model's place (no baseline, no DLF†): a rule or weights file scored alone (`rollout`).
pub fn of_one(run: &Run, net: &DlfNet, what: &str) -> anyhow::Result<Sequences> {
    let (truth, start, steps) = test_start(run)?;
    Ok(Sequences {
        truth,
        grounded: positions(run, net, &start, steps, what)?,
        baseline: None,
        published: None,
        supervised: None,
        interpolated: Vec::new(),
    })
}

/// NeuroFluid's DLF as evaluated (`diagnostics.weight_interpolation`): `pretrained` plus `fraction` of
/// the change from it to `grounded`.
pub fn evaluated_dlf(
    pretrained: &DlfNet,
    grounded: &DlfNet,
    fraction: f64,
) -> anyhow::Result<DlfNet> {
    if fraction == 1.0 {
        return Ok(grounded.clone());
    }
    tracing::info!(
        fraction,
        "NeuroFluid's DLF: the pretrained weights plus this fraction of grounding's change"
    );
    neurofluid_core::params::interpolate(pretrained, grounded.clone(), fraction)
        .context("diagnostics.weight_interpolation: the grounded DLF against dlf.weights")
}

/// The test split's true positions, the state every rollout starts from (the truth of its first
/// frame, or the particles from images) and the number of steps.
fn test_start(run: &Run) -> anyhow::Result<(Positions, Particles, usize)> {
    let test = run.scene.frames(Role::Test);
    let truth: Vec<_> = run.scene.particle_sequence(Role::Test)?;
    check_sequence(&truth, test.start).context("the test split's particles")?;
    let start = starting_particles(run, Role::Test, test.start, "first test frame")?;
    tracing::info!(steps = test.len() - 1, "rollouts from the first test frame");
    let truth = truth.into_iter().map(|p| p.pos).collect();
    Ok((truth, start, test.len() - 1))
}

/// `net`'s rollout of `steps` steps from `start` against the scene's boundary.
fn positions(
    run: &Run,
    net: &DlfNet,
    start: &Particles,
    steps: usize,
    what: &str,
) -> anyhow::Result<Positions> {
    let net = net.valid();
    let b = run.scene.boundary()?;
    let boundary = net.boundary(&b.points, &b.normals, &net.device());
    let bar = indicatif::ProgressBar::new(steps as u64).with_prefix(what.to_string());
    let out = rollout(&net, &start.pos, &start.vel, &boundary, steps, |_| {
        bar.inc(1)
    });
    bar.finish_and_clear();
    Ok(out.pos)
}
