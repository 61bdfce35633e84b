//! The example experiment and sweep files in `experiments/` load, resolve and stay consistent.

use std::path::{Path, PathBuf};

use neurofluid_core::sampler::Rng;
use neurofluid_train::config::{Experiment, RESOLVED_FILE};
use neurofluid_train::sweep::Sweep;

fn experiments_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../experiments")
}

fn example(name: &str) -> Experiment {
    let path = experiments_dir().join(name);
    Experiment::load(&path).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn every_example_experiment_loads_and_round_trips() {
    let mut names = Vec::new();
    for entry in std::fs::read_dir(experiments_dir()).unwrap() {
        let path = entry.unwrap().path();
        let file = path.file_name().unwrap().to_string_lossy().into_owned();
        if !file.ends_with(".toml") || file.starts_with("sweep") {
            continue;
        }
        let exp = Experiment::load(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(format!("{}.toml", exp.name), file, "name matches the file");
        let dir = tempfile::tempdir().unwrap();
        let resolved = exp.save_resolved(dir.path()).unwrap();
        assert_eq!(resolved, dir.path().join(RESOLVED_FILE));
        assert_eq!(Experiment::load(&resolved).unwrap(), exp.resolved());
        names.push(file);
    }
    names.sort();
    for needed in [
        "paper-watercube.toml",
        "quick-honeycone.toml",
        "quick-waterbunny.toml",
        "quick-watercube.toml",
        "quick-watersphere.toml",
        "tiny-ci.toml",
    ] {
        assert!(
            names.iter().any(|n| n == needed),
            "missing {needed} in {names:?}"
        );
    }
}

#[test]
fn paper_file_spells_out_the_defaults() {
    let paper = example("paper-watercube.toml");
    let defaults = Experiment::from_toml_str(
        // the one setting that is not a default: the NeRF-T baseline's images
        "name = \"paper-watercube\"\n[scene]\nbuiltin = \"watercube\"\nscale = \"paper\"\n\
         [scene.generate]\nwarmup_every_frame = true\n",
        Path::new("defaults"),
    )
    .unwrap();
    assert_eq!(paper, defaults);
}

#[test]
fn ci_budget_fits_its_tiny_images() {
    let e = example("tiny-ci.toml");
    let size = e.scene.generate["image_size"].as_integer().unwrap() as u32;
    let mut rng = Rng::new(e.seed);
    // the precrop window of the tiny image holds enough pixels for a ray batch
    assert!(e.warmup.precrop_iters > 0);
    rng.sample_pixels(e.warmup.rays, size, size, Some(e.warmup.precrop_frac))
        .unwrap();
    rng.sample_pixels(e.joint.rays, size, size, e.joint.precrop_at(0))
        .unwrap();
    assert!(e.warmup.iters <= 10 && e.joint.epochs <= 2);
}

#[test]
fn encoding_sweep_expands_to_table5() {
    let sweep = Sweep::load(&experiments_dir().join("sweep-encodings.toml")).unwrap();
    assert_eq!(sweep.name, "sweep-encodings");
    // the file spells out the default set (whose names the sweep's unit test pins)
    let named: Vec<(&str, &str)> = sweep
        .variants
        .iter()
        .map(|v| (v.name.as_str(), v.label.as_str()))
        .collect();
    let defaults = neurofluid_train::sweep::table5_variants();
    let expected: Vec<(&str, &str)> = defaults
        .iter()
        .map(|v| (v.name.as_str(), v.label.as_deref().unwrap_or(&v.name)))
        .collect();
    assert_eq!(named, expected);
    let off: Vec<usize> = sweep
        .variants
        .iter()
        .map(|v| {
            let e = v.experiment.physnerf.encoding;
            [e.pc, e.sigma_p, e.vd, e.dc]
                .iter()
                .filter(|on| !**on)
                .count()
        })
        .collect();
    assert_eq!(off, [0, 0, 1, 1, 1, 1]);
    let from_images: Vec<bool> = sweep
        .variants
        .iter()
        .map(|v| {
            v.experiment.scene.initial == neurofluid_train::config::InitialParticles::FromImages
        })
        .collect();
    assert_eq!(from_images, [false, true, false, false, false, false]);
    let base = example("quick-watercube.toml");
    for v in &sweep.variants {
        assert_eq!(
            v.experiment.out_dir(),
            Path::new("runs/sweep-encodings").join(&v.name)
        );
        assert_eq!(
            v.experiment.joint, base.joint,
            "only the encodings and the initial particles vary"
        );
    }
}

#[test]
fn generator_settings_are_accepted_by_the_scene_generator() {
    for name in [
        "quick-watercube.toml",
        "quick-watersphere.toml",
        "quick-honeycone.toml",
        "quick-waterbunny.toml",
        "paper-watercube.toml",
        "tiny-ci.toml",
    ] {
        let e = example(name);
        let table = e.scene.generator_table().expect("built-in scene");
        let cfg: neurofluid_scenegen::SceneConfig = toml::Value::Table(table)
            .try_into()
            .unwrap_or_else(|err| panic!("{name}: {err}"));
        cfg.validate(Path::new(name))
            .unwrap_or_else(|err| panic!("{name}: {err}"));
        assert_eq!(cfg.name.name(), e.scene.builtin.unwrap().name());
        assert_eq!(cfg.out_dir(), e.scene.scene_dir());
    }
}

/// The quick configs' learning rates per update are the ones they had when their milestones
/// counted iterations (`[147, 221]`): DLF's milestones now count its own updates, one per window
/// of `bptt_steps` transitions and one at every epoch's end, and were converted to `[39, 57]`.
#[test]
fn the_quick_configs_keep_their_learning_rate_per_update() {
    use neurofluid_core::lr_schedule::Schedule;
    use neurofluid_train::stages::joint::{updates_after, updates_before};
    // 50 training frames in every quick scene and every test-bed scene
    const TRANSITIONS: u64 = 49;
    // the iterations after which DLF's rate halves: windows of 4 transitions (the quick configs)
    // with `[39, 57]`; windows of 8 (the bed's water, rule 21) with `[21, 31]`, as screened: one
    // window of 8 later than 4's (the updates at iterations 160 and 232 against 152 and 224)
    let iteration_milestones = |bptt_steps: usize| Schedule::MultiStep {
        milestones: if bptt_steps == 8 {
            vec![152, 224]
        } else {
            vec![147, 221]
        },
        gamma: 0.5,
    };
    let mut files: Vec<PathBuf> = Vec::new();
    for dir in [experiments_dir(), experiments_dir().join("bed")] {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            if name.starts_with("quick-") || path.parent().unwrap().ends_with("bed") {
                files.push(path);
            }
        }
    }
    files.retain(|p| p.extension().is_some_and(|e| e == "toml"));
    assert!(files.len() >= 10, "{files:?}");
    for path in files {
        let exp = Experiment::load(&path).unwrap_or_else(|e| panic!("{e}"));
        let j = &exp.joint;
        let total = j.epochs * TRANSITIONS;
        let (mut physnerf, mut dlf) = (0, 0);
        for step in 0..total {
            let u = updates_after(j, TRANSITIONS, total, step);
            if u.physnerf {
                // PhysNeRF's milestones (the paper's, 10k and later) are never reached
                let before = j.physnerf_optim.lr_at(step);
                assert_eq!(j.physnerf_optim.lr_at(physnerf), before, "{path:?} {step}");
                physnerf += 1;
            }
            if u.dlf {
                let before = j.dlf_optim.lr * iteration_milestones(j.bptt_steps).factor_at(step);
                assert_eq!(j.dlf_optim.lr_at(dlf), before, "{path:?} step {step}");
                dlf += 1;
            }
        }
        // windows of 4 (the quick configs) or 8 (the bed's water, rule 21) transitions
        let (all, by_148) = match j.bptt_steps {
            4 => (78, 40),
            8 => (42, 21),
            other => panic!("{path:?}: bptt_steps {other}"),
        };
        assert_eq!((physnerf, dlf), (all, all), "{path:?}");
        // what a checkpoint written before the groups counted their updates is resumed with
        assert_eq!(updates_before(j, TRANSITIONS, total, 148), (by_148, by_148));
        assert_eq!(updates_before(j, TRANSITIONS, total, total), (all, all));
    }
}

/// The closed form against the updates counted one iteration at a time, over windows,
/// DLF cadences, epoch lengths, stage lengths and checkpoints that fall anywhere; and a
/// checkpoint's step of 2^64 − 1 is counted at once (it looped for ever; issue 72).
#[test]
fn updates_before_counts_what_updates_after_says() {
    use neurofluid_train::config::JointSection;
    use neurofluid_train::stages::joint::{updates_after, updates_before};
    for bptt_steps in 1..=5 {
        for dlf_every in 1..=3 {
            let cfg = JointSection {
                bptt_steps,
                dlf_every,
                ..JointSection::default()
            };
            for transitions in 1..=7u64 {
                for total in [1, transitions, 2 * transitions + 3, 5 * transitions] {
                    let mut counted = (0, 0);
                    for done in 0..=total + 4 {
                        assert_eq!(
                            updates_before(&cfg, transitions, total, done),
                            counted,
                            "bptt {bptt_steps}, dlf every {dlf_every}, {transitions} a \
                             epoch, {total} in all, {done} done"
                        );
                        let u = updates_after(&cfg, transitions, total, done);
                        counted.0 += u64::from(u.physnerf);
                        counted.1 += u64::from(u.dlf);
                    }
                }
            }
        }
    }
    let cfg = JointSection::default();
    let (p, d) = updates_before(&cfg, 49, 294, u64::MAX);
    assert!(p >= d && p > 0);
}
