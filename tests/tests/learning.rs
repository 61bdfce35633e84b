//! The CI experiment learns, so a change that stops gradients cannot pass: the warm-up improves
//! its renders, the joint stage changes both models, and NeuroFluid's rollout leaves DLF's. And
//! a model that cannot learn (the paper's ReLU density starting dead) is stopped with a message
//! instead of training nothing.

use burn::module::Module;
use neurofluid_core::metrics::{RgbImage, psnr};
use neurofluid_core::scene::Role;
use neurofluid_outputs::report::{FrameDistance, Rollout};
use neurofluid_outputs::scoring::{picture_frames, rendered_steps};
use neurofluid_outputs::sequences::{
    RENDERER_ON_DLF, RENDERER_ON_SUPERVISED_DLF, RENDERER_ON_TRUTH,
};
use neurofluid_tests::{params, seeded_turn, tiny_experiment};
use neurofluid_train::stage::Stage;
use neurofluid_train::stages::views::{ViewFrame, points_tensor, render_beside_truth};
use neurofluid_train::stages::{Run, Start, eval, joint, warmup};

/// PSNR of PhysNeRF's render of the first warm-up view of frame 0.
fn warmup_view_psnr(run: &Run, physnerf: &neurofluid_physnerf::PhysNerf) -> f64 {
    let view = &run.scene.views(Role::Warmup)[0];
    let frame = ViewFrame::load(&run.scene, Role::Warmup, view, 0).unwrap();
    let particles = run.scene.particles(Role::Warmup, 0).unwrap();
    let p = points_tensor(&particles.pos, &run.device);
    render_beside_truth(physnerf, &frame, &p)
        .unwrap()
        .psnr
        .unwrap()
}

/// PhysNeRF's render of `particles` from `frame`'s camera and the frame's truth, both as the
/// evaluation scores them (8-bit quantised).
fn scored_render(
    run: &Run,
    physnerf: &neurofluid_physnerf::PhysNerf,
    frame: &ViewFrame,
    particles: &[[f32; 3]],
) -> (RgbImage, RgbImage) {
    let image = physnerf
        .render_image(
            &frame.camera,
            &points_tensor(particles, &run.device),
            physnerf.config.chunk,
        )
        .unwrap();
    let (w, h) = (frame.camera.width as usize, frame.camera.height as usize);
    let quantised = |rgb: Vec<f32>| RgbImage::new(w, h, rgb).unwrap().quantised();
    (
        quantised(image.best().to_vec()),
        quantised(frame.image.rgb.clone()),
    )
}

