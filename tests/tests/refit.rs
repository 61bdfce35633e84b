//! The renderer refit (`refit.enabled`): a second renderer fitted to the grounded rollout after
//! the joint stage. Its warm-up is the warm-up stage's, the dynamics stay the joint stage's, the
//! evaluation renders with it, and it resumes exactly.

use std::path::Path;

use neurofluid_outputs::metrics_log::MetricsLog;
use neurofluid_tests::{params, seeded_turn, tiny_experiment};
use neurofluid_train::config::Experiment;
use neurofluid_train::stage::Stage;
use neurofluid_train::stages::views::{points_tensor, render_beside_truth};
use neurofluid_train::stages::{Run, Start, eval, joint, orbit, refit, run_all, warmup};

fn experiment(tmp: &Path, name: &str, overrides: &[&str]) -> Experiment {
    let mut e = tiny_experiment(tmp, name);
    e.apply_overrides(&["warmup.ckpt_every=0", "joint.ckpt_every=0"])
        .unwrap();
    e.apply_overrides(overrides).unwrap();
    e
}

fn prepared(e: Experiment) -> (Run, MetricsLog) {
    let run = Run::prepare(e, Start::Resume, &Stage::ALL).unwrap();
    let log = run.open_log().unwrap();
    (run, log)
}

#[test]
fn the_refit_renders_the_views_and_leaves_the_dynamics() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let before = {
        let (plain, mut log) =
            prepared(experiment(tmp.path(), "views", &["joint.preview_every=2"]));
        let report = run_all(&plain, &mut log).unwrap();
        assert!(!plain.stage_dir(Stage::Refit).exists());
        report
    };

    // the same run folder with the refit: `[refit]` shapes no earlier stage, so the warm-up and
    // the joint stage resume as they are and only the refit and the evaluation run
    let (with, mut log) = prepared(experiment(
        tmp.path(),
        "views",
        &["joint.preview_every=2", "refit.enabled=true"],
    ));
    let after = run_all(&with, &mut log).unwrap();
    assert_eq!(
        before.frames, after.frames,
        "d and d′ are the joint stage's"
    );
    assert!(before.renderer.is_none());
    assert!(
        after
            .nvs_markdown()
            .contains("the refitted PhysNeRF (`refit.enabled`, `refit.positions = \"relative\"`)")
    );
    assert_eq!(before.images.len(), after.images.len());
    assert!(
        before
            .images
            .iter()
            .zip(&after.images)
            .any(|(a, b)| a.psnr != b.psnr),
        "the views are rendered by another renderer"
    );

    // the refitted renderer moves with its particles (no γ(x): fewer inputs than the joint's)
    let grounded = joint::load_trained(&with).unwrap();
    let refitted = refit::for_views(&with, grounded.clone()).unwrap();
    assert_eq!(
        refitted.physnerf.config.positions,
        neurofluid_physnerf::Positions::Relative
    );
    let widths = |m: &neurofluid_physnerf::PhysNerf| params(m).iter().map(Vec::len).sum::<usize>();
    assert!(widths(&refitted.physnerf) < widths(&grounded.physnerf));
    assert_eq!(params(&refitted.dlf), params(&grounded.dlf));

    // `eval` alone renders with the refit's checkpoint, as `run` did
    let again = eval::run(&with, &refitted).unwrap();
    assert_eq!(again.images, after.images);

    // its rows: the warm-up phase and the fit phase, each step updating, with psnr_true
    let rows = neurofluid_outputs::metrics_log::read_jsonl(log.jsonl_path()).unwrap();
    let refit_rows: Vec<_> = rows.iter().filter(|r| r.stage == "refit").collect();
    let steps = with.exp.warmup.iters + with.exp.joint.epochs * 3;
    assert_eq!(refit_rows.len() as u64, steps, "one row per step");
    let scored = rows.iter().filter(|r| {
        r.stage.starts_with("refit")
            && r.scalars
                .iter()
                .any(|(k, v)| k == "psnr_true" && v.is_finite())
    });
    assert!(
        scored.count() >= 1,
        "the refit scores the renderer on the truth"
    );
}

/// A run with the refit at the first renderer's positions, through its joint stage: the run,
/// its log and the grounded DLF.
fn grounded_world(tmp: &Path, name: &str) -> (Run, MetricsLog, neurofluid_dlf::DlfNet) {
    let world = ["refit.enabled=true", "refit.positions=\"world\""];
    let (run, mut log) = prepared(experiment(tmp, name, &world));
    warmup::run(&run, &mut log).unwrap();
    let dlf = joint::run(&run, &mut log).unwrap().dlf;
    (run, log, dlf)
}

#[test]
fn the_refit_warms_up_as_the_warm_up_stage_and_resumes_exactly() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let (run, mut log, dlf) = grounded_world(tmp.path(), "world");
    // with the first renderer's positions, the refit's warm-up phase is the warm-up stage itself
    let iters = run.exp.warmup.iters;
    let warm = refit::run_until(&run, &mut log, &dlf, Some(iters)).unwrap();
    assert!(params(&warm) == params(&warmup::load_trained(&run).unwrap()));
    let straight = refit::run(&run, &mut log, &dlf).unwrap();
    assert!(params(&straight) != params(&warm), "the fit phase trains");

    // stopped inside the warm-up phase and inside the fit phase, resumed from the checkpoints
    let (pieces, mut log, dlf) = grounded_world(tmp.path(), "pieces");
    refit::run_until(&pieces, &mut log, &dlf, Some(iters / 2)).unwrap();
    refit::run_until(&pieces, &mut log, &dlf, Some(iters + 1)).unwrap();
    let resumed = refit::run(&pieces, &mut log, &dlf).unwrap();
    assert!(
        params(&resumed) == params(&straight),
        "the refit differs after resuming"
    );
}

