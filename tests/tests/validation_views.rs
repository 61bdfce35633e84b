//! Validation views (`validation` in `scene.json`): views no stage trains on, kept aside to
//! choose settings with. `eval.novel_views = "validation"` scores them in place of the test
//! views (here a copy of the test view under another name, which must score as the test view
//! does), changes nothing else, and is refused by name on a scene without them.

use std::path::Path;

use neurofluid_core::scene::{MANIFEST_FILE, Role};
use neurofluid_tests::{
    add_validation_copy, assert_scored_as_the_test_view, contents, seeded_turn, tiny_experiment,
};
use neurofluid_train::config::Experiment;
use neurofluid_train::stage::Stage;
use neurofluid_train::stages::{Run, Start, run_all};

const ASK: &str = "eval.novel_views=\"validation\"";

fn experiment(tmp: &Path, overrides: &[&str]) -> Experiment {
    let mut e = tiny_experiment(tmp, "val");
    e.apply_overrides(&["warmup.ckpt_every=0", "joint.ckpt_every=0"])
        .unwrap();
    e.apply_overrides(overrides).unwrap();
    e
}

#[test]
fn validation_views_are_scored_in_place_of_the_test_views() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let run = Run::prepare(experiment(tmp.path(), &[]), Start::Resume, &Stage::ALL).unwrap();
    let mut log = run.open_log().unwrap();
    let on_test = run_all(&run, &mut log).unwrap();
    let test_view = run.scene.views(Role::Test)[0].clone();
    let scene_dir = run.scene.root().to_path_buf();
    drop((run, log));
    assert!(!on_test.validation_views);

    // the generated scene has none: asking for them is refused, naming the file and the key
    let err = format!(
        "{:#}",
        Run::prepare(experiment(tmp.path(), &[ASK]), Start::Resume, &Stage::ALL).unwrap_err()
    );
    assert!(
        err.contains("eval.novel_views") && err.contains(MANIFEST_FILE),
        "{err}"
    );

    // view_9: the test view copied under another name, declared as the validation view
    add_validation_copy(&scene_dir, "view_9");

    // `eval.*` shapes no training stage: the stages resume as they are, only the evaluation runs
    let run = Run::prepare(experiment(tmp.path(), &[ASK]), Start::Resume, &Stage::ALL).unwrap();
    assert_eq!(run.exp.eval.views(&run.scene), ["view_9"]);
    let mut log = run.open_log().unwrap();
    let on_val = run_all(&run, &mut log).unwrap();
    assert!(on_val.validation_views);
    assert!(
        on_val.nvs_markdown().contains("the validation views"),
        "{}",
        on_val.nvs_markdown()
    );
    assert_eq!(on_val.frames, on_test.frames, "the dynamics are the same");
    assert_scored_as_the_test_view(&on_val.images, &on_test.images, "view_9", &test_view);
    assert!(run.stage_dir(Stage::Eval).join("renders/view_9").is_dir());
}

/// A built-in scene generated without validation views gains them when
/// `scene.generate.validation_views` asks (the generator's, on the ring beside the test view):
/// the scene is generated again, every file it had the same but its manifest, and a finished run
/// is scored on them without retraining (the key shapes no stage).
#[test]
fn a_built_in_scene_gains_validation_views_and_a_finished_run_is_scored_on_them() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let run = Run::prepare(experiment(tmp.path(), &[]), Start::Resume, &Stage::ALL).unwrap();
    let mut log = run.open_log().unwrap();
    let on_test = run_all(&run, &mut log).unwrap();
    let scene_dir = run.scene.root().to_path_buf();
    let joint_dir = run.stage_dir(Stage::Joint);
    drop((run, log));
    let (scene_before, joint_before) = (contents(&scene_dir), contents(&joint_dir));

    let ask = [ASK, "scene.generate.validation_views=true"];
    let run = Run::prepare(experiment(tmp.path(), &ask), Start::Resume, &Stage::ALL).unwrap();
    let val = ["view_6", "view_7", "view_8"];
    assert_eq!(run.scene.views(Role::Validation), val);
    assert_eq!(
        run.scene.frames(Role::Validation),
        run.scene.frames(Role::Test)
    );
    let scene_after = contents(&scene_dir);
    for (f, bytes) in &scene_before {
        if f != Path::new(MANIFEST_FILE) {
            assert!(scene_after.get(f) == Some(bytes), "{f:?} changed");
        }
    }
    let mut log = run.open_log().unwrap();
    let on_val = run_all(&run, &mut log).unwrap();
    assert!(on_val.validation_views);
    assert_eq!(on_val.frames, on_test.frames, "the dynamics are the same");
    for v in val {
        let scored = on_val.images.iter().filter(|s| s.view == v).count();
        let on_the_test_view = on_test.images.len();
        assert_eq!(
            scored, on_the_test_view,
            "{v}: one score per test-view step"
        );
    }
    assert_eq!(
        contents(&joint_dir),
        joint_before,
        "nothing was trained again"
    );
}
