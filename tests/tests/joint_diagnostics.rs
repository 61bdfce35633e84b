//! The joint stage's split of the image gradient and its diagnostics: the split (PhysNeRF's
//! gradients and ∂L/∂x from a render of the detached prediction, DLF's from the surrogate
//! Σ x·g) gives the gradients of the direct backward through DLF and the renderer; the rollout d,
//! gradient alignment and PSNR on the true particles reach the metrics log, and the rollout d
//! is the one an independent rollout of the grounded DLF gives; rays drawn mostly from the
//! fluid's pixels train as the uniform ones do; each particle term (`[joint.terms]`) adds its
//! value to the loss and logs it under its name; the rollout's density and energy are logged.

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::prelude::*;
use neurofluid_core::metrics::{SUPPORT_RADII, gt_to_pred_distance, mean_density};
use neurofluid_core::sampler::Rng;
use neurofluid_core::scene::Role;
use neurofluid_core::tensors::{points_tensor, tensor_points};
use neurofluid_outputs::metrics_log::{MetricsLog, MetricsRow, read_jsonl};
use neurofluid_physnerf::PhysNerf;
use neurofluid_tests::{params, seeded_turn, tiny_experiment};
use neurofluid_train::config::Experiment;
use neurofluid_train::stage::Stage;
use neurofluid_train::stages::joint::{self, JointData, dlf_surrogate, split_image_loss};
use neurofluid_train::stages::{Run, Start, warmup};

/// Every parameter's gradient in `grads`, in the module's order (empty where it has none).
fn gradients<M: Module>(module: &M, grads: &GradientsParams) -> Vec<Vec<f32>> {
    struct Collect<'a>(&'a GradientsParams, Vec<Vec<f32>>);
    impl ModuleVisitor for Collect<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let g = self.0.get::<D>(param.id);
            self.1
                .push(g.map_or_else(Vec::new, |g| g.into_data().try_to_vec::<f32>().unwrap()));
        }
    }
    let mut c = Collect(grads, Vec::new());
    module.visit(&mut c);
    c.1
}

/// The largest difference between `a` and `b` relative to `b`'s largest magnitude.
fn relative_difference(a: &[Vec<f32>], b: &[Vec<f32>]) -> f64 {
    assert_eq!(a.len(), b.len());
    let scale = b
        .iter()
        .flatten()
        .fold(0.0f64, |m, v| m.max(f64::from(v.abs())));
    assert!(scale > 0.0, "no gradient at all");
    let mut worst = 0.0f64;
    for (x, y) in a.iter().zip(b) {
        assert_eq!(
            x.len(),
            y.len(),
            "a parameter has a gradient on one side only"
        );
        for (u, v) in x.iter().zip(y) {
            worst = worst.max(f64::from((u - v).abs()));
        }
    }
    worst / scale
}

/// What a warm-up and joint stage of an experiment left.
struct Grounding {
    run: Run,
    /// The run's `metrics.jsonl`.
    jsonl: std::path::PathBuf,
    /// DLF's weights before the joint stage.
    before: Vec<Vec<f32>>,
    /// The grounded models.
    grounded: joint::Grounded,
}

/// Runs the warm-up and the joint stage of `e`.
fn ground(e: Experiment) -> Grounding {
    let run = Run::prepare(e, Start::Resume, &[Stage::Warmup, Stage::Joint]).unwrap();
    let mut log = MetricsLog::open(&run.dir).unwrap();
    warmup::run(&run, &mut log).unwrap();
    let before = params(&run.load_dlf(&run.exp.dlf.weights).unwrap());
    let grounded = joint::run(&run, &mut log).unwrap();
    Grounding {
        jsonl: log.jsonl_path().to_path_buf(),
        run,
        before,
        grounded,
    }
}

/// [`ground`] of the tiny experiment once per set of overrides, in order (run folders
/// `{name}0`, `{name}1`, …).
fn ground_each(tmp: &std::path::Path, name: &str, variants: &[Vec<String>]) -> Vec<Grounding> {
    variants
        .iter()
        .enumerate()
        .map(|(i, sets)| {
            let mut e = tiny_experiment(tmp, &format!("{name}{i}"));
            e.apply_overrides(sets).unwrap();
            ground(e)
        })
        .collect()
}

/// (step, loss) of every joint-stage row with a finite loss.
fn finite_losses(g: &Grounding) -> Vec<(u64, f64)> {
    rows_of(&g.jsonl, "joint")
        .iter()
        .filter(|r| r.loss.is_finite())
        .map(|r| (r.step, r.loss))
        .collect()
}

