//! Regression tests for inputs that used to slip through: each one now gets a clear error that
//! names the file or key, before any training time is spent, or a guarded stop; none panics and
//! none trains on something wrong.

use std::path::{Path, PathBuf};

use neurofluid_core::scene::{BoxParticles, Particles, Role, write_png_rgba};
use neurofluid_tests::{seeded_turn, tiny_experiment};
use neurofluid_train::config::Experiment;
use neurofluid_train::stage::Stage;
use neurofluid_train::stages::{Run, Start, joint, warmup};

/// The tiny experiment with its scene generated.
fn prepared(tmp: &Path, name: &str) -> Experiment {
    let e = tiny_experiment(tmp, name);
    drop(Run::prepare(e.clone(), Start::Resume, &Stage::ALL).unwrap());
    e
}

fn image_path(run: &Run, role: Role, view: &str, t: usize) -> PathBuf {
    run.scene
        .view_split(role, view)
        .unwrap()
        .image_path(t)
        .unwrap()
}

fn preflight_error(e: Experiment) -> String {
    format!(
        "{:#}",
        Run::prepare(e, Start::Resume, &Stage::ALL).unwrap_err()
    )
}

#[test]
fn every_bad_input_is_listed_before_the_first_iteration() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let mut e = prepared(tmp.path(), "inputs");
    let run = Run::prepare(e.clone(), Start::Resume, &Stage::ALL).unwrap();
    // a larger test image, a smaller training image (each view's first image sets its size), a
    // test frame missing particles, a missing weights file and a view the scene does not have
    let big = image_path(&run, Role::Test, "view_5", 1);
    write_png_rgba(&big, 40, 40, &vec![255; 40 * 40 * 4]).unwrap();
    let small = image_path(&run, Role::Train, "view_1", 2);
    write_png_rgba(&small, 8, 8, &vec![255; 8 * 8 * 4]).unwrap();
    let t_last = run.scene.frames(Role::Test).end - 1;
    let mut fewer = run.scene.particles(Role::Test, t_last).unwrap();
    fewer.pos.pop();
    fewer.vel.pop();
    let view = &run.scene.views(Role::Test)[0];
    let particle_file = run
        .scene
        .view_split(Role::Test, view)
        .unwrap()
        .particle_path(t_last)
        .unwrap();
    fewer.write(&particle_file).unwrap();
    drop(run);
    e.dlf.weights = tmp.path().join("missing.pt");
    e.eval.views = Some(vec!["view_5".into(), "view_9".into()]);

    let err = preflight_error(e);
    for needle in [
        big.display().to_string(),
        "40×40".into(),
        small.display().to_string(),
        "8×8".into(),
        format!("frame {t_last} has"),
        "missing.pt".into(),
        "view_9".into(),
    ] {
        assert!(err.contains(&needle), "`{needle}` not in:\n{err}");
    }
    // nothing ran
    assert!(!tmp.path().join("inputs/warmup").exists());
}

#[test]
fn a_wrong_size_image_is_refused_when_read() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let e = prepared(tmp.path(), "size");
    // a training frame larger than its view's first frame (which sets the camera's size)
    let run = Run::prepare(e, Start::Resume, &[]).unwrap();
    let path = image_path(&run, Role::Train, "view_1", 2);
    write_png_rgba(&path, 33, 32, &vec![255; 33 * 32 * 4]).unwrap();
    let err = run
        .scene
        .image(Role::Train, "view_1", 2)
        .unwrap_err()
        .to_string();
    assert!(err.contains(&path.display().to_string()), "{err}");
    assert!(err.contains("33×32"), "{err}");
    // and the joint stage, run without the preflight, stops on it, naming the file
    let mut log = run.open_log().unwrap();
    warmup::run(&run, &mut log).unwrap();
    let err = format!("{:#}", joint::run(&run, &mut log).unwrap_err());
    assert!(err.contains(&path.display().to_string()), "{err}");
}

