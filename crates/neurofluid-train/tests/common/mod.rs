//! What the tests of the `neurofluid-train` binary on sweeps share.

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

/// The binary under test.
pub const EXE: &str = env!("CARGO_BIN_EXE_neurofluid-train");

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()
        .unwrap()
}

/// Writes `<dir>/pair.toml`: two runs of the tiny experiment with `warmup_iters` warm-up steps,
/// `interrupted` and its twin `straight`, into `<dir>/out` (scene in `<dir>/scene`), then `tail`.
pub fn sweep_file(dir: &Path, warmup_iters: u64, tail: &str) -> PathBuf {
    let root = workspace_root();
    let path = dir.join("pair.toml");
    std::fs::write(
        &path,
        format!(
            r#"base = "{base}"
out_dir = "{out}"
set = ["scene.dir = '{scene}'", "dlf.weights = '{weights}'", "eval.write_ply = false",
       "warmup.iters = {warmup_iters}"]

[[variant]]
name = "interrupted"

[[variant]]
name = "straight"

{tail}"#,
            base = root.join("experiments/tiny-ci.toml").display(),
            out = dir.join("out").display(),
            scene = dir.join("scene").display(),
            weights = root
                .join("assets/dlf_pretrained/pretrained_model_weights.pt")
                .display(),
        ),
    )
    .unwrap();
    path
}

/// Runs `program` in `dir` and returns its output (echoed to stderr).
pub fn run(dir: &Path, program: &str, args: &[&str]) -> Output {
    run_with(dir, program, args, &[])
}

/// [`run`] with the environment variables `env` set.
pub fn run_with(dir: &Path, program: &str, args: &[&str], env: &[(&str, String)]) -> Output {
    let out = Command::new(program)
        .args(args)
        .current_dir(dir)
        .envs(env.iter().map(|(k, v)| (k, v)))
        .output()
        .unwrap_or_else(|e| panic!("running {program}: {e}"));
    eprintln!(
        "$ {program} {}\n{}{}",
        args.join(" "),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// Polls `probe` every 100 ms until it gives a value, for at most `limit`.
pub fn wait_for<T>(what: &str, limit: Duration, mut probe: impl FnMut() -> Option<T>) -> T {
    let start = Instant::now();
    loop {
        if let Some(v) = probe() {
            eprintln!("[{:>5.0} s] {what}", start.elapsed().as_secs_f64());
            return v;
        }
        assert!(start.elapsed() < limit, "timed out waiting for: {what}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The step of the latest checkpoint of `stage` in the run folder `run` (0 without one).
pub fn checkpoint_step(run: &Path, stage: &str) -> u64 {
    ["checkpoint", "checkpoint.old"]
        .iter()
        .filter_map(|c| std::fs::read_to_string(run.join(stage).join(c).join("state.json")).ok())
        .filter_map(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
        .filter_map(|v| v["step"].as_u64())
        .max()
        .unwrap_or(0)
}

/// Each metrics row's stage, step, loss and PSNR (the timings differ between runs).
pub fn metrics(run: &Path) -> Vec<(String, u64, String, String)> {
    std::fs::read_to_string(run.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            (
                v["stage"].as_str().unwrap().to_string(),
                v["step"].as_u64().unwrap(),
                v["loss"].to_string(),
                v["psnr"].to_string(),
            )
        })
        .collect()
}

/// The evaluation's numbers (without the experiment's name, the checkpoint's description and
/// its seal).
pub fn report(run: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(run.join("eval/report.json")).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let o = v.as_object_mut().unwrap();
    o.remove("experiment");
    o.remove("checkpoint");
    // the seal names the checkpoint's bytes, and Burn writes a random id per parameter into
    // each weights file: equal weights, another seal in every process
    o.remove("scored_seal");
    v
}