/// The refit is made from the stages before it: under other settings (another `[refit]`, a
/// joint stage that went on) it starts over instead of refusing the run, turned off it is left
/// alone, and the rows a stopped refit logged past its checkpoint are dropped when it resumes.
#[test]
fn a_stale_refit_starts_over_and_each_step_is_logged_once() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let on = ["joint.preview_every=2", "refit.enabled=true"];
    let steps = {
        let (run, mut log) = prepared(experiment(tmp.path(), "stale", &on));
        warmup::run(&run, &mut log).unwrap();
        let dlf = joint::run(&run, &mut log).unwrap().dlf;
        refit::run_until(&run, &mut log, &dlf, Some(run.exp.warmup.iters + 1)).unwrap();
        // a row logged after the last checkpoint, as by a refit killed between checkpoints
        let mut jsonl = std::fs::read_to_string(log.jsonl_path()).unwrap();
        let last = jsonl
            .lines()
            .rev()
            .find(|l| l.contains("\"refit\""))
            .unwrap();
        let row: serde_json::Value = serde_json::from_str(last).unwrap();
        let mut ghost = row.clone();
        ghost["step"] = (row["step"].as_u64().unwrap() + 1).into();
        jsonl.push_str(&format!("{ghost}\n"));
        std::fs::write(log.jsonl_path(), jsonl).unwrap();
        run.exp.warmup.iters + run.exp.joint.epochs * 3
    };
    let refit_rows = |log: &MetricsLog| {
        neurofluid_outputs::metrics_log::read_jsonl(log.jsonl_path())
            .unwrap()
            .into_iter()
            .filter(|r| r.stage == "refit")
            .count() as u64
    };
    {
        let (run, mut log) = prepared(experiment(tmp.path(), "stale", &on));
        run_all(&run, &mut log).unwrap();
        assert_eq!(refit_rows(&log), steps, "one row per step after resuming");
    }
    // another `[refit]`: the run is not refused, the refit starts over with the new renderer
    let world = [&on[..], &["refit.positions=\"world\""]].concat();
    let (run, mut log) = prepared(experiment(tmp.path(), "stale", &world));
    run_all(&run, &mut log).unwrap();
    assert_eq!(refit_rows(&log), steps, "the old refit's rows went with it");
    let grounded = refit::for_views(&run, joint::load_trained(&run).unwrap()).unwrap();
    assert_eq!(
        grounded.physnerf.config.positions,
        neurofluid_physnerf::Positions::World
    );
    drop((run, log));
    // turned off, the refit's folder does not stop the run
    let (run, mut log) = prepared(experiment(tmp.path(), "stale", &["joint.preview_every=2"]));
    let report = run_all(&run, &mut log).unwrap();
    assert!(report.renderer.is_none());
}

/// With `refit.replay_rays` the refitted renderer, fitted to the grounded rollout, draws the
/// warm-up frame from all round the fluid closer to what the warm-up's renderer drew there than
/// the same refit without it; the dynamics stay the joint stage's either way.
#[test]
fn the_refit_replay_holds_the_warm_ups_renders_all_round() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let fit = |name: &str, rays: usize| {
        let overrides = [
            "refit.enabled=true",
            "refit.positions=\"world\"",
            "joint.epochs=10",
            "joint.physnerf_optim.lr=1e-3",
            &format!("refit.replay_rays={rays}"),
        ];
        let (run, mut log) = prepared(experiment(tmp.path(), name, &overrides));
        warmup::run(&run, &mut log).unwrap();
        let dlf = joint::run(&run, &mut log).unwrap().dlf;
        let renderer = refit::run(&run, &mut log, &dlf).unwrap();
        (run, renderer, dlf)
    };
    let (run, without, dlf_without) = fit("without", 0);
    let (_, with, dlf_with) = fit("with", 256);
    assert_eq!(params(&dlf_with), params(&dlf_without));
    let data = warmup::warmup_data(&run).unwrap();
    let teacher = warmup::load_trained(&run).unwrap();
    let up = run.scene.up_axis().index();
    let orbit = orbit::orbit_replay(&teacher, &data, up).unwrap().views;
    let particles = points_tensor(&data.particles, &run.device);
    let psnr = |renderer: &neurofluid_physnerf::PhysNerf| {
        orbit
            .iter()
            .map(|v| {
                render_beside_truth(renderer, v, &particles)
                    .unwrap()
                    .psnr
                    .unwrap()
            })
            .sum::<f64>()
            / orbit.len() as f64
    };
    let (a, b) = (psnr(&without), psnr(&with));
    assert!(
        b > a + 0.1,
        "the orbit against the warm-up's renders: {b:.2} dB with the replay, {a:.2} without"
    );
}
