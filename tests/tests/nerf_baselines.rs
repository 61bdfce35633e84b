//! The NeRF baselines and the initial particles from images through the trainer: NeRF-T needs
//! the warm-up views at every frame and says how to get them; a baseline resumes exactly and is
//! scored on NeuroFluid's test frames; recovered initial particles feed every stage of `run`;
//! a NeRF that sees no fluid is refused with the reason.

use std::path::Path;

use neurofluid_core::scene::{Particles, Role};
use neurofluid_outputs::metrics_log::MetricsLog;
use neurofluid_outputs::scoring::rendered_steps;
use neurofluid_tests::{params, seeded_turn, tiny_experiment};
use neurofluid_train::config::Experiment;
use neurofluid_train::stage::Stage;
use neurofluid_train::stages::joint::{JointData, JointTrainer};
use neurofluid_train::stages::nerf::{self, NerfData, NerfKind};
use neurofluid_train::stages::{Run, Start, baseline, eval, initial, run_all, warmup};
use neurofluid_train::trainer::Trainer;

/// The tiny experiment with a tiny NeRF; `every_frame` renders the warm-up views at every frame.
fn experiment(tmp: &Path, name: &str, every_frame: bool, iters: u64) -> Experiment {
    let mut e = tiny_experiment(tmp, name);
    e.scene.dir = Some(tmp.join(if every_frame { "scene_all" } else { "scene" }));
    e.apply_overrides(&[
        format!("nerf.iters={iters}"),
        "nerf.rays=96".into(),
        "nerf.ckpt_every=3".into(),
        "nerf.log_every=1".into(),
        "nerf.preview_every=0".into(),
        "nerf.precrop_iters=2".into(),
        "nerf.model.width=16".into(),
        "nerf.model.skip=1".into(),
        "nerf.model.depth=3".into(),
        "nerf.model.n_samples=8".into(),
        "nerf.model.n_importance=8".into(),
        format!("scene.generate.warmup_every_frame={every_frame}"),
    ])
    .unwrap();
    e
}

#[test]
fn nerf_t_needs_the_warmup_views_at_every_frame() {
    let tmp = tempfile::tempdir().unwrap();
    let e = experiment(tmp.path(), "t", false, 3);
    let err = Run::prepare(e, Start::Resume, &[Stage::NerfT])
        .unwrap_err()
        .to_string();
    assert!(err.contains("warmup_every_frame"), "{err}");
    // asking for them regenerates the scene with them
    let e = experiment(tmp.path(), "t", true, 3);
    let run = Run::prepare(e, Start::Resume, &[Stage::NerfT]).unwrap();
    let scene = &run.scene;
    assert_eq!(scene.frames(Role::Warmup), scene.frames(Role::Train));
    // every warm-up view sees the same particles at a frame, from its own camera
    let t = scene.frames(Role::Train).end - 1;
    let views = scene.views(Role::Warmup);
    let first = scene.image(Role::Warmup, &views[0], t).unwrap();
    let p0 = scene.particles(Role::Train, t).unwrap();
    for v in &views[1..] {
        assert_ne!(
            scene.image(Role::Warmup, v, t).unwrap().rgb,
            first.rgb,
            "{v}"
        );
        let path = scene
            .view_split(Role::Warmup, v)
            .unwrap()
            .particle_path(t)
            .unwrap();
        assert_eq!(Particles::read(&path).unwrap().pos, p0.pos, "{v}");
    }
}

