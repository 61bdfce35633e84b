//! The `sweep` command on a two-variant sweep of the tiny experiment writes the Table-5-shaped
//! table with a row per variant, and `--table` rebuilds it from the variants' folders
//! (refusing a folder trained under other settings or holding an unfinished joint stage);
//! multi-step BPTT with differentiable conv geometry trains.

use neurofluid_outputs::metrics_log::MetricsLog;
use neurofluid_tests::{params, seeded_turn, tiny_experiment, workspace_root};
use neurofluid_train::commands::sweep;
use neurofluid_train::stage::Stage;
use neurofluid_train::stages::{Run, Start, joint, warmup};

#[test]
fn sweep_writes_a_row_per_variant() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let root = workspace_root();
    let file = tmp.path().join("mini-sweep.toml");
    let text = format!(
        r#"base = "{base}"
out_dir = "{out}"
set = ["scene.dir = '{scene}'", "dlf.weights = '{weights}'", "eval.render = false", "eval.write_ply = false"]

[[variant]]
name = "full"
label = "Full model"

[[variant]]
name = "no_vd"
label = "w/o v_D"
set = ["physnerf.encoding.vd=false"]
"#,
        base = root.join("experiments/tiny-ci.toml").display(),
        out = tmp.path().join("out").display(),
        scene = tmp.path().join("scene").display(),
        weights = root
            .join("assets/dlf_pretrained/pretrained_model_weights.pt")
            .display(),
    );
    std::fs::write(&file, &text).unwrap();
    let args = |table| sweep::Args {
        sweep: file.clone(),
        table,
        ..sweep::Args::default()
    };
    sweep::run(args(false)).unwrap();
    let md_path = tmp.path().join("out/table5.md");
    let md = std::fs::read_to_string(&md_path).unwrap();
    assert!(md.contains("Full model") && md.contains("w/o v_D"), "{md}");
    let csv_path = tmp.path().join("out/table5.csv");
    let csv = std::fs::read_to_string(&csv_path).unwrap();
    assert_eq!(csv.lines().count(), 3, "{csv}");

    // the same table from the folders alone
    std::fs::remove_file(&md_path).unwrap();
    std::fs::remove_file(&csv_path).unwrap();
    sweep::run(args(true)).unwrap();
    assert_eq!(std::fs::read_to_string(&md_path).unwrap(), md);
    assert_eq!(std::fs::read_to_string(&csv_path).unwrap(), csv);

    // a variant whose settings changed since its folder was trained, or whose joint stage would
    // now be longer than the folder's, gets an empty row
    for extra in ["joint.dlf_optim.lr=0.5", "joint.epochs=1000"] {
        let changed = text.replace(
            "set = [\"physnerf.encoding.vd=false\"]",
            &format!("set = [\"physnerf.encoding.vd=false\", \"{extra}\"]"),
        );
        assert_ne!(changed, text);
        std::fs::write(&file, changed).unwrap();
        sweep::run(args(true)).unwrap();
        let rows: Vec<String> = std::fs::read_to_string(&csv_path)
            .unwrap()
            .lines()
            .map(String::from)
            .collect();
        assert_eq!(
            rows[1],
            csv.lines().nth(1).unwrap(),
            "{extra}: the other row stays"
        );
        assert_eq!(rows[2], "w/o v_D,10,missing,,,,,", "{extra}: {rows:?}");
    }
}

#[test]
fn multi_step_bptt_with_differentiable_geometry_trains() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let mut e = tiny_experiment(tmp.path(), "bptt");
    e.apply_overrides(&[
        "joint.bptt_steps=3",
        "dlf.geometry=differentiable",
        "joint.rays=512",
    ])
    .unwrap();
    let run = Run::prepare(e, Start::Resume, &Stage::ALL).unwrap();
    let mut log = MetricsLog::open(&run.dir).unwrap();
    warmup::run(&run, &mut log).unwrap();
    let before = params(&run.load_dlf(&run.exp.dlf.weights).unwrap());
    let grounded = joint::run(&run, &mut log).unwrap();
    let after = params(&grounded.dlf);
    assert!(after.iter().flatten().all(|v| v.is_finite()));
    assert!(before != after, "three-step BPTT left DLF unchanged");
}
