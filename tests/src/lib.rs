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
/// process: tests that build seeded models take turns through this lock.
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
