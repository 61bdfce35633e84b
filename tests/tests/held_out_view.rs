//! A warm-up view held out of the warm-up (`warmup.held_out`): the warm-up trains on the other
//! views exactly as if they were the only ones, and its previews score the held-out view at the
//! warm-up's frame, a novel view from the training images alone.

use std::path::Path;

use neurofluid_core::scene::Role;
use neurofluid_core::tensors::points_tensor;
use neurofluid_outputs::metrics_log::read_jsonl;
use neurofluid_physnerf::render_image;
use neurofluid_tests::{params, seeded_turn, tiny_experiment};
use neurofluid_train::config::Experiment;
use neurofluid_train::stage::Stage;
use neurofluid_train::stages::views::ViewFrame;
use neurofluid_train::stages::{Run, Start, joint, refit, warmup};

fn experiment(tmp: &Path, name: &str, overrides: &[&str]) -> Experiment {
    let mut e = tiny_experiment(tmp, name);
    e.apply_overrides(&["warmup.ckpt_every=0", "warmup.preview_every=2"])
        .unwrap();
    e.apply_overrides(overrides).unwrap();
    e
}

/// PSNR of PhysNeRF's render of `view` at frame 0 of `role`, computed here from the pixels.
fn psnr_of(run: &Run, physnerf: &neurofluid_physnerf::PhysNerf, role: Role, view: &str) -> f64 {
    let t0 = run.scene.frames(Role::Warmup).start;
    let target = ViewFrame::load(&run.scene, role, view, t0).unwrap();
    let particles = run.scene.particles(Role::Warmup, t0).unwrap().pos;
    let particles = points_tensor(&particles, &physnerf.device());
    let image = render_image(physnerf, &target.camera, &particles, 1024, &mut |_, _| {}).unwrap();
    let pred = image.best();
    let truth = &target.image.rgb;
    assert_eq!(pred.len(), truth.len());
    let mse = pred
        .iter()
        .zip(truth)
        .map(|(a, b)| f64::from(a - b).powi(2))
        .sum::<f64>()
        / pred.len() as f64;
    -10.0 * mse.log10()
}

#[test]
fn a_held_out_view_leaves_the_warmup_and_is_what_its_previews_score() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let held = Run::prepare(
        experiment(tmp.path(), "held", &["warmup.held_out=\"view_2\""]),
        Start::Fresh,
        &[Stage::Warmup],
    )
    .unwrap();
    let all = held.scene.views(Role::Warmup).to_vec();
    assert!(all.len() >= 2 && all.contains(&"view_2".to_string()));
    let others: Vec<String> = all.iter().filter(|v| *v != "view_2").cloned().collect();
    assert_eq!(held.exp.warmup.views(&held.scene), others);

    let mut log = held.open_log().unwrap();
    let trained = warmup::run(&held, &mut log).unwrap();

    // the same warm-up as one told only the other views: the same weights, bit for bit
    let listed = format!(
        "warmup.views=[{}]",
        others
            .iter()
            .map(|v| format!("\"{v}\""))
            .collect::<Vec<_>>()
            .join(", ")
    );
    let plain = Run::prepare(
        experiment(tmp.path(), "plain", &[&listed]),
        Start::Fresh,
        &[Stage::Warmup],
    )
    .unwrap();
    let mut plain_log = plain.open_log().unwrap();
    let without = warmup::run(&plain, &mut plain_log).unwrap();
    assert!(params(&trained) == params(&without));

    // the previews score the held-out warm-up view at frame 0, the plain run's the test view
    let last = |jsonl: &Path| {
        let rows = read_jsonl(jsonl).unwrap();
        let row = rows
            .iter()
            .rev()
            .find(|r| r.stage == "warmup-preview")
            .expect("a preview row")
            .clone();
        assert_eq!(row.step, held.exp.warmup.iters);
        row.scalars.iter().find(|(k, _)| k == "psnr").unwrap().1
    };
    let scored = last(log.jsonl_path());
    let expected = psnr_of(&held, &trained, Role::Warmup, "view_2");
    assert!((scored - expected).abs() < 1e-3, "{scored} vs {expected}");
    let test_view = held.scene.views(Role::Test)[0].clone();
    let on_test = psnr_of(&held, &trained, Role::Test, &test_view);
    assert!((last(plain_log.jsonl_path()) - on_test).abs() < 1e-3);
    assert!(
        (scored - on_test).abs() > 1e-3,
        "another view, another score"
    );
}

