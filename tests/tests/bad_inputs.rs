//! Regression tests for inputs that used to slip through: each one now gets a clear error that
//! names the file or key, before any training time is spent, or a guarded stop; none panics and
//! none trains on something wrong.

use std::path::{Path, PathBuf};

use neurofluid_core::scene::{BoxParticles, Particles, Role, write_png_rgba};
use neurofluid_tests::{seeded_turn, tiny_experiment};
use neurofluid_train::config::Experiment;
use neurofluid_train::stages::preflight::Stage;
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