#[test]
fn the_ci_experiment_learns() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    // eight warm-up steps: the experiment's four move its half-width MLPs' render by about
    // 0.3 dB, less than this test asks of a warm-up that learns
    let experiment = || {
        let mut e = tiny_experiment(tmp.path(), "learns");
        e.apply_override("warmup.iters=8").unwrap();
        e
    };
    let run = Run::prepare(experiment(), Start::Resume, &Stage::ALL).unwrap();
    let mut log = run.open_log().unwrap();
    let initial = warmup::new_physnerf(&run).unwrap();
    let warmed = warmup::run(&run, &mut log).unwrap();
    let (before, after) = (
        warmup_view_psnr(&run, &initial),
        warmup_view_psnr(&run, &warmed),
    );
    assert!(
        after > before + 0.5,
        "the warm-up did not improve its render: PSNR {before:.3} → {after:.3} dB"
    );

    let grounded = joint::run(&run, &mut log).unwrap();
    assert!(
        params(&grounded.physnerf) != params(&warmed),
        "the joint stage left PhysNeRF unchanged"
    );
    let pretrained = run.load_dlf(&run.exp.dlf.weights).unwrap();
    assert!(
        params(&grounded.dlf) != params(&pretrained),
        "the joint stage left DLF unchanged"
    );
    let s = eval::run(&run, &grounded).unwrap().summary();
    let (nf, dlf) = (
        s.grounding.d_of(Rollout::NeuroFluid).unwrap(),
        s.grounding.d_of(Rollout::Dlf).unwrap(),
    );
    assert!(
        nf != dlf,
        "NeuroFluid's rollout is DLF's (d {nf} for both): the grounding changed nothing"
    );
    // the experiment steps as the paper (no rules): its DLF row is the paper's, given once
    assert_eq!(s.grounding.d_of(Rollout::PublishedDlf), None);

    // what a person looks at: per test view an animation of truth | DLF | NeuroFluid over the
    // rendered frames, and the particle sets at the first, last grounding and last frame
    let view = &run.scene.views(Role::Test)[0];
    let cam = run.scene.camera(Role::Test, view, 0).unwrap();
    let dir = run.stage_dir(eval::STAGE).join(eval::ANIMATIONS);
    let file = std::fs::File::open(dir.join(format!("{view}.png"))).unwrap();
    let mut apng = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .unwrap();
    let test_frames = run.scene.frames(Role::Test).len();
    let rendered = rendered_steps(test_frames, run.exp.eval.render_every).len();
    assert_eq!(
        apng.info().animation_control.unwrap().num_frames as usize,
        rendered
    );
    assert_eq!(
        (apng.info().width, apng.info().height),
        (
            3 * cam.width,
            cam.height + neurofluid_outputs::pictures::LABEL_HEIGHT
        )
    );
    let mut buf = vec![0; apng.output_buffer_size().unwrap()];
    for _ in 0..rendered {
        apng.next_frame(&mut buf).unwrap();
    }
    let picture = eval::particle_picture_path(&run.stage_dir(eval::STAGE), view);
    // the image scores (with LPIPS) are in the metrics log, once per render
    let rows = neurofluid_outputs::metrics_log::read_jsonl(&run.dir.join("metrics.jsonl")).unwrap();
    let eval_rows: Vec<_> = rows
        .iter()
        .filter(|r| r.stage == format!("eval-{view}"))
        .collect();
    assert_eq!(eval_rows.len(), rendered);
    assert!(
        eval_rows
            .iter()
            .all(|r| r.get("lpips").is_some_and(|v| v > 0.0) && r.get("psnr").is_some())
    );

    // the browser recording holds every frame of the three sets, as eval wrote them
    let rec = neurofluid_outputs::pictures::viewer::Recording::read(
        &run.stage_dir(eval::STAGE).join(eval::VIEWER_FILE),
    )
    .unwrap();
    assert_eq!(rec.frames, test_frames);
    let names: Vec<&str> = rec.tracks.iter().map(|t| t.name.as_str()).collect();
    assert_eq!(names, ["truth", "DLF", "NeuroFluid"]);
    let last = test_frames - 1;
    let ply = neurofluid_outputs::formats::ply::read_ply(
        &run.stage_dir(eval::STAGE)
            .join(format!("particles/neurofluid_{last:04}.ply")),
    )
    .unwrap();
    let step: f32 = (0..3).map(|a| rec.hi[a] - rec.lo[a]).fold(0.0, f32::max) / 65535.0;
    for (a, b) in rec.positions(2, last).unwrap().iter().zip(&ply.positions) {
        assert!(a.iter().zip(b).all(|(x, y)| (x - y).abs() <= step));
    }
    assert_eq!(rec.cameras[0].view, *view);
    let training: Vec<&str> = rec.training.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(training, ["warmup loss", "joint loss"]);
    assert_eq!(rec.training[0].points.len() as u64, run.exp.warmup.iters);
    let (w, h) = image::image_dimensions(&picture).unwrap();
    let panel = 240u32.max(cam.width);
    let rows = picture_frames(run.scene.frames(Role::Train).len(), test_frames - 1).len();
    assert_eq!(w, 3 * panel);
    assert_eq!(
        h as usize,
        rows * (panel as usize * cam.height as usize / cam.width as usize
            + neurofluid_outputs::pictures::LABEL_HEIGHT as usize)
    );

    // the renderer on the true particles (`diagnostics.render_truth`): a row of the novel-view table,
    // one score per NeuroFluid render, each the grounded renderer's image of the true particles
    drop((log, run));
    let mut e = experiment();
    e.apply_override("diagnostics.render_truth=true").unwrap();
    let again = Run::prepare(e, Start::Resume, &[Stage::Eval]).unwrap();
    let report = eval::run(&again, &grounded).unwrap();
    let on_truth = report
        .nvs_baselines
        .iter()
        .find(|b| b.model == RENDERER_ON_TRUTH)
        .expect("a row of the renderer on the true particles");
    let steps = |s: &[neurofluid_outputs::report::ImageScore]| -> Vec<(String, usize)> {
        s.iter().map(|i| (i.view.clone(), i.t)).collect()
    };
    assert_eq!(steps(&on_truth.images), steps(&report.images));
    let first = &on_truth.images[0];
    let at = again.scene.frames(Role::Test).start + first.t;
    let frame = ViewFrame::load(&again.scene, Role::Test, &first.view, at).unwrap();
    let truth = again.scene.particles(Role::Test, at).unwrap();
    let physnerf = grounded.physnerf.valid();
    let (rendered, target) = scored_render(&again, &physnerf, &frame, &truth.pos);
    let (w, h) = (frame.camera.width as usize, frame.camera.height as usize);
    assert_eq!(first.psnr, psnr(&rendered, &target).unwrap());
    // its error split by the truth's alpha, summed here pixel by pixel
    let (mut on, mut all) = (0.0f64, 0.0f64);
    for (p, a) in frame.image.alpha.iter().enumerate() {
        let e: f64 = (0..3)
            .map(|c| {
                let (x, y) = (rendered.data[3 * p + c], target.data[3 * p + c]);
                (f64::from(x) - f64::from(y)).powi(2)
            })
            .sum();
        all += e;
        on += if *a >= 0.5 { e } else { 0.0 };
    }
    assert!(frame.image.alpha.iter().any(|a| *a >= 0.5) && on > 0.0 && on < all);
    let share = first.error_on_fluid.expect("the error's split");
    assert!((share - on / all).abs() < 1e-9, "{share} vs {}", on / all);
    // and saved beside the truth: the left half is that render
    let png = again.stage_dir(Stage::Eval).join(format!(
        "renders/{}/true_particles_t{:04}.png",
        first.view, first.t
    ));
    let saved = image::open(&png).unwrap().to_rgb8();
    assert_eq!(saved.dimensions(), (2 * w as u32, h as u32));
    for (p, px) in (0..h).flat_map(|y| (0..w).map(move |x| (y * w + x, (x, y)))) {
        let got = saved.get_pixel(px.0 as u32, px.1 as u32).0;
        let want = rendered.data[3 * p..3 * p + 3]
            .iter()
            .map(|v| (v * 255.0).round() as u8);
        assert!(got.iter().copied().eq(want), "pixel {px:?}");
    }
    assert!(
        on_truth.images != report.images,
        "the true particles' renders scored as NeuroFluid's at every step"
    );
    assert!(report.markdown().contains(RENDERER_ON_TRUTH));
    drop(again);

    // the renderer on the pretrained DLF's and DLF†'s rollouts (`diagnostics.render_dlf`): a row each,
    // every score the grounded renderer's image of that rollout's particles at that step (DLF†
    // here the pretrained weights themselves, so its row is DLF's to the last digit)
    let mut e = experiment();
    e.apply_override("diagnostics.render_dlf=true").unwrap();
    let weights = e.dlf.weights.display().to_string();
    e.apply_override(&format!("eval.supervised_dlf={weights:?}"))
        .unwrap();
    let again = Run::prepare(e, Start::Resume, &[Stage::Eval]).unwrap();
    let with_dlf = eval::run(&again, &grounded).unwrap();
    let row = |model: &str| {
        with_dlf
            .nvs_baselines
            .iter()
            .find(|b| b.model == model)
            .unwrap_or_else(|| panic!("a row of {model}"))
            .images
            .clone()
    };
    let (on_dlf, on_supervised) = (row(RENDERER_ON_DLF), row(RENDERER_ON_SUPERVISED_DLF));
    assert!(
        with_dlf
            .nvs_baselines
            .iter()
            .all(|b| b.model != RENDERER_ON_TRUTH)
    );
    assert_eq!(steps(&on_dlf), steps(&with_dlf.images));
    assert_eq!(on_dlf, on_supervised);
    assert!(
        on_dlf != with_dlf.images,
        "DLF's renders scored as NeuroFluid's"
    );
    let rollouts = eval::rollouts::of(&again, &grounded).unwrap();
    let last = on_dlf.last().unwrap();
    let at = again.scene.frames(Role::Test).start + last.t;
    let frame = ViewFrame::load(&again.scene, Role::Test, &last.view, at).unwrap();
    let dlf_particles = &rollouts.baseline.as_ref().unwrap()[last.t];
    let (rendered, target) = scored_render(&again, &physnerf, &frame, dlf_particles);
    assert_eq!(last.psnr, psnr(&rendered, &target).unwrap());
    let dir = again
        .stage_dir(Stage::Eval)
        .join("renders")
        .join(&last.view);
    for prefix in ["dlf_particles_", "dlf_supervised_particles_"] {
        assert!(dir.join(format!("{prefix}t{:04}.png", last.t)).is_file());
    }
    assert!(with_dlf.markdown().contains(RENDERER_ON_DLF));

    drop(again);
    // `diagnostics.weight_interpolation`: at 0 NeuroFluid's DLF is the pretrained one, so its rollout
    // is DLF's at every frame; halfway it is neither, and the report says which model it scored
    let interpolated = |key: &str, fraction: &str| {
        let mut e = experiment();
        e.apply_override("eval.render=false").unwrap();
        e.apply_override(&format!("diagnostics.{key}={fraction}"))
            .unwrap();
        let run = Run::prepare(e, Start::Resume, &[Stage::Eval]).unwrap();
        let report = eval::run(&run, &grounded).unwrap();
        (report, run.stage_dir(eval::STAGE))
    };
    let (at_zero, _) = interpolated("weight_interpolation", "0.0");
    assert!(
        at_zero
            .frames
            .iter()
            .all(|f| Rollout::NeuroFluid.of(f) == Rollout::Dlf.of(f)
                && Rollout::NeuroFluid.reverse_of(f) == Rollout::Dlf.reverse_of(f)),
        "at weight_interpolation 0 NeuroFluid's rollout is not the pretrained DLF's"
    );
    let (halfway, _) = interpolated("weight_interpolation", "0.5");
    let d = |r: &neurofluid_outputs::report::EvalReport| -> Vec<f64> {
        r.frames
            .iter()
            .filter_map(|f| Rollout::NeuroFluid.of(f))
            .collect()
    };
    assert!(d(&halfway) != d(&at_zero) && d(&halfway) != d(&report));
    assert!(
        halfway
            .markdown()
            .contains("plus 0.5 of what grounding changed")
    );
    assert!(
        !report
            .markdown()
            .contains("diagnostics.weight_interpolation")
    );

    // `diagnostics.interpolation_sweep`: the grounded model's report gains d and d′ per window at each
    // fraction, the same figures as evaluating each fraction on its own (0: the pretrained DLF,
    // 1: NeuroFluid as trained), and a picture of them
    let means = |r: &neurofluid_outputs::report::EvalReport, of: fn(&FrameDistance) -> [f64; 2]| {
        let window = |(a, b): (usize, usize)| {
            let rows: Vec<[f64; 2]> = r
                .frames
                .iter()
                .filter(|f| (a..=b).contains(&f.t))
                .map(of)
                .collect();
            let n = rows.len() as f64;
            [0, 1].map(|k| rows.iter().map(|v| v[k]).sum::<f64>() / n)
        };
        (window(r.windows.grounding), window(r.windows.prediction))
    };
    fn both(m: Rollout, f: &FrameDistance) -> [f64; 2] {
        [m.of(f).unwrap(), m.reverse_of(f).unwrap()]
    }
    let dlf = |f: &FrameDistance| both(Rollout::Dlf, f);
    let nf = |f: &FrameDistance| both(Rollout::NeuroFluid, f);
    let (swept, dir) = interpolated("interpolation_sweep", "[0.5]");
    let points: Vec<_> = swept
        .interpolation
        .iter()
        .map(|i| (i.fraction, (i.grounding, i.prediction)))
        .collect();
    let close = |a: ([f64; 2], [f64; 2]), b: ([f64; 2], [f64; 2])| {
        let (a, b) = ([a.0, a.1].concat(), [b.0, b.1].concat());
        a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-9)
    };
    assert_eq!(
        points.iter().map(|p| p.0).collect::<Vec<_>>(),
        [0.0, 0.5, 1.0]
    );
    assert!(close(points[0].1, means(&swept, dlf)));
    assert!(close(points[1].1, means(&halfway, nf)));
    assert!(close(points[2].1, means(&swept, nf)));
    assert!(close(means(&swept, nf), means(&report, nf)));
    assert!(dir.join(eval::INTERPOLATION_PLOT).is_file());
    assert!(swept.markdown().contains("diagnostics.interpolation_sweep"));
}

