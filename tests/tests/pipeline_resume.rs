//! The tiny experiment end to end, and exact resume: a run stopped in the middle of the warm-up
//! and in the middle of a joint epoch (with a carried particle state) and resumed from its
//! checkpoints ends with the same parameters as a run that never stopped.

use std::path::Path;

use neurofluid_outputs::metrics_log::MetricsLog;
use neurofluid_outputs::report::{Rollout, Sequence};
use neurofluid_tests::{params, seeded_turn, tiny_resumable_experiment};
use neurofluid_train::commands::rollout;
use neurofluid_train::config::Experiment;
use neurofluid_train::stage::Stage;
use neurofluid_train::stages::{Run, Start, eval, joint, warmup};

fn experiment(tmp: &Path, name: &str) -> Experiment {
    tiny_resumable_experiment(tmp, name)
}

#[test]
fn resumed_run_matches_uninterrupted_run() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();

    // DLF† given as the pretrained weights themselves: its rollout must be the baseline's
    let mut e = experiment(tmp.path(), "straight");
    e.eval.supervised_dlf = Some(e.dlf.weights.clone());
    let straight = Run::prepare(e, Start::Resume, &Stage::ALL).unwrap();
    let mut log = MetricsLog::open(&straight.dir).unwrap();
    warmup::run(&straight, &mut log).unwrap();
    let a = joint::run(&straight, &mut log).unwrap();

    let pieces =
        Run::prepare(experiment(tmp.path(), "pieces"), Start::Resume, &Stage::ALL).unwrap();
    let mut log = MetricsLog::open(&pieces.dir).unwrap();
    let warm_iters = pieces.exp.warmup.iters;
    assert!(warm_iters >= 2);
    warmup::run_until(&pieces, &mut log, Some(warm_iters / 2)).unwrap();
    warmup::run(&pieces, &mut log).unwrap();
    // stop inside the first epoch: the carried (predicted) state goes into the checkpoint
    joint::run_until(&pieces, &mut log, Some(2)).unwrap();
    let b = joint::run(&pieces, &mut log).unwrap();

    let (pa, pb) = (params(&a.physnerf), params(&b.physnerf));
    assert_eq!(pa.len(), pb.len());
    let (da, db) = (params(&a.dlf), params(&b.dlf));
    // on every backend: the sums of rows run in a fixed order, without atomic adds
    assert!(pa == pb, "PhysNeRF parameters differ after resuming");
    assert!(da == db, "DLF parameters differ after resuming");
    // and training did change the transition model
    let start = straight.load_dlf(&straight.exp.dlf.weights).unwrap();
    assert!(
        params(&start) != params(&a.dlf),
        "joint training left DLF unchanged"
    );

    // the evaluation runs on the result and reports both models
    let report = eval::run(&straight, &a).unwrap();
    let s = report.summary();
    assert!(s.grounding.d_of(Rollout::NeuroFluid).unwrap().is_finite());
    assert!(s.grounding.d_of(Rollout::Dlf).unwrap().is_finite());
    for f in &report.frames {
        assert_eq!(
            Rollout::SupervisedDlf.of(f),
            Rollout::Dlf.of(f),
            "DLF† of the same weights, t = {}",
            f.t
        );
    }
    assert!(
        report
            .markdown()
            .contains("| DLF† (supervised on the training frames) |")
    );
    // `rollout` scores the pretrained DLF as the evaluation's DLF row does
    let alone = rollout::score(&straight, straight.exp.dlf.weights.clone()).unwrap();
    assert_eq!(Some(alone.d), report.distance_row(Rollout::Dlf));
    assert_eq!(Some(alone.d_reverse), report.reverse_row(Rollout::Dlf));
    // and the energy each particle gained, the rollout's and the truth's, as the report's rows
    let per_particle = |model: Sequence| {
        let e = report.energy.iter().find(|e| e.model == model).unwrap();
        [e.grounding_per_particle, e.prediction_per_particle]
    };
    assert_eq!(
        alone.energy_per_particle,
        [
            per_particle(Sequence::Rollout("DLF".into())),
            per_particle(Sequence::Truth)
        ]
    );
    let plot = straight.dir.join("eval").join(eval::DISTANCE_PLOT);
    assert_eq!(image::image_dimensions(&plot).unwrap(), (720, 360));
    assert!(
        straight.dir.join("eval").join("report.json").is_file()
            || straight.dir.join("eval").read_dir().unwrap().count() > 0
    );
}

