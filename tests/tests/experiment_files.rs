//! Every experiment and sweep file that ships in `experiments/` (the scene configs in
//! `experiments/scenes/` have their own test; the research records in `experiments/research/`
//! are kept as they ran, with the options of their day) loads as a user would run it from the
//! repository root: experiments parse and validate, sweeps resolve every variant's overrides,
//! and the reference files in `experiments/reference/` (`eval.reference`) read.

use std::path::{Path, PathBuf};

use neurofluid_outputs::reference::ReferenceFile;
use neurofluid_tests::workspace_root;
use neurofluid_train::config::{Experiment, SearchObjective};
use neurofluid_train::sweep::Sweep;

fn toml_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            if path
                .file_name()
                .is_some_and(|n| n != "scenes" && n != "research")
            {
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
    let (mut experiments, mut sweeps, mut references) = (0, 0, 0);
    for path in &files {
        let text = std::fs::read_to_string(path).unwrap();
        let is_sweep = text.lines().any(|l| l.trim_start().starts_with("base ="));
        if path.parent().is_some_and(|d| d.ends_with("reference")) {
            let file = ReferenceFile::read(path).unwrap_or_else(|e| panic!("{e}"));
            assert!(!file.scenes.is_empty(), "{}", path.display());
            references += 1;
        } else if is_sweep {
            let sweep = Sweep::load(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert!(!sweep.variants.is_empty(), "{}", path.display());
            sweeps += 1;
        } else {
            Experiment::load(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            experiments += 1;
        }
    }
    assert!(
        experiments >= 8 && sweeps >= 1 && references >= 1,
        "{experiments} experiments, {sweeps} sweeps, {references} reference files"
    );
}

/// The quick configs are copies of the main job's that differ only in the scene (the sweeps in
/// `experiments/research/grounding/constant-lr-*.toml` rely on it), and the from-images one only in where
/// the initial particles come from: one config for every fluid (issue 71), with no material
/// switch; a setting changed in one copy and not the others fails here.
#[test]
fn quick_configs_differ_from_the_main_job_only_in_the_scene() {
    use neurofluid_train::config::Settings;
    let root = workspace_root();
    let experiment = |name: &str| {
        let path = root.join("experiments").join(format!("{name}.toml"));
        Experiment::load(&path).unwrap_or_else(|e| panic!("{name}: {e}"))
    };
    let load = |name: &str| Settings::all(&experiment(name));
    // each copy runs the scene its name says, at the paper's gravity and without the energy
    // cap, the physical scalars chosen by the images' silhouette, then DLF grounded under the
    // anchor and the energy prior, whatever the fluid
    for scene in ["watercube", "watersphere", "waterbunny", "honeycone"] {
        let e = experiment(&format!("quick-{scene}"));
        assert_eq!(e.scene.builtin.map(|b| b.name()), Some(scene));
        assert_eq!(e.dlf.rules.energy_cap, neurofluid_dlf::EnergyCap::None);
        assert_eq!(
            e.dlf.rules.gravity_scale, 1.0,
            "quick-{scene}: gravity scale"
        );
        let search = e.joint.physics.as_ref().and_then(|p| p.search.as_ref());
        assert!(
            search.is_some_and(|s| s.objective == SearchObjective::Silhouette),
            "quick-{scene}: the images choose the physical scalars"
        );
        let terms = &e.joint.terms;
        assert!(
            terms.anchor.is_some() && terms.energy.is_some(),
            "quick-{scene}"
        );
    }
    let main = load("quick-watercube");
    let scene_keys = [
        "name",
        "out_dir",
        "scene.builtin",
        "scene.generate.warmup_every_frame",
    ];
    for (name, allowed) in [
        ("quick-honeycone", &scene_keys[..]),
        ("quick-waterbunny", &scene_keys[..]),
        ("quick-watersphere", &scene_keys[..]),
        (
            "quick-watercube-from-images",
            &["name", "out_dir", "scene.initial"][..],
        ),
    ] {
        let changed: Vec<String> = load(name)
            .changes_since(&main)
            .iter()
            .map(|c| c.to_string())
            .collect();
        assert!(
            changed
                .iter()
                .all(|c| allowed.iter().any(|k| c.starts_with(&format!("{k}: ")))),
            "{name} differs from quick-watercube beyond {allowed:?}: {changed:#?}"
        );
        assert!(changed.iter().any(|c| c.starts_with("name: ")), "{name}");
    }
}
