//! An input/output error that says what was being done and to which file or folder, the
//! operating system's error as its source: `creating runs/a: Permission denied` where a chain of
//! errors is printed.

use std::path::{Path, PathBuf};

/// `doing` on `path` failed.
#[derive(Debug, thiserror::Error)]
#[error("{doing} {}", path.display())]
pub struct PathIoError {
    /// What failed (`reading`, `writing`, `creating`, …).
    pub doing: &'static str,
    /// The file or folder.
    pub path: PathBuf,
    /// The operating system's error.
    pub source: std::io::Error,
}

impl PathIoError {
    /// The error of `doing` on `path`, from the operating system's (for `map_err`).
    pub fn on(doing: &'static str, path: &Path) -> impl FnOnce(std::io::Error) -> Self {
        let path = path.to_path_buf();
        move |source| Self {
            doing,
            path,
            source,
        }
    }
}