#[test]
fn a_box_without_particles_is_refused() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let e = prepared(tmp.path(), "box");
    let run = Run::prepare(e.clone(), Start::Resume, &Stage::ALL).unwrap();
    let path = run.scene.box_path();
    let npz = path.with_extension("npz");
    BoxParticles {
        points: Vec::new(),
        normals: Vec::new(),
    }
    .write(&npz)
    .unwrap();
    drop(run);
    let err = preflight_error(e);
    assert!(err.contains("box particle"), "{err}");
}

/// A search radius no sample can use gives a loss that depends on no parameter: a clear stop,
/// not "backward requires a tracked tensor".
#[test]
fn a_loss_without_parameters_stops_with_the_reason() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    // a radius no sample can use, and a ray segment that starts behind the fluid
    for (name, setting) in [
        ("radius", "physnerf.search_radius=1e-6"),
        ("near", "scene.near=5.0"),
    ] {
        let mut e = prepared(tmp.path(), name);
        e.apply_override(setting).unwrap();
        let run = Run::prepare(e, Start::Resume, &Stage::ALL).unwrap();
        let mut log = run.open_log().unwrap();
        let err = format!("{:#}", warmup::run(&run, &mut log).unwrap_err());
        assert!(err.contains("received no gradient"), "{setting}: {err}");
        assert!(err.contains("physnerf.search_radius"), "{setting}: {err}");
        assert!(err.contains("scene.near"), "{setting}: {err}");
    }
}

/// DLF exploding in the joint stage is stopped by the state check, and no checkpoint holds the
/// exploded state.
#[test]
fn an_exploding_joint_stage_stops_before_checkpointing_it() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let mut e = prepared(tmp.path(), "explode");
    e.apply_overrides(&["joint.dlf_optim.lr=1e4", "joint.ckpt_every=1"])
        .unwrap();
    let run = Run::prepare(e, Start::Resume, &Stage::ALL).unwrap();
    let mut log = run.open_log().unwrap();
    warmup::run(&run, &mut log).unwrap();
    let err = format!("{:#}", joint::run(&run, &mut log).unwrap_err());
    assert!(err.contains("joint stopped at step 2"), "{err}");
    // the checkpoint after step 1 held the update that exploded: discarded, none is left
    assert!(err.contains("discarded"), "{err}");
    let stage = run.stage_dir(joint::STAGE);
    assert!(neurofluid_train::trainer::checkpoint::latest(&stage).is_none());
    if let Some(ckpt) = neurofluid_train::trainer::checkpoint::latest(&stage)
        && let Ok(state) = Particles::read(&ckpt.join("carried_state.npz"))
    {
        assert!(
            state
                .pos
                .iter()
                .flatten()
                .all(|v| v.is_finite() && v.abs() < 10.0),
            "a checkpoint holds the exploded state"
        );
    }
}

/// Optimiser files swapped between the two groups are refused, not silently dropped.
#[test]
fn swapped_optimiser_files_are_refused() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let e = prepared(tmp.path(), "swap");
    let run = Run::prepare(e, Start::Resume, &Stage::ALL).unwrap();
    let mut log = run.open_log().unwrap();
    warmup::run(&run, &mut log).unwrap();
    joint::run_until(&run, &mut log, Some(2)).unwrap();
    let ckpt = run.stage_dir(joint::STAGE).join("checkpoint");
    let (a, b) = (ckpt.join("optim_physnerf.bpk"), ckpt.join("optim_dlf.bpk"));
    let tmp_file = ckpt.join("swap.tmp");
    std::fs::rename(&a, &tmp_file).unwrap();
    std::fs::rename(&b, &a).unwrap();
    std::fs::rename(&tmp_file, &b).unwrap();
    let err = format!("{:#}", joint::run(&run, &mut log).unwrap_err());
    assert!(err.contains("optim_physnerf.bpk"), "{err}");
    assert!(err.contains("does not have"), "{err}");
}

