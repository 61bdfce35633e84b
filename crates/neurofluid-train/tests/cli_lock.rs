//! The command line protects what it does not own: a second process on a run folder that
//! another process holds is refused, naming the holder, and touches nothing; a run name that
//! is not one folder name is refused before `--fresh` removes anything.

use std::process::Command;

use neurofluid_core::folder_lock::FolderLock;

#[test]
fn a_second_process_on_a_locked_run_folder_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let run_dir = tmp.path().join("held");
    let _held = FolderLock::acquire(&run_dir).unwrap();
    std::fs::write(run_dir.join("metrics.jsonl"), "{}\n").unwrap();
    let experiment =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../experiments/tiny-ci.toml");
    let out = Command::new(env!("CARGO_BIN_EXE_neurofluid-train"))
        .arg("run")
        .arg(&experiment)
        .arg("--fresh")
        .arg("--set")
        .arg(format!("out_dir=\"{}\"", run_dir.display()))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(stderr.contains("in use by another process"), "{stderr}");
    assert!(
        stderr.contains(&format!("pid {}", std::process::id())),
        "{stderr}"
    );
    // --fresh did not empty the folder it could not lock
    assert!(run_dir.join("metrics.jsonl").is_file());
}

#[test]
fn a_run_name_outside_runs_is_refused_before_anything_is_removed() {
    let tmp = tempfile::tempdir().unwrap();
    // `runs/..` would be the working directory: its stage-named folders must survive
    std::fs::create_dir_all(tmp.path().join("eval")).unwrap();
    std::fs::create_dir_all(tmp.path().join("warmup")).unwrap();
    let experiment =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../experiments/tiny-ci.toml");
    let out = Command::new(env!("CARGO_BIN_EXE_neurofluid-train"))
        .current_dir(tmp.path())
        .arg("run")
        .arg(&experiment)
        .arg("--fresh")
        .args(["--set", "name=.."])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(stderr.contains("name"), "{stderr}");
    assert!(tmp.path().join("eval").is_dir() && tmp.path().join("warmup").is_dir());
}
