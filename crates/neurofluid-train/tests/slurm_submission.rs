//! What `sweep --slurm` asks of Slurm, against stand-ins for `sbatch`, `scontrol` and `squeue`
//! that record their arguments and answer as Slurm does (the real cluster's behaviour is
//! `slurm_sweep`'s, which needs one): one submission per run while Slurm still holds its task,
//! the sweep frozen for the tasks, the table gathered by a dependent job, a warning for a time
//! limit that leaves no time to train; and the exit status and folder checks of `--status` and
//! `--table`.

use std::path::{Path, PathBuf};
use std::process::Output;

use crate::common::{EXE, run_with, sweep_file};
use neurofluid_train::sweep::state::{self, Phase, RunState};

/// A folder of stand-in Slurm commands: `sbatch` logs its arguments to `sbatch.log` and answers
/// job 100 for a held array, 101 for anything else; `scontrol` logs; `squeue` prints
/// `squeue.out` when it exists (the state of the job asked about), else nothing.
fn fake_slurm(dir: &Path) -> PathBuf {
    let bin = dir.join("fake-slurm");
    std::fs::create_dir_all(&bin).unwrap();
    let log = |name: &str| bin.join(format!("{name}.log")).display().to_string();
    let scripts = [
        (
            "sbatch",
            format!(
                "#!/bin/sh\nprintf '%s\\n' \"$*\" >> '{}'\ncase \"$*\" in *--hold*) echo 100 ;; \
                 *) echo 101 ;; esac\n",
                log("sbatch")
            ),
        ),
        (
            "scontrol",
            format!(
                "#!/bin/sh\nprintf '%s\\n' \"$*\" >> '{}'\n",
                log("scontrol")
            ),
        ),
        (
            "squeue",
            format!(
                "#!/bin/sh\nprintf '%s\\n' \"$*\" >> '{}'\n[ -f '{out}' ] && cat '{out}'\nexit 0\n",
                log("squeue"),
                out = bin.join("squeue.out").display()
            ),
        ),
    ];
    for (name, text) in scripts {
        let path = bin.join(name);
        std::fs::write(&path, text).unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    bin
}

/// Runs the trainer in `dir` with the stand-ins first on the PATH.
fn with_fake(bin: &Path, dir: &Path, args: &[&str]) -> Output {
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    run_with(dir, EXE, args, &[("PATH", path)])
}

fn calls(bin: &Path, name: &str) -> Vec<String> {
    std::fs::read_to_string(bin.join(format!("{name}.log")))
        .unwrap_or_default()
        .lines()
        .map(String::from)
        .collect()
}

#[test]
fn a_run_is_submitted_once_frozen_with_its_table_job() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let bin = fake_slurm(dir);
    let file = sweep_file(dir, 4, "");
    let out = dir.join("out");
    let f = file.to_str().unwrap();

    // a minute's limit, of which the default lead of 120 s takes it all: a warning
    let first = with_fake(&bin, dir, &["sweep", f, "--slurm", "--time", "1"]);
    assert!(first.status.success());
    let stderr = String::from_utf8_lossy(&first.stderr);
    assert!(
        stderr.contains("less than twice the signal's lead"),
        "{stderr}"
    );
    let sbatch = calls(&bin, "sbatch");
    assert_eq!(sbatch.len(), 2, "{sbatch:?}");
    assert!(sbatch[0].contains("--hold"), "{sbatch:?}");
    let frozen = out.join("submitted/pair.toml");
    assert!(
        sbatch[1].contains("--dependency=afterany:100")
            && sbatch[1].contains("--table")
            && sbatch[1].contains(&frozen.display().to_string()),
        "{sbatch:?}"
    );
    let job: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("slurm-job.json")).unwrap())
            .unwrap();
    assert_eq!(job["table_job"], "101");
    // the tasks read the frozen sweep: an edit of the file afterwards changes nothing queued
    let script = std::fs::read_to_string(out.join("sweep.sbatch")).unwrap();
    assert!(
        script.contains(&format!("sweep '{}'", frozen.display())),
        "{script}"
    );
    let before = std::fs::read_to_string(&frozen).unwrap();
    let edited = std::fs::read_to_string(&file)
        .unwrap()
        .replace("warmup.iters = 4", "warmup.iters = 5");
    std::fs::write(&file, edited).unwrap();
    assert_eq!(std::fs::read_to_string(&frozen).unwrap(), before);
    assert!(before.contains("warmup.iters = 4"), "{before}");
    for run in ["interrupted", "straight"] {
        assert_eq!(
            state::read(&out, run).unwrap().unwrap().state,
            Phase::Pending
        );
    }

    // while Slurm holds the tasks, submitting again submits nothing and says why
    std::fs::write(bin.join("squeue.out"), "RUNNING\n").unwrap();
    let again = with_fake(&bin, dir, &["sweep", f, "--slurm"]);
    assert!(again.status.success());
    let stdout = String::from_utf8_lossy(&again.stdout);
    assert_eq!(stdout.matches("not submitted again").count(), 2, "{stdout}");
    assert_eq!(calls(&bin, "sbatch").len(), 2);
    assert!(calls(&bin, "squeue").iter().any(|c| c.contains("100_0")));

    // once Slurm no longer lists them (cancelled without a word), they are submitted again
    std::fs::remove_file(bin.join("squeue.out")).unwrap();
    let third = with_fake(&bin, dir, &["sweep", f, "--slurm"]);
    assert!(third.status.success());
    assert!(String::from_utf8_lossy(&third.stderr).contains("no longer lists"));
    assert_eq!(calls(&bin, "sbatch").len(), 4);
}

#[test]
fn status_and_table_say_when_runs_failed_and_create_no_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let bin = fake_slurm(dir);
    let file = sweep_file(dir, 4, "");
    let f = file.to_str().unwrap();
    let out = dir.join("out");

    // nothing ran: no folder to read, and none is made
    for mode in ["--status", "--table"] {
        let o = with_fake(&bin, dir, &["sweep", f, mode]);
        assert_eq!(o.status.code(), Some(1), "{mode}");
        assert!(String::from_utf8_lossy(&o.stderr).contains("no sweep folder"));
        assert!(!out.exists(), "{mode} created {}", out.display());
    }

    let reason = "joint: the DLF diverged\ncaused by: step 7: loss is NaN";
    state::write(
        &out,
        &RunState::new("interrupted", Phase::Failed).because(reason),
    )
    .unwrap();
    let status = with_fake(&bin, dir, &["sweep", f, "--status"]);
    assert_eq!(status.status.code(), Some(1));
    let stdout = String::from_utf8_lossy(&status.stdout);
    assert!(stdout.contains("step 7: loss is NaN"), "{stdout}");
    assert!(
        String::from_utf8_lossy(&status.stderr).contains("1 of the 2 runs"),
        "the exit names the failed runs"
    );
    let table = with_fake(&bin, dir, &["sweep", f, "--table"]);
    assert_eq!(table.status.code(), Some(1));
    assert!(
        out.join("table5.csv").is_file(),
        "the table is written all the same"
    );
}