/// A temporary checkpoint folder a killed process left behind is removed when the stage starts.
#[test]
fn orphan_checkpoint_folders_are_removed() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let e = prepared(tmp.path(), "orphan");
    let run = Run::prepare(e, Start::Resume, &Stage::ALL).unwrap();
    let orphan = run.stage_dir(warmup::STAGE).join("checkpoint.99999.tmp");
    std::fs::create_dir_all(&orphan).unwrap();
    std::fs::write(orphan.join("physnerf.bpk"), b"half").unwrap();
    let mut log = run.open_log().unwrap();
    warmup::run(&run, &mut log).unwrap();
    assert!(!orphan.exists());
}

/// Reads `path` as JSON, lets `edit` change it, writes it back.
fn edit_json(path: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    edit(&mut v);
    std::fs::write(path, serde_json::to_string_pretty(&v).unwrap()).unwrap();
}

/// Names and paths in a downloaded scene's files cannot reach outside it: a view name that is
/// not one plain name, an absolute or climbing particle path, a box file outside the scene.
#[test]
fn names_and_paths_in_scene_files_stay_inside_the_scene() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let e = prepared(tmp.path(), "paths");
    let scene_dir = e.scene.scene_dir();
    let manifest = scene_dir.join("scene.json");
    let original = std::fs::read(&manifest).unwrap();
    let evil = tmp.path().join("evilview");
    let climb = format!("../../../../../../../..{}", evil.display());
    edit_json(&manifest, |m| {
        m["test"]["views"] = serde_json::json!([climb])
    });
    let err = preflight_error(e.clone());
    assert!(
        err.contains("scene.json") && err.contains("test.views") && err.contains("plain name"),
        "{err}"
    );
    std::fs::write(&manifest, &original).unwrap();
    edit_json(&manifest, |m| {
        m["box_file"] = serde_json::json!("/etc/passwd")
    });
    let err = preflight_error(e.clone());
    assert!(
        err.contains("box_file") && err.contains("inside the dataset"),
        "{err}"
    );
    std::fs::write(&manifest, &original).unwrap();
    let transforms = scene_dir.join("view_1/transforms_train.json");
    for (key, value) in [
        ("particle_path", "/etc/hostname"),
        ("particle_path", "../../../outside.npz"),
        ("file_path", "../../elsewhere/0000"),
    ] {
        let before = std::fs::read(&transforms).unwrap();
        edit_json(&transforms, |t| {
            t["frames"][1][key] = serde_json::json!(value)
        });
        let err = preflight_error(e.clone());
        assert!(
            err.contains("transforms_train.json")
                && err.contains(&format!("frames[1].{key}"))
                && err.contains("inside the dataset"),
            "{err}"
        );
        std::fs::write(&transforms, before).unwrap();
    }
    assert!(!evil.exists() && !tmp.path().join("evilview.png").exists());
    drop(Run::prepare(e, Start::Resume, &Stage::ALL).unwrap());
}