/// Positions and velocities of every particle.
type HostState = (Vec<[f32; 3]>, Vec<[f32; 3]>);

/// The run's pretrained DLF rolled out by hand from the joint stage's first state (what a joint
/// stage with `joint.dlf_optim.lr = 0` steps through): the stage's data and every state, the
/// first one's included.
fn held_rollout(run: &Run) -> (JointData, Vec<HostState>) {
    let data = JointData::load(&run.scene, &run.exp.joint).unwrap();
    let dlf = run.load_dlf(&run.exp.dlf.weights).unwrap();
    let device = dlf.device();
    let boundary = dlf.boundary(&data.walls.0, &data.walls.1, &device);
    let mut states = vec![(data.initial.pos.clone(), data.initial.vel.clone())];
    for _ in 0..data.transitions() {
        let (pos, vel) = states.last().unwrap();
        let next = dlf.step(
            points_tensor(pos, &device),
            points_tensor(vel, &device),
            &boundary,
        );
        states.push((tensor_points(&next.pos), tensor_points(&next.vel)));
    }
    (data, states)
}

/// With DLF held, `held`'s loss is above `free`'s at every logged step by exactly the term a
/// prior adds there (`terms` per transition, the same in every epoch), to 1e-3 of the larger of
/// the term and `floor`.
fn assert_loss_rises_by(free: &Grounding, held: &Grounding, terms: &[f64], floor: f64, what: &str) {
    let (free, held) = (finite_losses(free), finite_losses(held));
    assert!(!free.is_empty());
    assert_eq!(free.len(), held.len());
    for ((step, a), (_, b)) in free.iter().zip(&held) {
        let expected = terms[(*step as usize - 1) % terms.len()];
        assert!(
            (b - a - expected).abs() < 1e-3 * expected.max(floor),
            "{what}, step {step}: the loss rose by {} where the term adds {expected}",
            b - a
        );
    }
}

/// `g`'s joint rows log the particle term `name` (`loss/<name>`) at every logged step as the
/// term of that step's transition (`terms` per transition, the same in every epoch), to 1e-3 of
/// the larger of the term and `floor`; with `terms` empty, the term is not logged at all.
fn assert_term_logged(g: &Grounding, name: &str, terms: &[f64], floor: f64) {
    let key = format!("loss/{name}");
    let rows = rows_of(&g.jsonl, "joint");
    let logged: Vec<(u64, f64)> = rows
        .iter()
        .filter_map(|r| r.get(&key).map(|v| (r.step, v)))
        .collect();
    if terms.is_empty() {
        assert!(
            logged.is_empty(),
            "{key} logged without the term: {logged:?}"
        );
        return;
    }
    assert!(!logged.is_empty(), "{key} not logged");
    for (step, v) in logged {
        let expected = terms[(step as usize - 1) % terms.len()];
        assert!(
            (v - expected).abs() < 1e-3 * expected.max(floor),
            "{key}, step {step}: logged {v}, by hand {expected}"
        );
    }
}

/// The metrics rows of `stage`.
fn rows_of(jsonl: &std::path::Path, stage: &str) -> Vec<MetricsRow> {
    read_jsonl(jsonl)
        .unwrap()
        .into_iter()
        .filter(|r| r.stage == stage)
        .collect()
}