#[test]
fn stratified_jitter_is_seeded_and_reproducible() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let mut params_of = Vec::new();
    for name in ["jitter-a", "jitter-b"] {
        let mut e = experiment(tmp.path(), name);
        e.apply_overrides(&["physnerf.stratified=true"]).unwrap();
        let run = Run::prepare(e, Start::Resume, &Stage::ALL).unwrap();
        let mut log = MetricsLog::open(&run.dir).unwrap();
        params_of.push(params(&warmup::run(&run, &mut log).unwrap()));
    }
    assert!(
        params_of[0] == params_of[1],
        "same seed, different jittered warm-up"
    );
}

#[test]
fn resumed_metrics_log_has_no_duplicate_steps() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let run = Run::prepare(experiment(tmp.path(), "log"), Start::Resume, &Stage::ALL).unwrap();
    let mut log = run.open_log().unwrap();
    warmup::run_until(&run, &mut log, Some(2)).unwrap();
    // a row logged after the last checkpoint, as a crash would leave it
    log.append(&neurofluid_outputs::metrics_log::MetricsRow::new(
        "warmup", 3, 0.5, 1.0,
    ))
    .unwrap();
    drop(log);
    let mut log = run.open_log().unwrap();
    warmup::run(&run, &mut log).unwrap();
    let rows = neurofluid_outputs::metrics_log::read_jsonl(log.jsonl_path()).unwrap();
    let steps: Vec<u64> = rows
        .iter()
        .filter(|r| r.stage == "warmup")
        .map(|r| r.step)
        .collect();
    assert_eq!(steps, (1..=run.exp.warmup.iters).collect::<Vec<_>>());
}

#[test]
fn resume_refuses_changed_settings_and_records_safe_changes() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let run = Run::prepare(experiment(tmp.path(), "guard"), Start::Resume, &Stage::ALL).unwrap();
    let mut log = run.open_log().unwrap();
    warmup::run_until(&run, &mut log, Some(2)).unwrap();
    drop(log);
    // the run folder is locked while a run holds it
    let err = Run::prepare(experiment(tmp.path(), "guard"), Start::Resume, &Stage::ALL)
        .unwrap_err()
        .to_string();
    assert!(err.contains("in use by another process"), "{err}");
    drop(run);

    // a learning rate shapes the state: refused before anything runs, naming the key and the
    // way out; and the stage itself refuses it too
    let mut changed = experiment(tmp.path(), "guard");
    changed.apply_override("warmup.optim.lr=1e-3").unwrap();
    let err = format!(
        "{:#}",
        Run::prepare(changed.clone(), Start::Resume, &Stage::ALL).unwrap_err()
    );
    assert!(err.contains("warmup.optim.lr"), "{err}");
    assert!(err.contains("--fresh"), "{err}");
    let run2 = Run::prepare(changed, Start::Resume, &[]).unwrap();
    let mut log = run2.open_log().unwrap();
    let err = warmup::run(&run2, &mut log).unwrap_err().to_string();
    assert!(err.contains("warmup.optim.lr"), "{err}");
    drop(log);
    drop(run2);

    // --fresh of a later stage keeps the earlier ones; a folder the tool did not make is left
    // alone
    let run4 = Run::prepare(experiment(tmp.path(), "guard"), Start::Resume, &Stage::ALL).unwrap();
    let mut log = run4.open_log().unwrap();
    warmup::run(&run4, &mut log).unwrap();
    drop(log);
    std::fs::create_dir_all(run4.stage_dir(Stage::Eval)).unwrap();
    drop(run4);
    let run5 = Run::prepare(
        experiment(tmp.path(), "guard"),
        Start::Fresh,
        &[Stage::Joint],
    )
    .unwrap();
    assert!(run5.stage_dir(Stage::Warmup).join("checkpoint").is_dir());
    assert!(!run5.stage_dir(Stage::Eval).exists());
    drop(run5);
    let foreign = tmp.path().join("foreign");
    std::fs::create_dir_all(foreign.join("warmup")).unwrap();
    let mut e = experiment(tmp.path(), "foreign");
    e.out_dir = Some(foreign.clone());
    drop(Run::prepare(e, Start::Fresh, &Stage::ALL).unwrap());
    assert!(foreign.join("warmup").is_dir());

    // the logging cadence does not: resumed, and the change is recorded
    let mut safe = experiment(tmp.path(), "guard");
    safe.apply_override("warmup.log_every=2").unwrap();
    let run3 = Run::prepare(safe, Start::Resume, &Stage::ALL).unwrap();
    let mut log = run3.open_log().unwrap();
    warmup::run(&run3, &mut log).unwrap();
    let history = std::fs::read_to_string(run3.dir.join("config.history")).unwrap();
    assert!(history.contains("warmup.log_every"), "{history}");
}
