//! End-to-end tests across the NeuroFluid-rs crates live in `tests/tests/`; this library holds
//! the helpers they share.

use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};

use burn::module::{Module, ModuleVisitor, Param};
use burn::prelude::*;
use neurofluid_train::config::Experiment;

/// The workspace root (for experiment files, weights and test data).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ sits in the workspace root")
        .to_path_buf()
}

/// Burn's backend RNG, which initialises models from the experiment's seed, is global to the
/// process, and every test of `end_to_end` shares one: the tests that build seeded models take
/// turns through this lock, and so do those that draw from it unseeded (a model built from
/// scratch draws its weights; loading one from a file draws nothing: `loading_draws`), lest a
/// draw land between a seed and the model it seeds.
pub fn seeded_turn() -> MutexGuard<'static, ()> {
    static SEEDED: Mutex<()> = Mutex::new(());
    SEEDED.lock().unwrap_or_else(|e| e.into_inner())
}

#[derive(Default)]
struct Collect(Vec<Vec<f32>>);

impl ModuleVisitor for Collect {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        self.0
            .push(param.val().try_into_vec_as::<f32>().expect("float data"));
    }
}

/// Every float parameter of a module, in visiting order.
pub fn params<M: Module>(m: &M) -> Vec<Vec<f32>> {
    let mut c = Collect::default();
    m.visit(&mut c);
    c.0
}

/// A built-in scene's preset in a small box ([−0.4, 0.4] × [−0.4, 0.6] × [−0.4, 0.4]) with a
/// small body `shape`: fast enough for CI.
pub fn small_preset(
    kind: neurofluid_scenegen::SceneKind,
    shape: neurofluid_scenegen::shapes::Shape,
) -> neurofluid_scenegen::Preset {
    use neurofluid_scenegen::{Preset, Scale, SceneConfig};
    let mut p = Preset::resolve(&SceneConfig::new(kind, Scale::Quick));
    p.box_lo = [-0.4, -0.4, -0.4];
    p.box_hi = [0.4, 0.6, 0.4];
    p.shape = shape;
    p
}

/// `experiments/tiny-ci.toml` with its run folder `<tmp>/<name>`, its scene in `<tmp>/scene`
/// and absolute paths, so tests run from any working directory; on the device
/// `$NEUROFLUID_TEST_DEVICE` names (the CPU when unset).
pub fn tiny_experiment(tmp: &Path, name: &str) -> Experiment {
    let root = workspace_root();
    let mut e =
        Experiment::load(&root.join("experiments/tiny-ci.toml")).expect("tiny-ci.toml loads");
    e.name = name.into();
    e.out_dir = Some(tmp.join(name));
    e.scene.dir = Some(tmp.join("scene"));
    e.dlf.weights = root.join("assets/dlf_pretrained/pretrained_model_weights.pt");
    e.device = neurofluid_core::device::test_device_name();
    e
}

/// [`tiny_experiment`] as the exact-resume tests run it: checkpoints only where a test stops it,
/// and enough rays that the image loss reaches the particles in every joint iteration.
pub fn tiny_resumable_experiment(tmp: &Path, name: &str) -> Experiment {
    let mut e = tiny_experiment(tmp, name);
    e.apply_overrides(&[
        "warmup.ckpt_every=0",
        "joint.ckpt_every=0",
        "joint.rays=512",
    ])
    .expect("the overrides apply");
    e
}

/// Every file under `root`, as paths relative to it, sorted.
pub fn files_under(root: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push(p.strip_prefix(root).unwrap().to_path_buf());
            }
        }
    }
    out.sort();
    out
}

/// Every file under `root` (as [`files_under`] names them) with its bytes.
pub fn contents(root: &Path) -> std::collections::BTreeMap<PathBuf, Vec<u8>> {
    files_under(root)
        .into_iter()
        .map(|f| {
            let bytes = std::fs::read(root.join(&f)).unwrap();
            (f, bytes)
        })
        .collect()
}

/// Copies the folder `from` to `to` (files and subfolders).
pub fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        let q = to.join(p.file_name().unwrap());
        if p.is_dir() {
            copy_dir(&p, &q);
        } else {
            std::fs::copy(&p, &q).unwrap();
        }
    }
}

/// Declares `view`, a copy of the scene's first test view under that name, as the validation
/// view of the scene in `scene_dir` (the same camera and images: it must score as the test view).
pub fn add_validation_copy(scene_dir: &Path, view: &str) {
    use neurofluid_core::scene::{MANIFEST_FILE, SceneManifest, ViewSet};
    let path = scene_dir.join(MANIFEST_FILE);
    let mut m = SceneManifest::read(&path).unwrap();
    copy_dir(&scene_dir.join(&m.test.views[0]), &scene_dir.join(view));
    m.validation = Some(ViewSet {
        views: vec![view.into()],
        ..m.test.clone()
    });
    m.write(&path).unwrap();
}

/// Asserts that `validation` scored the views of `add_validation_copy` (named `view`) frame by
/// frame exactly as `test` scored the test view `test_view`: the same camera and images.
pub fn assert_scored_as_the_test_view(
    validation: &[neurofluid_outputs::report::ImageScore],
    test: &[neurofluid_outputs::report::ImageScore],
    view: &str,
    test_view: &str,
) {
    assert_eq!(validation.len(), test.len());
    assert!(!validation.is_empty());
    for (v, t) in validation.iter().zip(test) {
        assert_eq!((v.view.as_str(), t.view.as_str()), (view, test_view));
        assert_eq!(
            (v.t, v.psnr, v.ssim, v.lpips),
            (t.t, t.psnr, t.ssim, t.lpips),
            "the same camera and images score the same"
        );
    }
}