#[test]
fn split_image_gradient_equals_the_direct_one() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let run = Run::prepare(
        tiny_experiment(tmp.path(), "split"),
        Start::Resume,
        &[Stage::Warmup],
    )
    .unwrap();
    let data = JointData::load(&run.scene, &run.exp.joint).unwrap();
    let physnerf = PhysNerf::new(run.physnerf_config(), &run.device).unwrap();
    let dlf = run.load_dlf(&run.exp.dlf.weights).unwrap();
    let device = dlf.device();
    let boundary = dlf.boundary(&data.walls.0, &data.walls.1, &device);
    let target = data.target(2);
    let (w, h) = (target.camera.width, target.camera.height);
    let pixels = Rng::new(3).sample_pixels(512, w, h, None).unwrap();
    let (rays, colours) = target.batch(&pixels, &device);
    let start = || {
        (
            points_tensor(&data.initial.pos, &device),
            points_tensor(&data.initial.vel, &device),
        )
    };

    // two transitions, the loss at the second: the gradient crosses a transition too
    let (x0, v0) = start();
    let p1 = dlf.step(x0, v0, &boundary);
    let p2 = dlf.step(p1.pos, p1.vel, &boundary);
    let out = physnerf.render_rays(&p2.pos, &rays, None).unwrap();
    let mut grads = physnerf.loss(&out, colours.clone()).total.backward();
    let direct_dlf = GradientsParams::from_module(&mut grads, &dlf);
    let direct_physnerf = GradientsParams::from_module(&mut grads, &physnerf);

    let (x0, v0) = start();
    let p1 = dlf.step(x0, v0, &boundary);
    let p2 = dlf.step(p1.pos, p1.vel, &boundary);
    let split = split_image_loss(&physnerf, &p2.pos, &rays, colours, None).unwrap();
    let dx = split.dx.expect("the render depends on the positions");
    assert!(dx.iter().flatten().any(|v| *v != 0.0));
    let mut grads = dlf_surrogate(&p2.pos, Some(points_tensor(&dx, &device))).backward();
    let split_dlf = GradientsParams::from_module(&mut grads, &dlf);
    let split_physnerf = split.physnerf_grads.expect("PhysNeRF's gradients");

    let d = relative_difference(&gradients(&dlf, &split_dlf), &gradients(&dlf, &direct_dlf));
    assert!(d < 1e-4, "DLF's gradients differ by {d:e} of their scale");
    let p = relative_difference(
        &gradients(&physnerf, &split_physnerf),
        &gradients(&physnerf, &direct_physnerf),
    );
    assert!(
        p < 1e-5,
        "PhysNeRF's gradients differ by {p:e} of their scale"
    );
}

#[test]
fn diagnostics_reach_the_metrics_and_match_an_independent_rollout() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let mut e = tiny_experiment(tmp.path(), "diagnostics");
    // an evaluation after every epoch, two epochs
    e.apply_overrides(&["joint.epochs=2", "joint.preview_every=3", "joint.rays=512"])
        .unwrap();
    let Grounding {
        run,
        jsonl,
        grounded,
        ..
    } = ground(e);
    assert_eq!(
        run.scene.frames(Role::Train).len(),
        4,
        "3 transitions an epoch"
    );
    let rows = rows_of(&jsonl, "joint-preview");
    assert_eq!(rows.iter().map(|r| r.step).collect::<Vec<_>>(), [3, 6]);
    for r in &rows {
        let a = r.get("grad_alignment").expect("alignment");
        assert!((-1.0..=1.0).contains(&a), "{a}");
        assert!(
            r.get("psnr_true")
                .expect("PSNR on the true particles")
                .is_finite()
        );
        assert!(
            r.get("rollout_d_prime")
                .expect("the rollout's d′")
                .is_finite()
        );
    }
    let csv =
        std::fs::read_to_string(run.dir.join(neurofluid_outputs::metrics_log::CSV_FILE)).unwrap();
    assert!(
        csv.lines()
            .next()
            .unwrap()
            .contains("rollout_d,grad_alignment,psnr_true,rollout_d_prime")
    );

    // the last evaluation follows the last update: its rollout d is the grounded DLF's
    let truth = run.scene.particle_sequence(Role::Train).unwrap();
    let net = grounded.dlf.valid();
    let walls = run.scene.boundary().unwrap();
    let boundary = net.boundary(&walls.points, &walls.normals, &net.device());
    let rollout = neurofluid_dlf::rollout::rollout(
        &net,
        &truth[0].pos,
        &truth[0].vel,
        &boundary,
        truth.len() - 1,
        |_| {},
    );
    let expected = (1..truth.len())
        .map(|t| gt_to_pred_distance(&truth[t].pos, &rollout.pos[t]).mean)
        .sum::<f64>()
        / (truth.len() - 1) as f64;
    let logged = rows[1].get("rollout_d").expect("rollout d");
    assert!(
        (logged - expected).abs() <= 1e-9 * expected.max(1.0),
        "logged {logged}, independent {expected}"
    );
    // and the energy it gains: E_t from consecutive positions, the gains of steps t ≥ 2 summed
    let dt = net.config.dt;
    let energy = |t: usize| {
        let vel: Vec<[f32; 3]> = rollout.pos[t]
            .iter()
            .zip(&rollout.pos[t - 1])
            .map(|(a, b)| std::array::from_fn(|k| (a[k] - b[k]) / dt))
            .collect();
        energy_by_hand(&rollout.pos[t], &vel, net.config.gravity)
    };
    let gained: f64 = (2..truth.len())
        .map(|t| (energy(t) - energy(t - 1)).max(0.0))
        .sum();
    let logged = rows[1].get("rollout_energy_gain").expect("energy gain");
    assert!(
        (logged - gained).abs() <= 1e-6 * gained.max(1.0),
        "logged {logged}, by hand {gained}"
    );
    // the renderer on that rollout at psnr_true's pixels: the logged value is the independent
    // rollout's; on the truth it is psnr_true; on the truth moved a box length away (the fluid
    // gone from where the images show it) it is worse
    let data = JointData::load(&run.scene, &run.exp.joint).unwrap();
    let psnr = |frames: &[Vec<[f32; 3]>]| {
        joint::psnr_on_frames(&grounded.physnerf, &data, frames, 512, run.exp.seed)
            .unwrap()
            .expect("a PSNR")
    };
    let logged = rows[1].get("rollout_psnr").expect("the rollout's PSNR");
    let independent = psnr(&rollout.pos);
    assert!(
        (logged - independent).abs() <= 1e-9 * independent.abs().max(1.0),
        "logged {logged}, independent {independent}"
    );
    let true_pos: Vec<Vec<[f32; 3]>> = truth.iter().map(|f| f.pos.clone()).collect();
    let on_truth = psnr(&true_pos);
    assert_eq!(Some(on_truth), rows[1].get("psnr_true"));
    let length = data.interior.max[0] - data.interior.min[0];
    let moved: Vec<Vec<[f32; 3]>> = true_pos
        .iter()
        .map(|f| f.iter().map(|p| [p[0] + length, p[1], p[2]]).collect())
        .collect();
    let away = psnr(&moved);
    assert!(
        away < on_truth,
        "moved away {away} dB, the truth {on_truth} dB"
    );
}