#[test]
fn the_joint_stage_scores_the_held_out_view_after_grounding() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let e = experiment(
        tmp.path(),
        "joint",
        &["warmup.held_out=\"view_3\"", "joint.preview_every=3"],
    );
    let run = Run::prepare(e, Start::Fresh, &[Stage::Warmup, Stage::Joint]).unwrap();
    let mut log = run.open_log().unwrap();
    warmup::run(&run, &mut log).unwrap();
    let grounded = joint::run(&run, &mut log).unwrap();
    let rows = read_jsonl(log.jsonl_path()).unwrap();
    let scored: Vec<(u64, f64)> = rows
        .iter()
        .filter(|r| r.stage == "joint-preview")
        .filter_map(|r| {
            let v = r.scalars.iter().find(|(k, _)| k == "psnr_held_out")?;
            Some((r.step, v.1))
        })
        .collect();
    assert_eq!(
        scored.len(),
        1,
        "one evaluation, at the epoch's end: {scored:?}"
    );
    // the last evaluation follows the last update: the grounded renderer on view_3 at frame 0
    let expected = psnr_of(&run, &grounded.physnerf, Role::Warmup, "view_3");
    assert!(
        (scored[0].1 - expected).abs() < 1e-3,
        "{scored:?} vs {expected}"
    );
    // and not the warm-up's renderer: grounding moved it
    let warmed = warmup::load_trained(&run).unwrap();
    assert!((psnr_of(&run, &warmed, Role::Warmup, "view_3") - expected).abs() > 1e-4);
}

#[test]
fn a_held_out_view_must_be_a_warmup_view_and_leave_one() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let training_view = {
        let e = experiment(tmp.path(), "probe", &[]);
        let run = Run::prepare(e, Start::Fresh, &[Stage::Warmup]).unwrap();
        run.exp.joint.view(&run.scene).unwrap()
    };
    let trained_on = format!("warmup.held_out=\"{training_view}\"");
    for (overrides, expected) in [
        (
            vec!["warmup.held_out=\"view_9\""],
            "expected one of the warm-up views",
        ),
        (
            vec!["warmup.views=[\"view_2\"]", "warmup.held_out=\"view_2\""],
            "the only warm-up view",
        ),
        (
            vec![trained_on.as_str()],
            "a view the joint stage trains on",
        ),
    ] {
        // refused whichever stage is asked for: the NeRFs see the warm-up's views too
        for stages in [&[Stage::Warmup][..], &[Stage::Nerf]] {
            let e = experiment(tmp.path(), "bad", &overrides);
            let Err(err) = Run::prepare(e, Start::Fresh, stages) else {
                panic!("{overrides:?} was not refused for {stages:?}");
            };
            let message = format!("{err:#}");
            assert!(message.contains("warmup.held_out"), "{message}");
            assert!(message.contains(expected), "{message}");
        }
    }
    // a view listed twice is no second view: refused where the views are set
    let mut e = experiment(tmp.path(), "twice", &[]);
    let err = e
        .apply_overrides(&["warmup.views=[\"view_2\", \"view_2\"]"])
        .unwrap_err();
    assert_eq!(err.key(), "warmup.views");
    assert!(err.to_string().contains("listed twice"), "{err}");
}

#[test]
fn the_refit_scores_the_held_out_view_after_its_fit() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let e = experiment(
        tmp.path(),
        "refit",
        &[
            "warmup.held_out=\"view_3\"",
            "joint.preview_every=1",
            "refit.enabled=true",
            "refit.positions=\"world\"",
        ],
    );
    let run = Run::prepare(e, Start::Fresh, &Stage::ALL).unwrap();
    let mut log = run.open_log().unwrap();
    warmup::run(&run, &mut log).unwrap();
    let dlf = joint::run(&run, &mut log).unwrap().dlf;
    let refitted = refit::run(&run, &mut log, &dlf).unwrap();
    let rows = read_jsonl(log.jsonl_path()).unwrap();
    let last = rows
        .iter()
        .filter(|r| r.stage.starts_with("refit"))
        .filter_map(|r| {
            let v = r.scalars.iter().find(|(k, _)| k == "psnr_held_out")?;
            Some((r.step, v.1))
        })
        .max_by_key(|(step, _)| *step)
        .expect("the refit scores the held-out view");
    let steps = run.exp.warmup.iters + run.exp.joint.epochs * 3;
    assert_eq!(
        last.0, steps,
        "the last evaluation is the refit's last step"
    );
    let expected = psnr_of(&run, &refitted, Role::Warmup, "view_3");
    assert!((last.1 - expected).abs() < 1e-3, "{last:?} vs {expected}");
    let warmed = warmup::load_trained(&run).unwrap();
    assert!((psnr_of(&run, &warmed, Role::Warmup, "view_3") - expected).abs() > 1e-4);
}