#[test]
fn nerf_t_on_neurofluids_images_sees_the_warmup_frame_and_the_joint_views() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    // the rig: warm-up views at frame 0 only, which the cycling protocol refuses
    let mut e = experiment(tmp.path(), "same", false, 2);
    e.apply_overrides(&["nerf.t_images=\"neurofluid\""])
        .unwrap();
    let run = Run::prepare(e, Start::Resume, &[Stage::NerfT]).unwrap();
    let scene = &run.scene;
    let data = NerfData::load(scene, NerfKind::NerfT, &run.exp, false).unwrap();
    let (warm, train) = (scene.frames(Role::Warmup), scene.frames(Role::Train));
    let views = scene.views(Role::Warmup);
    let joint = scene.views(Role::Train)[0].clone();
    let mut expected: Vec<(Role, String, usize)> = views
        .iter()
        .map(|v| (Role::Warmup, v.clone(), warm.start))
        .collect();
    expected.extend(train.clone().map(|t| (Role::Train, joint.clone(), t)));
    assert_eq!(data.images.len(), expected.len());
    for (image, (role, view, t)) in data.images.iter().zip(&expected) {
        assert_eq!(
            image.view.image.rgb,
            scene.image(*role, view, *t).unwrap().rgb
        );
        assert_eq!(image.time, Some(nerf::time_of(*t, &train)), "{view} {t}");
    }
    let mut log = run.open_log().unwrap();
    let model = nerf::train(&run, &mut log, NerfKind::NerfT).unwrap();
    let scores = baseline::evaluate(&run, &model, NerfKind::NerfT).unwrap();
    assert_eq!(scores.model, "NeRF-T (NeuroFluid's images)");

    // with joint.extra_views those views join at every training frame, as in the joint stage
    let mut e = experiment(tmp.path(), "same_extra", true, 2);
    let extra = views[1].clone();
    e.apply_overrides(&[
        "nerf.t_images=\"neurofluid\"".to_string(),
        format!("joint.extra_views=[\"{extra}\"]"),
    ])
    .unwrap();
    let run = Run::prepare(e, Start::Resume, &[Stage::NerfT]).unwrap();
    let data = NerfData::load(&run.scene, NerfKind::NerfT, &run.exp, false).unwrap();
    let frames = run.scene.frames(Role::Train).len();
    assert_eq!(data.images.len(), views.len() + 2 * frames);
    let last = data.images.last().unwrap();
    let t = run.scene.frames(Role::Train).end - 1;
    assert_eq!(
        last.view.image.rgb,
        run.scene.image(Role::Warmup, &extra, t).unwrap().rgb
    );
}

#[test]
fn a_baseline_resumes_exactly_and_is_scored_on_the_test_frames() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let straight = Run::prepare(
        experiment(tmp.path(), "straight", true, 6),
        Start::Resume,
        &[Stage::NerfT],
    )
    .unwrap();
    let mut log = MetricsLog::open(&straight.dir).unwrap();
    let a = nerf::train(&straight, &mut log, NerfKind::NerfT).unwrap();

    let first = Run::prepare(
        experiment(tmp.path(), "pieces", true, 3),
        Start::Resume,
        &[Stage::NerfT],
    )
    .unwrap();
    let mut log = first.open_log().unwrap();
    nerf::train(&first, &mut log, NerfKind::NerfT).unwrap();
    drop((log, first));
    let second = Run::prepare(
        experiment(tmp.path(), "pieces", true, 6),
        Start::Resume,
        &[Stage::NerfT],
    )
    .unwrap();
    let mut log = second.open_log().unwrap();
    let b = nerf::train(&second, &mut log, NerfKind::NerfT).unwrap();
    assert_eq!(params(&a), params(&b), "the resumed NeRF-T differs");
    let rows = neurofluid_outputs::metrics_log::read_jsonl(log.jsonl_path())
        .unwrap()
        .iter()
        .filter(|r| r.stage == "nerf-t")
        .count();
    assert_eq!(rows, 6, "one metrics row per step, none repeated");

    let scores = baseline::evaluate(&second, &b, NerfKind::NerfT).unwrap();
    let test = second.scene.frames(Role::Test);
    let frames = rendered_steps(test.len(), second.exp.eval.render_every);
    assert_eq!(scores.model, "NeRF-T");
    assert_eq!(
        scores.images.iter().map(|s| s.t).collect::<Vec<_>>(),
        frames
    );
    assert!(scores.images.iter().all(|s| s.psnr.is_finite()));
    assert!(
        scores
            .images
            .iter()
            .all(|s| s.error_on_fluid.is_some_and(|f| (0.0..=1.0).contains(&f))),
        "each render's error split by the truth's alpha"
    );
    let read = baseline::read_all(&second).unwrap();
    assert_eq!(read, vec![scores.clone()]);

    // on validation views (here the test view copied under another name) it scores them into
    // a file of their own, the same per frame; the test views' scores stay as they were
    let test_view = second.scene.views(Role::Test)[0].clone();
    let scene_dir = second.scene.root().to_path_buf();
    drop((log, second));
    neurofluid_tests::add_validation_copy(&scene_dir, "view_9");
    let mut e = experiment(tmp.path(), "pieces", true, 6);
    e.apply_overrides(&["eval.novel_views=\"validation\""])
        .unwrap();
    let on_val = Run::prepare(e, Start::Resume, &[Stage::NerfT]).unwrap();
    let mut log = on_val.open_log().unwrap();
    let c = nerf::train(&on_val, &mut log, NerfKind::NerfT).unwrap();
    assert_eq!(params(&c), params(&b), "eval.novel_views shapes no NeRF");
    let val = baseline::evaluate(&on_val, &c, NerfKind::NerfT).unwrap();
    neurofluid_tests::assert_scored_as_the_test_view(
        &val.images,
        &scores.images,
        "view_9",
        &test_view,
    );
    assert_eq!(baseline::read_all(&on_val).unwrap(), vec![val]);
    drop((log, on_val));
    let on_test = Run::prepare(
        experiment(tmp.path(), "pieces", true, 6),
        Start::Resume,
        &[Stage::NerfT],
    )
    .unwrap();
    assert_eq!(baseline::read_all(&on_test).unwrap(), vec![scores]);
}