/// `--fresh` removes only after every check that can fail before the first step: ray counts the
/// images cannot supply, and cameras that disagree with their images or cannot see.
#[test]
fn fresh_removes_nothing_when_the_cameras_or_ray_counts_are_wrong() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let e = prepared(tmp.path(), "fresh");
    let run_dir = e.out_dir();
    // a finished stage's work, standing in for hours of training
    for stage in ["warmup", "joint", "eval", "nerf"] {
        std::fs::create_dir_all(run_dir.join(stage)).unwrap();
        std::fs::write(run_dir.join(stage).join("work"), b"keep").unwrap();
    }
    let survives = |what: &str| {
        for stage in ["warmup", "joint", "eval", "nerf"] {
            assert!(
                run_dir.join(stage).join("work").is_file(),
                "{what}: {stage} removed"
            );
        }
    };
    // 300 rays from the 16×16 precrop window; 5000 from a 32×32 image
    for (setting, stages, needle) in [
        ("warmup.rays=300", &Stage::ALL[..], "warmup.rays"),
        ("joint.rays=5000", &Stage::ALL[..], "joint.rays"),
        ("nerf.rays=100000", &[Stage::Nerf][..], "nerf.rays"),
    ] {
        let mut bad = e.clone();
        bad.apply_override(setting).unwrap();
        let err = format!("{:#}", Run::prepare(bad, Start::Fresh, stages).unwrap_err());
        assert!(
            err.contains(needle) && err.contains("distinct pixels"),
            "{setting}: {err}"
        );
        survives(setting);
    }
    let transforms = e.scene.scene_dir().join("view_1/transforms_train.json");
    let before = std::fs::read(&transforms).unwrap();
    for (what, edit) in [
        ("w", serde_json::json!({"w": 40})),
        (
            "transform_matrix",
            serde_json::json!({"transform_matrix": vec![[0.0; 4]; 4]}),
        ),
        // a camera 10^30 m away, and a rotation whose columns are nearly parallel (issue 72)
        (
            "camera position",
            serde_json::json!({"transform_matrix": [
                [1.0, 0.0, 0.0, 1e30], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0],
                [0.0, 0.0, 0.0, 1.0]]}),
        ),
        (
            "right angles",
            serde_json::json!({"transform_matrix": [
                [1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.999, 0.0], [0.0, 0.0, 0.0447, 4.0],
                [0.0, 0.0, 0.0, 1.0]]}),
        ),
        ("fl_x", serde_json::json!({"fl_x": 1e-30})),
        ("cx", serde_json::json!({"cx": 1e30})),
    ] {
        edit_json(&transforms, |t| {
            for (k, v) in edit.as_object().unwrap() {
                t["frames"][2][k] = v.clone();
            }
        });
        let err = format!(
            "{:#}",
            Run::prepare(e.clone(), Start::Fresh, &Stage::ALL).unwrap_err()
        );
        assert!(
            err.contains("transforms_train.json") && err.contains(what),
            "{what}: {err}"
        );
        survives(what);
        std::fs::write(&transforms, &before).unwrap();
    }
    // with the inputs right, --fresh empties the folder
    drop(Run::prepare(e, Start::Fresh, &Stage::ALL).unwrap());
    assert!(!run_dir.join("warmup/work").exists());
}

/// A folder the tool did not make is not a run folder: it is refused before anything is
/// written, and `--fresh` refuses a run folder that is a symbolic link.
#[test]
fn foreign_and_linked_run_folders_are_refused() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let e = prepared(tmp.path(), "ours");
    let mut user = e.clone();
    let home = tmp.path().join("home");
    std::fs::create_dir_all(&home).unwrap();
    std::fs::write(home.join("metrics.csv"), b"my numbers").unwrap();
    std::fs::write(home.join("thesis.tex"), b"my thesis").unwrap();
    user.out_dir = Some(home.clone());
    let err = preflight_error(user);
    assert!(
        err.contains("not a run folder") && err.contains("thesis.tex"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(home.join("metrics.csv")).unwrap(),
        b"my numbers"
    );
    #[cfg(unix)]
    {
        let link = tmp.path().join("link");
        std::os::unix::fs::symlink(e.out_dir(), &link).unwrap();
        std::fs::create_dir_all(e.out_dir().join("warmup")).unwrap();
        std::fs::write(e.out_dir().join("warmup/work"), b"keep").unwrap();
        let mut linked = e.clone();
        linked.out_dir = Some(link);
        let err = format!(
            "{:#}",
            Run::prepare(linked, Start::Fresh, &Stage::ALL).unwrap_err()
        );
        assert!(err.contains("symbolic link"), "{err}");
        assert!(e.out_dir().join("warmup/work").is_file());
    }
}

/// A run folder whose stage folder or lock is a symbolic link is refused before anything is
/// written, whatever the start (issue 72: `eval` wrote through a linked `eval/`, and truncated the
/// target of a linked `.lock`): the link's target is left as it was.
#[cfg(unix)]
#[test]
fn links_inside_a_run_folder_are_refused() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let outside = tmp.path().join("outside");
    std::fs::create_dir_all(&outside).unwrap();
    std::fs::write(outside.join("precious"), b"keep").unwrap();
    for (name, target) in [
        ("eval", outside.clone()),
        (".lock", outside.join("precious")),
    ] {
        let e = prepared(
            tmp.path(),
            &format!("linked-{}", name.trim_start_matches('.')),
        );
        let link = e.out_dir().join(name);
        let _ = std::fs::remove_file(&link);
        let _ = std::fs::remove_dir_all(&link);
        std::os::unix::fs::symlink(&target, &link).unwrap();
        for start in [Start::Resume, Start::Fresh] {
            let err = format!(
                "{:#}",
                Run::prepare(e.clone(), start, &[Stage::Eval]).unwrap_err()
            );
            assert!(
                err.contains("symbolic link") && err.contains(name),
                "{name}: {err}"
            );
        }
        assert_eq!(std::fs::read(outside.join("precious")).unwrap(), b"keep");
        assert_eq!(std::fs::read_dir(&outside).unwrap().count(), 1);
    }
}