#[test]
fn a_model_that_starts_dead_is_stopped_with_the_reason() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let mut e = tiny_experiment(tmp.path(), "dead");
    // the paper's ReLU density and width; with seed 1 both networks start with σ ≤ 0 everywhere
    // (so do seeds 4, 8 and 9 of 0–11; the draw is the CPU's on every device)
    e.apply_override("physnerf.density=\"relu\"").unwrap();
    e.apply_override("physnerf.width=256").unwrap();
    e.apply_override("seed=1").unwrap();
    let run = Run::prepare(e, Start::Resume, &Stage::ALL).unwrap();
    let mut log = run.open_log().unwrap();
    let err = format!("{:#}", warmup::run(&run, &mut log).unwrap_err());
    assert!(err.contains("physnerf received no gradient"), "{err}");
    assert!(err.contains("physnerf.density"), "{err}");
    // the rows logged so far show the zero gradients, and the message counts steps as they do
    let rows = neurofluid_outputs::metrics_log::read_jsonl(log.jsonl_path()).unwrap();
    assert!(
        rows.iter()
            .all(|r| r.get("grad_norm/physnerf") == Some(0.0))
    );
    // (a session shorter than the patience is judged after its last, logged, step)
    let last = rows.iter().map(|r| r.step).max().unwrap();
    assert_eq!(last, run.exp.warmup.iters);
    assert!(err.contains(&format!("stopped at step {last}")), "{err}");
}
