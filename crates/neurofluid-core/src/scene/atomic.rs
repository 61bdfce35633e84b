//! Atomic scene writes through the crate's one atomic writer, with scene errors.

use std::path::Path;

use super::error::{Result, SceneError};

/// Writes `bytes` to `path` atomically (see [`crate::atomic`]), creating parent folders.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    crate::atomic::write_bytes(path, bytes).map_err(|e| SceneError::io(path, e))
}