#[test]
fn foreground_rays_train_and_see_more_fluid() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let mut e = tiny_experiment(tmp.path(), "foreground");
    e.apply_overrides(&["joint.foreground_rays=0.75", "joint.rays=256"])
        .unwrap();
    let focused = ground(e);
    let after = params(&focused.grounded.dlf);
    assert!(after.iter().flatten().all(|v| v.is_finite()));
    assert!(
        focused.before != after,
        "DLF unchanged with foreground rays"
    );
    // most of the rays of a step now see fluid: the batch PSNR is lower than on the mostly
    // white uniform draw of the same models
    let psnr = |stage_rows: &[MetricsRow]| {
        stage_rows.iter().filter_map(|r| r.get("psnr")).sum::<f64>() / stage_rows.len() as f64
    };
    let focused = psnr(&rows_of(&focused.jsonl, "joint"));
    let mut e = tiny_experiment(tmp.path(), "uniform");
    e.apply_overrides(&["joint.rays=256"]).unwrap();
    let uniform = psnr(&rows_of(&ground(e).jsonl, "joint"));
    assert!(
        focused < uniform,
        "focused {focused:.2} dB vs uniform {uniform:.2} dB"
    );
}

/// The largest change of any weight between `a` and `b`.
fn largest_change(a: &[Vec<f32>], b: &[Vec<f32>]) -> f64 {
    a.iter()
        .flatten()
        .zip(b.iter().flatten())
        .map(|(x, y)| f64::from((x - y).abs()))
        .fold(0.0, f64::max)
}

#[test]
fn dlf_every_sums_transitions_into_one_step() {
    // Adam's first step moves every weight by at most its learning rate (m̂/√v̂ = ±1): one DLF
    // step per epoch of 3 transitions stays within lr, three steps go beyond
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let lr = 1e-3;
    let mut moved = Vec::new();
    for every in [3, 1] {
        let mut e = tiny_experiment(tmp.path(), &format!("every{every}"));
        e.apply_overrides(&[
            format!("joint.dlf_every={every}"),
            format!("joint.dlf_optim.lr={lr}"),
            "joint.dlf_optim.schedule.kind=\"constant\"".into(),
            "joint.rays=256".into(),
        ])
        .unwrap();
        let g = ground(e);
        moved.push(largest_change(&g.before, &params(&g.grounded.dlf)));
        // one metrics row per DLF step
        let steps: Vec<u64> = rows_of(&g.jsonl, "joint").iter().map(|r| r.step).collect();
        assert_eq!(steps, if every == 3 { vec![3] } else { vec![1, 2, 3] });
    }
    assert!(moved[0] > 0.0 && moved[0] <= lr * 1.001, "{moved:?}");
    assert!(moved[1] > 1.5 * lr, "{moved:?}");
}