#[test]
fn particles_from_images_feed_every_stage() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let mut e = experiment(tmp.path(), "fromimages", false, 3);
    e.apply_overrides(&["scene.initial=from_images"]).unwrap();
    // before any recovery the stages that start from them refuse to start, saying why
    let err = Run::prepare(e.clone(), Start::Resume, &[Stage::Warmup])
        .unwrap_err()
        .to_string();
    assert!(err.contains("init-particles"), "{err}");

    // recovered particles (here: the truth moved up by two radii and thinned to every other one)
    let run = Run::prepare(e.clone(), Start::Resume, &[Stage::Nerf]).unwrap();
    let truth = run.scene.particles(Role::Warmup, 0).unwrap();
    let moved: Vec<[f32; 3]> = truth
        .pos
        .iter()
        .step_by(2)
        .map(|p| [p[0], p[1] + 0.05, p[2]])
        .collect();
    let n = moved.len();
    Particles {
        pos: moved.clone(),
        vel: vec![[0.0; 3]; n],
    }
    .write(&initial::particles_path(&run))
    .unwrap();
    drop(run);

    let run = Run::prepare(
        e,
        Start::Resume,
        &[Stage::Warmup, Stage::Joint, Stage::Eval],
    )
    .unwrap();
    let start = initial::starting_particles(&run, Role::Test, 0, "start").unwrap();
    assert_eq!(start.pos, moved);
    let mut log = run.open_log().unwrap();
    warmup::run(&run, &mut log).unwrap();
    let data = JointData::load(&run.scene, &run.exp.joint).unwrap();
    let mut trainer = JointTrainer::new(
        &run.exp.joint,
        warmup::load_trained(&run).unwrap(),
        run.load_dlf(&run.exp.dlf.weights).unwrap(),
        JointData {
            initial: start.clone(),
            ..data
        },
        run.exp.seed,
    )
    .unwrap();
    // the recovered particles are not the true ones: no alignment (it matches particles by
    // index), but a rollout d against the truth
    trainer.step(0).unwrap();
    let d = trainer.diagnostics().unwrap();
    assert_eq!(d.grad_alignment, None);
    assert!(d.rollout_d.unwrap() > 20.0, "{d:?}");
    let grounded = neurofluid_train::stages::joint::run(&run, &mut log).unwrap();
    let report = eval::run(&run, &grounded).unwrap();
    assert!(report.initial_from_images);
    assert!(report.markdown().contains("initial particles from images"));
    // the rollouts start from the recovered particles: at t = 1 the truth is about two radii
    // (50 × 10⁻³) from them, far more than from a rollout of the true state
    assert!(
        neurofluid_outputs::report::Rollout::NeuroFluid
            .of(&report.frames[0])
            .unwrap()
            > 20.0,
        "{:?}",
        report.frames[0]
    );
}

#[test]
fn a_nerf_that_sees_no_fluid_is_refused_with_the_reason() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let mut e = experiment(tmp.path(), "nofluid", false, 2);
    // a surface no untrained NeRF reaches: σ_iso = −ln(1e-9)/(2r) ≈ 414
    e.apply_overrides(&[
        "scene.initial=from_images",
        "initial.threshold=opacity",
        "initial.opacity=0.999999999",
    ])
    .unwrap();
    let run = Run::prepare(e, Start::Resume, &Stage::ALL).unwrap();
    let mut log = run.open_log().unwrap();
    let err = format!("{:#}", run_all(&run, &mut log).unwrap_err());
    assert!(err.contains("no value above the threshold"), "{err}");
    assert!(
        !initial::particles_path(&run).exists(),
        "no particle file after a failed recovery"
    );
}

#[test]
fn a_nerf_without_warmup_views_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let mut e = experiment(tmp.path(), "noviews", false, 2);
    let err = e
        .apply_overrides(&["warmup.views=[]"])
        .unwrap_err()
        .to_string();
    assert!(err.contains("warmup.views"), "{err}");
    let run = Run::prepare(e, Start::Resume, &[Stage::Nerf]).unwrap();
    // a scene without warm-up views (validation refuses an empty list in a config)
    let mut exp = run.exp.clone();
    exp.warmup.views = Some(Vec::new());
    let err = nerf::NerfData::load(&run.scene, NerfKind::Nerf, &exp, false)
        .unwrap_err()
        .to_string();
    assert!(err.contains("no warm-up views"), "{err}");
}
