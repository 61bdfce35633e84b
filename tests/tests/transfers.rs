//! Host–device copies: every read and upload goes through `neurofluid_core::transfer` (so the
//! counts are complete), and a training step of each stage of the tiny experiment reads the
//! device a small, stated number of times (each read stalls a GPU's queue). Runs on the device
//! `$NEUROFLUID_TEST_DEVICE` names (the CPU when unset; wgpu on lavapipe without a GPU).

use std::path::Path;

use neurofluid_outputs::metrics_log::{MetricsLog, read_jsonl};
use neurofluid_tests::{seeded_turn, tiny_experiment, workspace_root};
use neurofluid_train::stage::Stage;
use neurofluid_train::stages::{Run, Start, joint, warmup};

/// The device→host reads of a warm-up step beside one per rendering pass (its coarse weights,
/// which importance sampling draws from on the host; a pass per view on the CPU, one for all
/// views on an accelerator): the step's values (each pass's fine MSE, the loss and the
/// gradients' squares) in one read. Before issue 30: three per view and one per parameter (61
/// with the tiny experiment's 4 views).
const WARMUP_READS_BESIDE_VIEWS: f64 = 1.0;

/// The most device→host reads of a joint step (one view, DLF with a box): DLF's neighbour search
/// reads the positions it moved by gravity, the prediction is read once (the rays, the
/// renderer's neighbour search, the diagnostics and the state check share it), the coarse
/// weights, and the step's values (losses, both groups' gradients' squares and the alignment's
/// sums) in one read: 4, on every backend. ∂L/∂x_{t+1} stays on the device (DLF's surrogate
/// multiplies by it there; it was a fifth read until the thirty-first session). Before issue 30:
/// 75 on the CPU.
const JOINT_READS: f64 = 4.0;

#[test]
fn a_training_step_of_each_stage_reads_the_device_a_stated_number_of_times() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let run = Run::prepare(
        tiny_experiment(tmp.path(), "transfers"),
        Start::Resume,
        &[Stage::Warmup, Stage::Joint],
    )
    .unwrap();
    let views = warmup::WarmupData::load(&run.scene, &run.exp.warmup)
        .unwrap()
        .views
        .len();
    assert!(views > 1, "the tiny experiment warms up on several views");
    let mut log = MetricsLog::open(&run.dir).unwrap();
    warmup::run(&run, &mut log).unwrap();
    joint::run(&run, &mut log).unwrap();
    let rows = read_jsonl(log.jsonl_path()).unwrap();
    let passes = if neurofluid_core::device::is_host(&run.device) {
        views
    } else {
        1
    };
    let most_reads = [
        ("warmup", passes as f64 + WARMUP_READS_BESIDE_VIEWS),
        ("joint", JOINT_READS),
    ];
    for (stage, most) in most_reads {
        let rows: Vec<_> = rows.iter().filter(|r| r.stage == stage).collect();
        assert!(!rows.is_empty(), "no {stage} rows");
        for r in rows {
            let reads = r.get("reads_per_step").expect("reads per step");
            let uploads = r.get("uploads_per_step").expect("uploads per step");
            println!(
                "{stage} step {}: {reads} reads ({} B), {uploads} uploads ({} B) per step",
                r.step,
                r.get("read_bytes_per_step").unwrap(),
                r.get("upload_bytes_per_step").unwrap()
            );
            // the steps' own time, within the row's window (checkpoints and previews outside)
            let wall = r.get("step_s").expect("seconds per step");
            assert!(
                wall > 0.0 && wall <= r.time_s,
                "{stage} step {}: {wall} s",
                r.step
            );
            // a step reads its loss at least, and uploads its rays' target colours
            assert!(reads >= 1.0 && uploads >= 1.0, "{stage}: nothing counted");
            assert!(
                reads <= most,
                "{stage} step {}: {reads} reads per step, more than the {most} stated",
                r.step
            );
        }
    }
}

/// The source of `path` without its unit tests (`#[cfg(test)]` to the end of the file).
fn product_source(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap();
    match text.find("#[cfg(test)]\nmod tests") {
        Some(i) => text[..i].to_string(),
        None => text,
    }
}

fn rust_files(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

#[test]
fn every_copy_between_host_and_device_goes_through_the_counting_door() {
    // Burn's calls that copy a tensor to or from the host; flex's host kernels (`flex_host.rs`,
    // the dense layer's backward) work on CPU tensors, no device in between
    let calls = [
        ".into_data(",
        ".to_data(",
        "into_scalar",
        "to_vec_as",
        "into_vec_as",
        "::from_data(",
        "::from_floats(",
        "::from_ints(",
        "Transaction",
    ];
    let allowed = ["transfer.rs", "flex_host.rs", "dense.rs"];
    let mut files = Vec::new();
    for krate in std::fs::read_dir(workspace_root().join("crates")).unwrap() {
        let krate = krate.unwrap().path();
        for dir in ["src", "benches"] {
            if krate.join(dir).is_dir() {
                rust_files(&krate.join(dir), &mut files);
            }
        }
    }
    assert!(files.len() > 50, "found only {} source files", files.len());
    let mut found = Vec::new();
    for file in &files {
        let name = file.file_name().unwrap().to_string_lossy().to_string();
        let text = product_source(file);
        for (i, line) in text.lines().enumerate() {
            let code = line.split("//").next().unwrap();
            for call in calls {
                if code.contains(call) && !allowed.contains(&name.as_str()) {
                    found.push(format!("{}:{}: {}", file.display(), i + 1, line.trim()));
                }
            }
        }
    }
    assert!(
        found.is_empty(),
        "copies outside neurofluid_core::transfer:\n{}",
        found.join("\n")
    );
}