#[test]
fn extra_views_join_the_loss_and_need_their_frames() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    // without the warm-up views at every frame: refused before training, saying how to get them
    let mut e = tiny_experiment(tmp.path(), "views");
    e.apply_overrides(&["joint.extra_views=[\"view_2\", \"view_3\"]"])
        .unwrap();
    let err = format!(
        "{:#}",
        Run::prepare(e.clone(), Start::Resume, &[Stage::Warmup, Stage::Joint]).unwrap_err()
    );
    assert!(
        err.contains("joint.extra_views (view_2, view_3)") && err.contains("warmup_every_frame"),
        "{err}"
    );
    e.scene.dir = Some(tmp.path().join("scene_all"));
    e.apply_overrides(&["scene.generate.warmup_every_frame=true", "joint.rays=257"])
        .unwrap();
    let g = ground(e);
    let data = JointData::load(&g.run.scene, &g.run.exp.joint).unwrap();
    assert_eq!(data.views.len(), 3);
    assert!(data.views.iter().all(|v| v.len() == 4));
    // the three views see the same frame from their own cameras
    assert_ne!(data.views[1][3].image.rgb, data.views[2][3].image.rgb);
    assert!(g.before != params(&g.grounded.dlf));
    // the step's 257 rays, shared among the views
    let rows = rows_of(&g.jsonl, "joint");
    assert!(!rows.is_empty() && rows.iter().all(|r| r.loss.is_finite()));
    assert_eq!(
        (0..3)
            .map(|i| neurofluid_train::stages::views::ray_share(257, 3, i))
            .collect::<Vec<_>>(),
        [86, 86, 85]
    );
}

/// For each run, the squared distance (summed over particles) between its grounded DLF's step
/// and the pretrained DLF's step from one state: the pretrained rollout's from the first training
/// frame, `past` steps after the end of the training window (`None`: the first frame itself).
fn moved_from_pretrained(runs: &[Grounding], past: Option<u64>) -> Vec<f64> {
    let run = &runs[0].run;
    let data = JointData::load(&run.scene, &run.exp.joint).unwrap();
    let pretrained = run.load_dlf(&run.exp.dlf.weights).unwrap();
    let device = pretrained.device();
    let boundary = pretrained.boundary(&data.walls.0, &data.walls.1, &device);
    let mut state = (
        points_tensor(&data.initial.pos, &device),
        points_tensor(&data.initial.vel, &device),
    );
    for _ in 0..past.map_or(0, |p| data.transitions() + p) {
        let next = pretrained.step(state.0, state.1, &boundary);
        state = (next.pos, next.vel);
    }
    let step = |net: &neurofluid_dlf::DlfNet| {
        tensor_points(&net.step(state.0.clone(), state.1.clone(), &boundary).pos)
    };
    let reference = step(&pretrained);
    runs.iter()
        .map(|g| {
            step(&g.grounded.dlf)
                .iter()
                .zip(&reference)
                .map(|(a, b)| (0..3).map(|k| f64::from(a[k] - b[k]).powi(2)).sum::<f64>())
                .sum::<f64>()
        })
        .collect()
}

#[test]
fn anchor_costs_nothing_at_the_start_and_holds_dlf_near_the_pretrained_step() {
    // two runs that differ only in the anchor's weight: the first window's loss is the same (the
    // grounded DLF starts as the pretrained one, so the anchor term is exactly 0), and after
    // training the anchored DLF's step from the first frame stays nearer the pretrained step
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let runs = ground_each(
        tmp.path(),
        "anchor",
        &[0.0, 1.0].map(|w| vec![format!("joint.terms.anchor.weight={w}")]),
    );
    let first_loss = |g: &Grounding| rows_of(&g.jsonl, "joint")[0].loss;
    assert_eq!(first_loss(&runs[0]), first_loss(&runs[1]));

    let moved = moved_from_pretrained(&runs, None);
    let (free, anchored) = (moved[0], moved[1]);
    assert!(free > 0.0, "the free DLF did not move");
    assert!(
        anchored < 0.5 * free,
        "anchored step moved {anchored} vs {free} unanchored"
    );
}