/// A generated scene whose recorded generator settings differ from the experiment's is not
/// reused silently.
#[test]
fn a_generated_scene_with_other_settings_is_refused() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let mut e = prepared(tmp.path(), "regen");
    e.apply_override("scene.generate.seed=7").unwrap();
    let err = preflight_error(e);
    assert!(
        err.contains("generated with other settings") && err.contains("seed"),
        "{err}"
    );
}

/// A malformed line in the run's metrics log stops the evaluation before it renders anything.
#[test]
fn a_malformed_metrics_line_is_found_before_the_evaluation() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let e = prepared(tmp.path(), "jsonl");
    let log = e.out_dir().join("metrics.jsonl");
    std::fs::write(&log, "{\"stage\": \"warmup\"\nnot json\n").unwrap();
    let err = format!(
        "{:#}",
        Run::prepare(e.clone(), Start::Resume, &[Stage::Eval]).unwrap_err()
    );
    assert!(err.contains("metrics.jsonl"), "{err}");
    assert!(!e.out_dir().join("eval").exists());
}

/// Checkpoint files carry a seal: a damaged model or optimiser file is refused as damaged,
/// never loaded, and a report made before the stage went on is not taken for the current one.
#[test]
fn damaged_checkpoints_and_stale_reports_are_refused() {
    use neurofluid_core::checksums;
    use neurofluid_train::trainer::checkpoint;
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let e = prepared(tmp.path(), "seal");
    let run = Run::prepare(e, Start::Resume, &Stage::ALL).unwrap();
    let mut log = run.open_log().unwrap();
    warmup::run(&run, &mut log).unwrap();
    let ckpt = checkpoint::latest(&run.stage_dir(warmup::STAGE)).unwrap();
    for name in ["physnerf.bpk", "optim_physnerf.bpk"] {
        let path = ckpt.join(name);
        let good = std::fs::read(&path).unwrap();
        let mut bad = good.clone();
        let n = bad.len();
        for b in &mut bad[n / 2..n / 2 + 64] {
            *b ^= 0x5a;
        }
        std::fs::write(&path, &bad).unwrap();
        let err = format!("{:#}", warmup::run(&run, &mut log).unwrap_err());
        assert!(
            err.contains(name) && err.contains("damaged"),
            "{name}: {err}"
        );
        std::fs::write(&path, good).unwrap();
    }
    warmup::run(&run, &mut log).unwrap();
    // a report names the seal of the checkpoint it scored; a newer checkpoint makes it stale
    let joint_dir = run.stage_dir(joint::STAGE);
    let first = checkpoint::write(&joint_dir, |d| {
        std::fs::write(d.join("state.json"), "{\"step\": 1}")?;
        Ok(())
    })
    .unwrap();
    let mut report = neurofluid_outputs::report::EvalReport::new(
        "seal",
        "scene",
        "joint",
        neurofluid_outputs::report::Windows::from_lengths(4, 6),
    );
    report.scored_seal = checksums::seal_digest(&first).unwrap();
    neurofluid_train::stages::eval::check_current(&run, &report).unwrap();
    checkpoint::write(&joint_dir, |d| {
        std::fs::write(d.join("state.json"), "{\"step\": 2}")?;
        Ok(())
    })
    .unwrap();
    let err = neurofluid_train::stages::eval::check_current(&run, &report)
        .unwrap_err()
        .to_string();
    assert!(err.contains("stale"), "{err}");
}
