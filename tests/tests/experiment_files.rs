//! Every experiment and sweep file in `experiments/` (the scene configs in `experiments/scenes/`
//! have their own test) loads as a user would run it from the repository root: experiments
//! parse and validate, sweeps resolve every variant's overrides.

use std::path::{Path, PathBuf};

use neurofluid_tests::workspace_root;
use neurofluid_train::config::Experiment;
use neurofluid_train::sweep::Sweep;

fn toml_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            if path.file_name().is_some_and(|n| n != "scenes") {
                toml_files(&path, out);
            }
        } else if path.extension().is_some_and(|e| e == "toml") {
            out.push(path);
        }
    }
}

#[test]
fn every_experiment_and_sweep_file_loads() {
    let root = workspace_root();
    // sweep bases are relative to the repository root, where the trainer runs
    std::env::set_current_dir(&root).unwrap();
    let mut files = Vec::new();
    toml_files(&root.join("experiments"), &mut files);
    files.sort();
    let (mut experiments, mut sweeps) = (0, 0);
    for path in &files {
        let text = std::fs::read_to_string(path).unwrap();
        let is_sweep = text.lines().any(|l| l.trim_start().starts_with("base ="));
        if is_sweep {
            let sweep = Sweep::load(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert!(!sweep.variants.is_empty(), "{}", path.display());
            sweeps += 1;
        } else {
            Experiment::load(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            experiments += 1;
        }
    }
    assert!(
        experiments >= 8 && sweeps >= 6,
        "{experiments} experiments, {sweeps} sweeps"
    );
}