/// E(x, v) by hand, in f64: the mean over particles of ½|v|² − g·x.
fn energy_by_hand(pos: &[[f32; 3]], vel: &[[f32; 3]], gravity: [f32; 3]) -> f64 {
    let sum: f64 = pos
        .iter()
        .zip(vel)
        .map(|(x, v)| {
            (0..3)
                .map(|k| 0.5 * f64::from(v[k]).powi(2) - f64::from(gravity[k]) * f64::from(x[k]))
                .sum::<f64>()
        })
        .sum();
    sum / pos.len() as f64
}

#[test]
fn energy_prior_adds_each_steps_energy_gain_to_the_loss() {
    // two runs that differ only in the energy prior, DLF held at its starting weights (lr 0), so
    // that both roll the same states out and PhysNeRF trains the same: every step's loss differs
    // by w·max(0, E(x′, v′) − E(x, v)) / (|g| r) of that DLF's step, by hand, which is also the
    // term's logged value (`loss/energy`), and the joint diagnostics log the same gains of the
    // held DLF's rollout, the fluid's and each particle's. The pretrained DLF
    // gains no energy on the tiny scene (a cube in free fall), so the runs start
    // from one whose last layer lifts every particle by 2.5 mm a step (0.32 of the raw output,
    // 1/128 m each), which does; at that lift some particles still lose energy while the fluid
    // gains, so that the fluid's and each particle's gains differ.
    const LIFT: f32 = 0.32;
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let weights = tmp.path().join("perturbed.bpk");
    {
        let run = Run::prepare(
            tiny_experiment(tmp.path(), "perturb"),
            Start::Resume,
            &[Stage::Warmup],
        )
        .unwrap();
        let mut lifting = run.load_dlf(&run.exp.dlf.weights).unwrap();
        // the raw output's up component (model frame: y)
        let up = Tensor::<1>::from_data(
            TensorData::new(vec![0.0f32, LIFT, 0.0], [3]),
            &lifting.device(),
        );
        let bias = lifting.dense3.bias.take().expect("dense3 has a bias");
        lifting.dense3.bias = Some(Param::from_tensor((bias.val() + up).detach()));
        neurofluid_dlf::save_checkpoint(&lifting, &weights).unwrap();
    }
    let weight = 10.0;
    let runs = ground_each(
        tmp.path(),
        "energy",
        &[0.0, weight].map(|w| {
            vec![
                format!("dlf.weights={:?}", weights.display().to_string()),
                format!("joint.terms.energy.weight={w}"),
                "joint.dlf_optim.lr=0.0".into(),
                "joint.epochs=2".into(),
                // an evaluation (the diagnostics) after every epoch
                "joint.preview_every=3".into(),
            ]
        }),
    );
    let run = &runs[0].run;
    let (data, states) = held_rollout(run);
    let gravity = run.load_dlf(&run.exp.dlf.weights).unwrap().config.gravity;
    let unit = 9.81 * f64::from(data.radius);
    let (mut fluid, mut particle) = (Vec::new(), Vec::new());
    for pair in states.windows(2) {
        let ((pos, vel), (p, v)) = (&pair[0], &pair[1]);
        let gain = energy_by_hand(p, v, gravity) - energy_by_hand(pos, vel, gravity);
        fluid.push(weight * gain.max(0.0) / unit);
        let each = (0..p.len())
            .map(|i| {
                let one =
                    |x: &[[f32; 3]], u: &[[f32; 3]]| energy_by_hand(&x[i..=i], &u[i..=i], gravity);
                (one(p, v) - one(pos, vel)).max(0.0)
            })
            .sum::<f64>()
            / p.len() as f64;
        particle.push(weight * each / unit);
    }
    assert!(
        fluid.iter().any(|&g| g > 1e-3),
        "the DLF gains no energy on this scene: the test would see nothing ({fluid:?}, {particle:?})"
    );
    assert!(
        fluid
            .iter()
            .zip(&particle)
            .any(|(a, b)| (b - a).abs() > 1e-2 * a.max(1.0)),
        "the fluid's and each particle's gains agree at every step: the test would not tell \
         the diagnostics apart ({fluid:?}, {particle:?})"
    );
    // the joint diagnostics log the same rollout's gains in both forms (its DLF held): from
    // positions alone, the steps from t = 2 on, which are the transitions after the first
    let logged = rows_of(&runs[0].jsonl, "joint-preview");
    for (key, gains) in [
        ("rollout_energy_gain", &fluid),
        ("rollout_particle_energy_gain", &particle),
    ] {
        let expected = gains[1..].iter().sum::<f64>() * unit / weight;
        let values: Vec<f64> = logged.iter().filter_map(|r| r.get(key)).collect();
        assert!(!values.is_empty(), "no {key} logged");
        for v in values {
            assert!(
                (v - expected).abs() <= 1e-4 * expected.max(1e-3),
                "{key}: logged {v}, by hand {expected}"
            );
        }
    }
    assert_loss_rises_by(&runs[0], &runs[1], &fluid, 1.0, "fluid");
    assert_term_logged(&runs[1], "energy", &fluid, 1.0);
    assert_term_logged(&runs[0], "energy", &[], 1.0);
}

