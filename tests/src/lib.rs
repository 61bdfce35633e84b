//! End-to-end tests across the NeuroFluid-rs crates live in `tests/tests/`; this library holds
//! the helpers they share.

use std::path::{Path, PathBuf};

/// The workspace root (for experiment files, weights and test data).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ sits in the workspace root")
        .to_path_buf()
}
