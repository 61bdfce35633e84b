//! The CLI re-executes itself once with glibc's allocator tunables (`neurofluid_core::malloc`),
//! keeping its arguments, unless `NEUROFLUID_MALLOC=default`.

use std::process::Command;

use neurofluid_core::malloc::{MALLOC_VAR, TUNABLES};

/// Runs `neurofluid-train -v info <missing folder>` (fails fast after logging starts) and returns
/// its stderr.
fn stderr_of(opt_out: bool) -> String {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_neurofluid-train"));
    cmd.args(["-v", "info", "/nonexistent/neurofluid-scene"])
        .env_remove("GLIBC_TUNABLES")
        .env_remove("RUST_LOG");
    if opt_out {
        cmd.env(MALLOC_VAR, "default");
    } else {
        cmd.env_remove(MALLOC_VAR);
    }
    let out = cmd.output().expect("the CLI runs");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn the_cli_runs_under_the_tunables_unless_told_not_to() {
    if !cfg!(all(target_os = "linux", target_env = "gnu")) {
        return;
    }
    let tuned = stderr_of(false);
    assert!(
        tuned.contains(&format!("GLIBC_TUNABLES={TUNABLES}")),
        "re-executed with the tunables: {tuned}"
    );
    // the arguments survived the re-exec: the error names the missing folder
    assert!(tuned.contains("/nonexistent/neurofluid-scene"), "{tuned}");
    let default = stderr_of(true);
    assert!(
        default.contains("GLIBC_TUNABLES=(glibc defaults)"),
        "opted out: {default}"
    );
}
