//! `sweep --slurm` against a real Slurm, not a mock: a two-run sweep of the tiny experiment as
//! a job array on the single-node cluster of `scripts/slurm-local.sh`. One task is asked to stop
//! twice while it trains (SIGTERM to the batch shell alone, as `--signal=B:TERM@…` does before a
//! time limit; then to every process of the task, as preemption does); each time it checkpoints,
//! requeues itself and resumes, and it ends bit for bit where its uninterrupted twin ends. A
//! second process on the same run is refused meanwhile. The table is collected from the files.
//!
//! Needs the cluster, so it runs only with `NEUROFLUID_SLURM=1` (CI does not set it):
//!
//! ```sh
//! scripts/slurm-local.sh start && eval "$(scripts/slurm-local.sh env)"
//! NEUROFLUID_SLURM=1 cargo test -p neurofluid-train --test train_tests slurm_sweep:: -- --nocapture
//! scripts/slurm-local.sh stop
//! ```

use std::time::{Duration, Instant};

use neurofluid_train::sweep::state::{self, Phase, RunState};

use crate::common;

use common::{EXE, checkpoint_step, metrics, report, run, sweep_file, wait_for};

#[test]
fn a_stopped_task_requeues_itself_and_resumes_to_the_uninterrupted_result() {
    if std::env::var("NEUROFLUID_SLURM").as_deref() != Ok("1") {
        eprintln!("skipped: set NEUROFLUID_SLURM=1 with a cluster up (scripts/slurm-local.sh)");
        return;
    }
    let started = Instant::now();
    let tmp = tempfile::Builder::new()
        .prefix("nf-slurm-sweep")
        .tempdir()
        .unwrap();
    let dir = tmp.path();
    let out = dir.join("out");
    let sweep_file = sweep_file(dir, 160, "[slurm]\ncpus_per_task = 1\ntime = \"30\"\n");
    let file = sweep_file.to_str().unwrap();

    let submitted = run(dir, EXE, &["sweep", file, "--slurm"]);
    assert!(submitted.status.success());
    let job: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("slurm-job.json")).unwrap())
            .unwrap();
    let job = job["job"].as_str().unwrap().to_string();
    let task = format!("{job}_0");
    let pending = state::read(&out, "straight").unwrap().unwrap();
    assert!(
        pending.job.as_deref() == Some(&format!("{job}_1")[..]),
        "{pending:?}"
    );

    let run_dir = out.join("interrupted");
    let state_of = |run: &str| -> RunState { state::read(&out, run).unwrap().unwrap() };
    let limit = Duration::from_secs(600);
    let first = wait_for("task 0 trains its warm-up", limit, || {
        let step = checkpoint_step(&run_dir, "warmup");
        (state_of("interrupted").state == Phase::Running && step >= 10).then_some(step)
    });
    assert!(
        first < 140,
        "the warm-up is nearly over ({first}): lengthen it"
    );

    // a second process on the same run is refused and leaves the task's state alone
    let second = run(dir, EXE, &["sweep", file, "--variant", "interrupted"]);
    assert_eq!(second.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&second.stderr).contains("in use by another process"));
    let running = state_of("interrupted");
    assert_eq!(
        (running.state, running.job.as_deref(), running.attempt),
        (Phase::Running, Some(&task[..]), Some(1))
    );

    // 1: SIGTERM to the batch shell alone (what --signal=B:TERM@… sends before the time limit)
    assert!(
        run(dir, "scancel", &["--batch", "--signal=TERM", &task])
            .status
            .success()
    );
    let stopped_at = wait_for("task 0 stopped with a checkpoint", limit, || {
        let s = state_of("interrupted");
        (s.state == Phase::Stopped).then(|| checkpoint_step(&run_dir, "warmup"))
    });
    wait_for("task 0 requeued, resumed and training again", limit, || {
        let s = state_of("interrupted");
        (s.state == Phase::Running
            && s.attempt == Some(2)
            && checkpoint_step(&run_dir, "warmup") > stopped_at)
            .then_some(())
    });

    // 2: SIGTERM to every process of the task (what preemption sends)
    assert!(
        run(dir, "scancel", &["--full", "--signal=TERM", &task])
            .status
            .success()
    );
    wait_for("task 0 requeued a second time", limit, || {
        (state_of("interrupted").attempt == Some(3)).then_some(())
    });
    wait_for("both runs done", limit, || {
        ["interrupted", "straight"]
            .iter()
            .all(|r| state_of(r).state == Phase::Done)
            .then_some(())
    });

    let log = std::fs::read_to_string(out.join("logs/task-0.out")).unwrap();
    let lines: Vec<&str> = log
        .lines()
        .filter(|l| l.starts_with("==") || l.contains("stop") || l.contains("resuming"))
        .collect();
    eprintln!("task 0's log, in short:\n{}", lines.join("\n"));
    assert_eq!(log.matches("requeueing").count(), 2, "{log}");
    assert_eq!(log.matches("stopped on request").count(), 2, "{log}");
    assert!(log.contains("resuming warmup from"), "{log}");
    let shown = run(dir, "scontrol", &["show", "job", &task]);
    assert!(String::from_utf8_lossy(&shown.stdout).contains("Restarts=2"));

    // bit for bit the uninterrupted run's result
    assert_eq!(report(&run_dir), report(&out.join("straight")));
    assert_eq!(metrics(&run_dir), metrics(&out.join("straight")));

    // collected from the files alone
    let table = run(dir, EXE, &["sweep", file, "--table"]);
    assert!(table.status.success());
    let csv = std::fs::read_to_string(out.join("table5.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(rows.len(), 3, "{csv}");
    assert!(rows[1].starts_with("interrupted,10,done,"), "{csv}");
    assert_eq!(
        rows[1].trim_start_matches("interrupted"),
        rows[2].trim_start_matches("straight")
    );
    let status = run(dir, EXE, &["sweep", file, "--status"]);
    assert!(String::from_utf8_lossy(&status.stdout).contains("2 runs: 2 done"));
    eprintln!(
        "real Slurm sweep test: {:.0} s",
        started.elapsed().as_secs_f64()
    );
}
