//! The warm-up step with every view's rays in one pass (the default on an accelerator: one read
//! of the coarse weights and one set of kernel launches per step) is the step with one pass per
//! view (the CPU's): the same loss (the views' MSEs summed), PSNR and gradient norm, step after
//! step, on the tiny experiment's warm-up views (depths not jittered, so both draw the same
//! pixels). Runs on the device `$NEUROFLUID_TEST_DEVICE` names.

use neurofluid_tests::{seeded_turn, tiny_experiment};
use neurofluid_train::stage::Stage;
use neurofluid_train::stages::{Run, Start, warmup};
use neurofluid_train::trainer::{StepStats, Trainer};

fn close(a: f64, b: f64, what: &str) {
    assert!(
        (a - b).abs() <= 1e-4 * a.abs().max(b.abs()),
        "{what}: {a} in one pass, {b} view by view"
    );
}

#[test]
fn one_pass_over_the_views_is_the_views_one_by_one() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let run = Run::prepare(
        tiny_experiment(tmp.path(), "warmup-passes"),
        Start::Resume,
        &[Stage::Warmup],
    )
    .unwrap();
    assert!(
        !run.physnerf_config().stratified,
        "the pixels alone are drawn"
    );
    let steps = |one_pass: bool| -> Vec<StepStats> {
        let data = warmup::warmup_data(&run).unwrap();
        assert!(data.views.len() > 1, "several warm-up views");
        let physnerf = warmup::new_physnerf(&run).unwrap();
        let mut trainer = warmup::WarmupTrainer::new(&run.exp.warmup, physnerf, data, run.exp.seed)
            .with_one_pass(one_pass);
        (0..3).map(|s| trainer.step(s).unwrap()).collect()
    };
    let (one, each) = (steps(true), steps(false));
    for (s, (a, b)) in one.iter().zip(&each).enumerate() {
        close(a.loss, b.loss, &format!("step {s}'s loss"));
        close(
            a.psnr.unwrap(),
            b.psnr.unwrap(),
            &format!("step {s}'s PSNR"),
        );
        close(
            a.grad_norms[0].1,
            b.grad_norms[0].1,
            &format!("step {s}'s gradient norm"),
        );
        assert_eq!(a.rays, b.rays);
    }
}
