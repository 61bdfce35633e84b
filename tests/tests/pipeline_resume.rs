//! The tiny experiment end to end, and exact resume: a run stopped in the middle of the warm-up
//! and in the middle of a joint epoch (with a carried particle state) and resumed from its
//! checkpoints ends with the same parameters as a run that never stopped.

use std::path::Path;

use burn::module::{Module, ModuleVisitor, Param};
use burn::prelude::*;
use neurofluid_tests::workspace_root;
use neurofluid_train::config::Experiment;
use neurofluid_train::metrics_log::MetricsLog;
use neurofluid_train::stages::{Run, eval, joint, warmup};

/// Every float parameter of a module, in visiting order.
#[derive(Default)]
struct Collect(Vec<Vec<f32>>);

impl ModuleVisitor for Collect {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        self.0
            .push(param.val().try_into_vec_as::<f32>().expect("float data"));
    }
}

/// Burn's backend RNG (which initialises the renderer from the experiment's seed) is global to
/// the process: tests that build models from a seed take turns.
static SEEDED: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn params<M: Module>(m: &M) -> Vec<Vec<f32>> {
    let mut c = Collect::default();
    m.visit(&mut c);
    c.0
}

fn experiment(tmp: &Path, name: &str) -> Experiment {
    let root = workspace_root();
    let mut e =
        Experiment::load(&root.join("experiments/tiny-ci.toml")).expect("tiny-ci.toml loads");
    e.name = name.into();
    e.out_dir = Some(tmp.join(name));
    e.scene.dir = Some(tmp.join("scene"));
    e.dlf.weights = root.join("assets/dlf_pretrained/pretrained_model_weights.pt");
    // enough rays that the image loss reaches the particles in every joint iteration
    e.apply_overrides(&[
        "warmup.ckpt_every=0",
        "joint.ckpt_every=0",
        "joint.rays=512",
    ])
    .unwrap();
    e
}

#[test]
fn resumed_run_matches_uninterrupted_run() {
    let _turn = SEEDED.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();

    let straight = Run::open(experiment(tmp.path(), "straight")).unwrap();
    let mut log = MetricsLog::open(&straight.dir).unwrap();
    warmup::run(&straight, &mut log).unwrap();
    let a = joint::run(&straight, &mut log).unwrap();

    let pieces = Run::open(experiment(tmp.path(), "pieces")).unwrap();
    let mut log = MetricsLog::open(&pieces.dir).unwrap();
    let warm_iters = pieces.exp.warmup.iters;
    assert!(warm_iters >= 2);
    warmup::run_until(&pieces, &mut log, Some(warm_iters / 2)).unwrap();
    warmup::run(&pieces, &mut log).unwrap();
    // stop inside the first epoch: the carried (predicted) state goes into the checkpoint
    joint::run_until(&pieces, &mut log, Some(2)).unwrap();
    let b = joint::run(&pieces, &mut log).unwrap();

    let (pa, pb) = (params(&a.renderer), params(&b.renderer));
    assert_eq!(pa.len(), pb.len());
    assert!(pa == pb, "renderer parameters differ after resuming");
    assert!(
        params(&a.dlf) == params(&b.dlf),
        "DLF parameters differ after resuming"
    );
    // and training did change the transition model
    let start = straight.load_dlf(&straight.exp.dlf.weights).unwrap();
    assert!(
        params(&start) != params(&a.dlf),
        "joint training left DLF unchanged"
    );

    // the evaluation runs on the result and reports both models
    let report = eval::run(&straight, &a).unwrap();
    let s = report.summary();
    assert!(s.grounding.neurofluid_d.unwrap().is_finite());
    assert!(s.grounding.dlf_d.unwrap().is_finite());
    assert!(
        straight.dir.join("eval").join("report.json").is_file()
            || straight.dir.join("eval").read_dir().unwrap().count() > 0
    );
}

#[test]
fn stratified_jitter_is_seeded_and_reproducible() {
    let _turn = SEEDED.lock().unwrap_or_else(|e| e.into_inner());
    let tmp = tempfile::tempdir().unwrap();
    let mut params_of = Vec::new();
    for name in ["jitter-a", "jitter-b"] {
        let mut e = experiment(tmp.path(), name);
        e.apply_overrides(&["renderer.jitter=true"]).unwrap();
        let run = Run::open(e).unwrap();
        let mut log = MetricsLog::open(&run.dir).unwrap();
        params_of.push(params(&warmup::run(&run, &mut log).unwrap()));
    }
    assert!(
        params_of[0] == params_of[1],
        "same seed, different jittered warm-up"
    );
}
