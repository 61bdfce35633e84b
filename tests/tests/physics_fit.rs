//! `[joint.physics]`: the joint stage fits DLF's gravity scale, viscosity and dissipation from
//! the images, with their own Adam: on the tiny experiment the values move from the `[dlf]`
//! rules', stay within their bounds, are logged at every update (`physics/<name>`), step the
//! grounded DLF's later rollouts, and a run stopped inside an epoch and resumed ends with the same
//! values (and the same DLF) as one that never stopped.

use std::path::Path;

use neurofluid_outputs::metrics_log::{MetricsLog, read_jsonl};
use neurofluid_tests::{params, seeded_turn, tiny_resumable_experiment};
use neurofluid_train::config::Experiment;
use neurofluid_train::stage::Stage;
use neurofluid_train::stages::{Run, Start, eval, joint, warmup};

fn experiment(tmp: &Path, name: &str) -> Experiment {
    let mut e = tiny_resumable_experiment(tmp, name);
    e.apply_overrides(&[
        "dlf.gravity_scale=1.5",
        "dlf.viscosity=0.1",
        "dlf.dissipation=0.02",
        "joint.physics.fit=[\"gravity_scale\", \"viscosity\", \"dissipation\"]",
        "joint.physics.optim.lr=0.02",
    ])
    .unwrap();
    e
}

#[test]
fn the_joint_stage_fits_the_physical_scalars_and_resumes_exactly() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();

    let straight = Run::prepare(
        experiment(tmp.path(), "straight"),
        Start::Resume,
        &Stage::ALL,
    )
    .unwrap();
    let start = straight.exp.dlf.rules;
    let mut log = MetricsLog::open(&straight.dir).unwrap();
    warmup::run(&straight, &mut log).unwrap();
    let a = joint::run(&straight, &mut log).unwrap();
    let fitted = a.dlf.config.rules;
    eprintln!("fitted {fitted:?} from {start:?}");
    let moved = [
        (fitted.gravity_scale, start.gravity_scale, (0.25, 4.0)),
        (fitted.viscosity, start.viscosity, (0.0, 1.0)),
        (fitted.dissipation, start.dissipation, (0.0, 0.5)),
    ];
    for (value, from, (lo, hi)) in moved {
        assert!(
            value != from,
            "{fitted:?} against {start:?}: a scalar did not move"
        );
        assert!((lo..=hi).contains(&value), "{fitted:?} out of bounds");
    }
    // each update's values in the metrics, the last one the grounded DLF's
    let rows = read_jsonl(&straight.dir.join("metrics.jsonl")).unwrap();
    let joint_rows: Vec<_> = rows
        .iter()
        .filter(|r| r.stage == "joint" && r.get("physics/gravity_scale").is_some())
        .collect();
    assert!(
        !joint_rows.is_empty(),
        "no physics/* columns in the metrics"
    );
    let last = joint_rows.last().unwrap();
    assert!((last.get("physics/viscosity").unwrap() - fitted.viscosity).abs() < 1e-6);
    // the evaluation's rollouts load the grounded DLF with the fitted values
    let loaded = joint::load_trained(&straight).unwrap();
    assert_eq!(loaded.dlf.config.rules, fitted);
    // and the report says what was fitted, from what
    let report = eval::run(&straight, &loaded).unwrap();
    assert_eq!(report.fitted_physics.len(), 3);
    assert_eq!(report.fitted_physics[1].value, fitted.viscosity);
    assert_eq!(report.fitted_physics[1].from, start.viscosity);
    assert!(
        report
            .markdown()
            .contains("the physical scalars the images fitted")
    );

    let pieces =
        Run::prepare(experiment(tmp.path(), "pieces"), Start::Resume, &Stage::ALL).unwrap();
    let mut log = MetricsLog::open(&pieces.dir).unwrap();
    warmup::run(&pieces, &mut log).unwrap();
    joint::run_until(&pieces, &mut log, Some(2)).unwrap();
    let b = joint::run(&pieces, &mut log).unwrap();
    assert_eq!(
        b.dlf.config.rules, fitted,
        "the values differ after resuming"
    );
    assert!(
        params(&a.dlf) == params(&b.dlf),
        "DLF differs after resuming"
    );
}

/// `hold_dlf_epochs`: while DLF is held its weights take no step and the scalars still move;
/// after it, DLF is grounded with them.
#[test]
fn a_held_dlf_takes_no_step_while_the_scalars_move() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let mut e = experiment(tmp.path(), "held");
    e.apply_overrides(&["joint.epochs=2", "joint.physics.hold_dlf_epochs=1"])
        .unwrap();
    let run = Run::prepare(e, Start::Resume, &Stage::ALL).unwrap();
    let pretrained = run.load_dlf(&run.exp.dlf.weights).unwrap();
    let mut log = MetricsLog::open(&run.dir).unwrap();
    warmup::run(&run, &mut log).unwrap();
    // the first epoch: DLF held
    let transitions = run.scene.frames(neurofluid_core::scene::Role::Train).len() as u64 - 1;
    joint::run_until(&run, &mut log, Some(transitions)).unwrap();
    let held = joint::load_trained(&run).unwrap();
    assert!(
        params(&held.dlf) == params(&pretrained),
        "DLF's weights moved while held"
    );
    assert_ne!(
        held.dlf.config.rules.gravity_scale, 1.5,
        "the scalars did not move while DLF was held"
    );
    // the second: grounded with them
    let grounded = joint::run(&run, &mut log).unwrap();
    assert!(
        params(&grounded.dlf) != params(&pretrained),
        "DLF was never grounded after the held epochs"
    );
}

/// The anchor holds DLF's weights near the pretrained ones, not the physical scalars near the
/// rules' constants: with DLF held it costs exactly nothing, so the scalars fitted with an anchor
/// are those fitted without one, to the bit (anchored to the rules' constants, it pulled a
/// fitted gravity scale back toward them: docs/notebook/2026-12-05-quick-reference.md, U5).
#[test]
fn the_anchor_leaves_the_fitted_scalars_to_the_images() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let fitted = |anchor: f64| {
        let mut e = experiment(tmp.path(), &format!("anchor-{anchor}"));
        e.apply_overrides(&[
            "joint.epochs=1".to_string(),
            "joint.physics.hold_dlf_epochs=1".to_string(),
            format!("joint.terms.anchor.weight={anchor}"),
        ])
        .unwrap();
        let run = Run::prepare(e, Start::Resume, &Stage::ALL).unwrap();
        let mut log = MetricsLog::open(&run.dir).unwrap();
        warmup::run(&run, &mut log).unwrap();
        let start = run.exp.dlf.rules;
        let rules = joint::run(&run, &mut log).unwrap().dlf.config.rules;
        assert_ne!(rules, start, "the scalars did not move");
        rules
    };
    assert_eq!(fitted(0.0), fitted(1.0));
}
