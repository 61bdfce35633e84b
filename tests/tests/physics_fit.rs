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

/// `settle`: the fit is held after the first held epoch (from the second) over which no fitted
/// scalar moved by more than that share of its range, or at the latest after `hold_dlf_epochs`.
/// Until then DLF's weights take no step; from then the scalars take none and DLF's weights do.
/// Both runs stop at the hold and resume, so the hold is also carried by the checkpoint.
#[test]
fn a_settled_fit_is_held_while_dlf_is_grounded() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    // a share of 0.99 settles at the first comparison (after epoch 2); 1e-9 only at the cap (3)
    for (settle, held_after) in [(0.99, 2u64), (1e-9, 3)] {
        let mut e = experiment(tmp.path(), &format!("settle-{settle}"));
        e.apply_overrides(&[
            "joint.epochs=4".to_string(),
            "joint.physics.hold_dlf_epochs=3".to_string(),
            format!("joint.physics.settle={settle}"),
        ])
        .unwrap();
        let run = Run::prepare(e, Start::Resume, &Stage::ALL).unwrap();
        let start = run.exp.dlf.rules;
        let pretrained = run.load_dlf(&run.exp.dlf.weights).unwrap();
        let mut log = MetricsLog::open(&run.dir).unwrap();
        warmup::run(&run, &mut log).unwrap();
        let transitions = run.scene.frames(neurofluid_core::scene::Role::Train).len() as u64 - 1;
        joint::run_until(&run, &mut log, Some(held_after * transitions)).unwrap();
        let at_hold = joint::load_trained(&run).unwrap();
        assert!(
            params(&at_hold.dlf) == params(&pretrained),
            "settle {settle}: DLF's weights moved before the fit was held"
        );
        assert_ne!(at_hold.dlf.config.rules, start, "settle {settle}: no fit");
        let end = joint::run(&run, &mut log).unwrap();
        assert_eq!(
            end.dlf.config.rules, at_hold.dlf.config.rules,
            "settle {settle}: the scalars moved after the hold"
        );
        assert!(
            params(&end.dlf) != params(&pretrained),
            "settle {settle}: DLF was not grounded after the hold"
        );
        let rows = read_jsonl(&run.dir.join("metrics.jsonl")).unwrap();
        let held: Vec<f64> = rows
            .iter()
            .filter(|r| r.stage == "joint")
            .filter_map(|r| r.get("physics/held_after_epoch"))
            .collect();
        assert!(!held.is_empty(), "settle {settle}: the hold is not logged");
        assert!(
            held.iter().all(|&h| h == held_after as f64),
            "settle {settle}: held after {held:?}, expected {held_after}"
        );
    }
}

/// `shrink`: each fitted damping is moved toward 0 after every update, so with a step larger than
/// any update the images can make it stays at 0, while the gravity scale is fitted as without it
/// and a damping not fitted keeps the rules' constant.
#[test]
fn a_shrunk_damping_stays_off_unless_the_images_push_it() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let mut e = experiment(tmp.path(), "shrink");
    e.apply_overrides(&[
        "joint.epochs=1",
        "joint.physics.fit=[\"gravity_scale\", \"dissipation\"]",
        "joint.physics.shrink=1.0",
    ])
    .unwrap();
    let run = Run::prepare(e, Start::Resume, &Stage::ALL).unwrap();
    let start = run.exp.dlf.rules;
    let mut log = MetricsLog::open(&run.dir).unwrap();
    warmup::run(&run, &mut log).unwrap();
    let rules = joint::run(&run, &mut log).unwrap().dlf.config.rules;
    assert_eq!(rules.dissipation, 0.0, "the dissipation was not shrunk off");
    // (the scalars are held in f32)
    assert_eq!(
        rules.viscosity as f32, start.viscosity as f32,
        "a damping not fitted moved"
    );
    assert_ne!(
        rules.gravity_scale, start.gravity_scale,
        "the gravity scale was not fitted"
    );
}
