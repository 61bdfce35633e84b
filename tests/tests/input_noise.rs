//! `joint.input_noise`: noise on the velocities of the joint stage's training rollout changes
//! what the joint stage learns, and a run stopped inside an epoch and resumed ends with the same
//! DLF as one that never stopped (the noise of each iteration is fixed by the seed and the step).

use std::path::Path;

use neurofluid_outputs::metrics_log::MetricsLog;
use neurofluid_tests::{params, seeded_turn, tiny_resumable_experiment};
use neurofluid_train::config::Experiment;
use neurofluid_train::stage::Stage;
use neurofluid_train::stages::{Run, Start, joint, warmup};

fn experiment(tmp: &Path, name: &str, noise: f64) -> Experiment {
    let mut e = tiny_resumable_experiment(tmp, name);
    e.apply_overrides(&[format!("joint.input_noise={noise}").as_str()])
        .unwrap();
    e
}

#[test]
fn input_noise_changes_the_grounding_and_resumes_exactly() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let prepare = |name, noise| {
        Run::prepare(
            experiment(tmp.path(), name, noise),
            Start::Resume,
            &Stage::ALL,
        )
        .unwrap()
    };

    let clean = prepare("clean", 0.0);
    let mut log = MetricsLog::open(&clean.dir).unwrap();
    warmup::run(&clean, &mut log).unwrap();
    let without = joint::run(&clean, &mut log).unwrap();

    let straight = prepare("straight", 0.2);
    let mut log = MetricsLog::open(&straight.dir).unwrap();
    warmup::run(&straight, &mut log).unwrap();
    let a = joint::run(&straight, &mut log).unwrap();
    assert!(
        params(&a.dlf) != params(&without.dlf),
        "the noise did not change what DLF learned"
    );

    let pieces = prepare("pieces", 0.2);
    let mut log = MetricsLog::open(&pieces.dir).unwrap();
    warmup::run(&pieces, &mut log).unwrap();
    joint::run_until(&pieces, &mut log, Some(2)).unwrap();
    let b = joint::run(&pieces, &mut log).unwrap();
    assert!(
        params(&a.dlf) == params(&b.dlf),
        "DLF differs after resuming with input noise"
    );
}