/// `[joint.terms.truth]`: with DLF held (lr 0) each step's loss rises by exactly w times the
/// mean squared distance, in particle radii², from the step's prediction to the true particles
/// of its frame, computed here by hand from an independent rollout and the scene's truth; a
/// scene whose truth is not the predicted particles is refused naming the key.
#[test]
fn the_truth_term_adds_each_steps_squared_error() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let weight = 3.0;
    let runs = ground_each(
        tmp.path(),
        "truth",
        &[0.0, weight].map(|w| {
            vec![
                format!("joint.terms.truth.weight={w}"),
                "joint.dlf_optim.lr=0.0".into(),
                "joint.epochs=2".into(),
            ]
        }),
    );
    let run = &runs[0].run;
    let (data, states) = held_rollout(run);
    let truth = data
        .truth
        .clone()
        .expect("the tiny scene has its true particles");
    let r2 = f64::from(data.radius).powi(2);
    let terms: Vec<f64> = states[1..]
        .iter()
        .zip(&truth[1..])
        .map(|((pos, _), true_pos)| {
            let squared: f64 = pos
                .iter()
                .zip(true_pos)
                .map(|(p, q)| (0..3).map(|k| f64::from(p[k] - q[k]).powi(2)).sum::<f64>())
                .sum();
            weight * squared / pos.len() as f64 / r2
        })
        .collect();
    assert_eq!(terms.len() as u64, data.transitions());
    assert!(terms.iter().all(|&t| t > 1e-4), "{terms:?}");
    assert_loss_rises_by(&runs[0], &runs[1], &terms, 1e-2, "truth");
    assert_term_logged(&runs[1], "truth", &terms, 1e-2);
    let dlf = run.load_dlf(&run.exp.dlf.weights).unwrap();
    // initial particles that are not the truth's (another count) are refused, naming the key
    let mut other = data;
    other.initial.pos.pop();
    other.initial.vel.pop();
    let physnerf = PhysNerf::new(run.physnerf_config(), &run.device).unwrap();
    let mut cfg = run.exp.joint.clone();
    cfg.terms.truth = Some(joint::terms::truth::TruthSettings {
        weight: 1.0,
        matching: Default::default(),
    });
    let err = joint::JointTrainer::new(&cfg, physnerf, dlf, other, 0)
        .err()
        .expect("refused")
        .to_string();
    assert!(err.contains("joint.terms.truth"), "{err}");
}

/// The diagnostics log the rollout's mean kernel density relative to the first state's
/// (`rollout_density`), the mean over the training frames, as computed here by hand from an
/// independent rollout of the held DLF.
#[test]
fn the_rollouts_density_is_logged() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let runs = ground_each(
        tmp.path(),
        "density",
        &[vec![
            "joint.dlf_optim.lr=0.0".to_string(),
            "joint.epochs=2".into(),
            "joint.preview_every=3".into(),
        ]],
    );
    let (data, states) = held_rollout(&runs[0].run);
    let support = SUPPORT_RADII * data.radius;
    let rest = mean_density(&data.initial.pos, support);
    let ratios: Vec<f64> = states[1..]
        .iter()
        .map(|(pos, _)| mean_density(pos, support) / rest)
        .collect();
    let expected = ratios.iter().sum::<f64>() / ratios.len() as f64;
    let logged: Vec<f64> = rows_of(&runs[0].jsonl, "joint-preview")
        .iter()
        .filter_map(|r| r.get("rollout_density"))
        .collect();
    assert!(!logged.is_empty(), "no rollout_density logged");
    for v in logged {
        assert!(
            (v - expected).abs() < 1e-6,
            "logged {v}, by hand {expected}"
        );
    }
}
