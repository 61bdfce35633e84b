//! Limits and counts given to the CLI that make no sense stop it at its start, naming what was
//! given (issue 72): a bad `NEUROFLUID_MAX_FILE_MB`, `--validate-every 0`.

use std::process::Command;

use neurofluid_core::limits::MAX_FILE_MB_ENV;

/// `neurofluid-train info <missing folder>` with the cap set to `value`: (success, stderr).
fn info_with_cap(value: &str) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_neurofluid-train"))
        .args(["info", "/nonexistent/neurofluid-scene"])
        .env(MAX_FILE_MB_ENV, value)
        .output()
        .expect("the CLI runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn a_bad_file_cap_stops_the_cli_with_the_variable_named() {
    for bad in ["abc", "0"] {
        let (ok, err) = info_with_cap(bad);
        assert!(!ok, "{bad}");
        assert!(
            err.contains(MAX_FILE_MB_ENV) && err.contains(&format!("{bad:?}")),
            "{bad}: {err}"
        );
    }
    // a good cap reaches the command, which then fails on the missing folder
    let (ok, err) = info_with_cap("64");
    assert!(
        !ok && err.contains("/nonexistent/neurofluid-scene") && !err.contains(MAX_FILE_MB_ENV),
        "{err}"
    );
}

/// `pretrain-dlf --validate-every 0` is refused by the command line (it meant "never validate,
/// checkpoint only at the end", which `--help` did not say; issue 72).
#[test]
fn validating_every_zero_steps_is_refused() {
    let out = Command::new(env!("CARGO_BIN_EXE_neurofluid-train"))
        .args([
            "pretrain-dlf",
            "--data",
            "/nonexistent/records",
            "--output",
            "/nonexistent/out.bpk",
            "--validate-every",
            "0",
        ])
        .output()
        .expect("the CLI runs");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("--validate-every") && err.contains('0'),
        "{err}"
    );
}
