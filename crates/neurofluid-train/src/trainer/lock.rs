//! One process per folder: a run folder (or `pretrain-dlf`'s checkpoint folder) is locked while a
//! process owns it, so two runs never interleave their checkpoints, metrics and results; a
//! built-in scene's folder is locked while it is generated, and runs that need it wait.
//!
//! The lock is an advisory OS file lock on `<folder>/.lock`, which also records who holds it;
//! the operating system releases it when the process ends, however it ends (a `kill -9` leaves
//! no stale lock behind).

use std::fs::{File, OpenOptions, TryLockError};
use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};

use anyhow::Context;

/// The lock file inside a locked folder.
pub const LOCK_FILE: &str = ".lock";

/// A held lock on a folder; released when dropped.
#[derive(Debug)]
pub struct FolderLock {
    file: File,
    path: PathBuf,
}

impl FolderLock {
    /// Locks `dir` (created if missing) for this process, or fails naming the process that
    /// holds it.
    pub fn acquire(dir: &Path) -> anyhow::Result<Self> {
        Self::take(dir, false)
    }

    /// Locks `dir` (created if missing) for this process, waiting while another process holds
    /// it (e.g. one generating the scene this one needs).
    pub fn wait(dir: &Path) -> anyhow::Result<Self> {
        Self::take(dir, true)
    }

    fn take(dir: &Path, wait: bool) -> anyhow::Result<Self> {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let path = dir.join(LOCK_FILE);
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .with_context(|| format!("opening the lock file {}", path.display()))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) if wait => {
                tracing::info!(
                    "waiting for {}, in use by another process{}",
                    dir.display(),
                    holder(&mut file)
                );
                file.lock()
                    .with_context(|| format!("locking {}", path.display()))?;
            }
            Err(TryLockError::WouldBlock) => {
                anyhow::bail!(
                    "{} is in use by another process{}; wait for it to finish, stop it, or give \
                     this run another `name`",
                    dir.display(),
                    holder(&mut file)
                );
            }
            Err(TryLockError::Error(e)) => {
                return Err(e).with_context(|| format!("locking {}", path.display()));
            }
        }
        let command: Vec<String> = std::env::args().collect();
        let since = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs());
        let record = format!(
            "pid {}, since {since} (Unix time), running `{}`\n",
            std::process::id(),
            command.join(" ")
        );
        file.set_len(0)
            .and_then(|()| file.rewind())
            .and_then(|()| file.write_all(record.as_bytes()))
            .and_then(|()| file.flush())
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(Self { file, path })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// ` (<who holds the lock>)`, as its holder recorded it, or nothing.
fn holder(file: &mut File) -> String {
    let mut holder = String::new();
    let _ = file.read_to_string(&mut holder);
    let holder = holder.trim();
    if holder.is_empty() {
        String::new()
    } else {
        format!(" ({holder})")
    }
}

impl Drop for FolderLock {
    fn drop(&mut self) {
        let _ = self.file.set_len(0);
        let _ = self.file.unlock();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_holder_is_refused_with_the_first_named_until_it_lets_go() {
        let dir = tempfile::tempdir().unwrap();
        let folder = dir.path().join("runs/a");
        let first = FolderLock::acquire(&folder).unwrap();
        assert!(first.path().is_file());
        let err = FolderLock::acquire(&folder).unwrap_err().to_string();
        assert!(err.contains("in use by another process"), "{err}");
        assert!(
            err.contains(&format!("pid {}", std::process::id())),
            "{err}"
        );
        assert!(err.contains(&folder.display().to_string()), "{err}");
        drop(first);
        let second = FolderLock::acquire(&folder).unwrap();
        // one who waits gets the folder once the holder lets go
        let waiter = {
            let folder = folder.clone();
            std::thread::spawn(move || FolderLock::wait(&folder).map(drop))
        };
        std::thread::sleep(std::time::Duration::from_millis(200));
        assert!(!waiter.is_finished(), "the waiter did not wait");
        drop(second);
        waiter.join().unwrap().unwrap();
    }
}
