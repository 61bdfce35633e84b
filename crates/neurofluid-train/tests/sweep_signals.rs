//! The binary on SIGTERM: `sweep FILE --variant I` stops after the step it is in, with a
//! checkpoint, exit status 75 and its state `stopped`; run again, it resumes and ends bit for bit
//! where its uninterrupted twin ends; meanwhile `--table` and `--status` mark it stopped. And
//! `--slurm --dry-run` writes the array script alone.

use crate::common;

use std::time::Duration;

use common::{EXE, checkpoint_step, metrics, report, run, sweep_file, wait_for};
use neurofluid_train::sweep::state::{self, Phase};

#[test]
fn sigterm_stops_a_run_with_a_checkpoint_and_status_75_and_it_resumes_exactly() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let file = sweep_file(dir, 60, "");
    let file = file.to_str().unwrap();
    let out = dir.join("out");

    // the twin first: it generates the scene, so the signal below lands in the warm-up
    assert!(
        run(dir, EXE, &["sweep", file, "--variant", "1"])
            .status
            .success()
    );

    let mut child = std::process::Command::new(EXE)
        .args(["sweep", file, "--variant", "interrupted"])
        .current_dir(dir)
        .spawn()
        .unwrap();
    let run_dir = out.join("interrupted");
    let at = wait_for(
        "the warm-up has a checkpoint",
        Duration::from_secs(300),
        || {
            let step = checkpoint_step(&run_dir, "warmup");
            (step >= 2).then_some(step)
        },
    );
    assert!(at < 50, "the warm-up is nearly over ({at}): lengthen it");
    let pid = child.id().to_string();
    assert!(
        run(dir, "sh", &["-c", &format!("kill -TERM {pid}")])
            .status
            .success()
    );
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(75), "{status}");
    let stopped = state::read(&out, "interrupted").unwrap().unwrap();
    assert_eq!(stopped.state, Phase::Stopped);
    assert!(
        stopped
            .reason
            .as_deref()
            .unwrap()
            .contains("stopped on request"),
        "{stopped:?}"
    );
    let step = checkpoint_step(&run_dir, "warmup");
    assert!(step > at && step < 60, "checkpoint at {step}");
    assert!(!run_dir.join("eval").exists());

    // the table marks the stopped run and holds its twin's row; the status lists both
    assert!(run(dir, EXE, &["sweep", file, "--table"]).status.success());
    let csv = std::fs::read_to_string(out.join("table5.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(rows[1], "interrupted,10,stopped,,,,,", "{csv}");
    assert!(rows[2].starts_with("straight,10,done,"), "{csv}");
    let status = run(dir, EXE, &["sweep", file, "--status"]);
    let status = String::from_utf8_lossy(&status.stdout);
    assert!(
        status.contains("| 0 | interrupted | stopped |")
            && status.contains("2 runs: 1 stopped, 1 done"),
        "{status}"
    );

    let resumed = run(dir, EXE, &["sweep", file, "--variant", "interrupted"]);
    assert!(resumed.status.success());
    let log = String::from_utf8_lossy(&resumed.stderr);
    assert!(
        log.contains(&format!("step={step}")) && log.contains("resuming warmup"),
        "{log}"
    );
    assert_eq!(
        state::read(&out, "interrupted").unwrap().unwrap().state,
        Phase::Done
    );
    assert_eq!(report(&run_dir), report(&out.join("straight")));
    assert_eq!(metrics(&run_dir), metrics(&out.join("straight")));
}

#[test]
fn a_dry_run_writes_the_array_script_and_submits_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let file = sweep_file(dir, 4, "[slurm]\npartition = \"gpu\"\n");
    let file = file.to_str().unwrap();
    let out = dir.join("out");
    let dry = run(
        dir,
        EXE,
        &[
            "sweep",
            file,
            "--slurm",
            "--dry-run",
            "--max-running",
            "1",
            "--time",
            "10",
        ],
    );
    assert!(dry.status.success());
    let script = std::fs::read_to_string(out.join("sweep.sbatch")).unwrap();
    for line in [
        "#SBATCH --array=0-1%1",
        "#SBATCH --partition=gpu",
        "#SBATCH --time=10",
        "runs=('interrupted' 'straight')",
    ] {
        assert!(script.lines().any(|l| l == line), "{line}:\n{script}");
    }
    assert!(script.contains(&format!("--output={}/logs/task-%a.out", out.display())));
    assert!(
        out.join("logs").is_dir(),
        "Slurm does not create the log folder"
    );
    assert!(!out.join("state").exists() && !out.join("slurm-job.json").exists());
    // scheduling options without --slurm are refused
    let stray = run(dir, EXE, &["sweep", file, "--table", "--time", "10"]);
    assert_eq!(stray.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&stray.stderr).contains("go with --slurm"));
}
