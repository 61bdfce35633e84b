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

use crate::io_error::PathIoError;

/// The lock file inside a locked folder.
pub const LOCK_FILE: &str = ".lock";

/// Why a folder could not be locked; every message names the folder or its lock file.
#[derive(Debug, thiserror::Error)]
pub enum FolderLockError {
    /// Another process holds the folder.
    #[error(
        "{} is in use by another process{holder}; wait for it to finish, stop it, or give this \
         run another `name`",
        dir.display()
    )]
    InUse {
        /// The folder.
        dir: PathBuf,
        /// ` (<who holds the lock>)`, as its holder recorded it, or nothing.
        holder: String,
    },
    /// The lock file is a symbolic link: locking would write through it to wherever it points.
    #[error(
        "{} is a symbolic link: the lock is written only as a file of the folder itself (remove \
         the link)",
        path.display()
    )]
    Linked {
        /// The lock file.
        path: PathBuf,
    },
    /// The folder or its lock file could not be created, opened, locked or written.
    #[error(transparent)]
    Io(#[from] PathIoError),
}

/// A held lock on a folder; released when dropped.
#[derive(Debug)]
pub struct FolderLock {
    file: File,
    path: PathBuf,
}

impl FolderLock {
    /// Locks `dir` (created if missing) for this process, or fails naming the process that
    /// holds it.
    pub fn acquire(dir: &Path) -> Result<Self, FolderLockError> {
        Self::take(dir, false)
    }

    /// Locks `dir` (created if missing) for this process, waiting while another process holds
    /// it (e.g. one generating the scene this one needs).
    pub fn wait(dir: &Path) -> Result<Self, FolderLockError> {
        Self::take(dir, true)
    }

    fn take(dir: &Path, wait: bool) -> Result<Self, FolderLockError> {
        std::fs::create_dir_all(dir).map_err(PathIoError::on("creating", dir))?;
        let path = dir.join(LOCK_FILE);
        if std::fs::symlink_metadata(&path).is_ok_and(|m| m.file_type().is_symlink()) {
            return Err(FolderLockError::Linked { path });
        }
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(PathIoError::on("opening the lock file", &path))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) if wait => {
                tracing::info!(
                    "waiting for {}, in use by another process{}",
                    dir.display(),
                    holder(&mut file)
                );
                file.lock().map_err(PathIoError::on("locking", &path))?;
            }
            Err(TryLockError::WouldBlock) => {
                return Err(FolderLockError::InUse {
                    dir: dir.to_path_buf(),
                    holder: holder(&mut file),
                });
            }
            Err(TryLockError::Error(e)) => return Err(PathIoError::on("locking", &path)(e).into()),
        }
        let command: Vec<String> = std::env::args().collect();
        let since = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs());
        let record = format!(
            "pid {}, since {}, running `{}`\n",
            std::process::id(),
            utc_time(since),
            command.join(" ")
        );
        file.set_len(0)
            .and_then(|()| file.rewind())
            .and_then(|()| file.write_all(record.as_bytes()))
            .and_then(|()| file.flush())
            .map_err(PathIoError::on("writing", &path))?;
        Ok(Self { file, path })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// `seconds` since the Unix epoch as a UTC date and time, `2026-12-05 09:44:33 UTC` (the
/// proleptic Gregorian calendar: days to civil dates as in Howard Hinnant's `civil_from_days`).
fn utc_time(seconds: u64) -> String {
    let (days, rest) = ((seconds / 86_400) as i64, seconds % 86_400);
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02} {:02}:{:02}:{:02} UTC",
        rest / 3600,
        rest / 60 % 60,
        rest % 60
    )
}

/// The most of a lock file's record an error shows (the file could be anything).
const HOLDER_BYTES: u64 = 1024;

/// ` (<who holds the lock>)`, as its holder recorded it, or nothing.
fn holder(file: &mut File) -> String {
    let mut holder = String::new();
    let _ = file.take(HOLDER_BYTES).read_to_string(&mut holder);
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

    /// Dates as Python's `datetime.utcfromtimestamp` gives them (the epoch, a leap day, and the
    /// day this was written).
    #[test]
    fn lock_times_are_utc_dates() {
        assert_eq!(utc_time(0), "1970-01-01 00:00:00 UTC");
        assert_eq!(utc_time(951_782_400), "2000-02-29 00:00:00 UTC");
        assert_eq!(utc_time(1_796_463_873), "2026-12-05 09:44:33 UTC");
    }

    /// A lock file of any size shows at most its first kilobyte in the refusal.
    #[test]
    fn a_huge_record_is_cut() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("lock");
        std::fs::write(&path, "x".repeat(1 << 20)).unwrap();
        let mut file = File::open(&path).unwrap();
        assert!(holder(&mut file).len() <= HOLDER_BYTES as usize + 3);
    }

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

    /// A lock file that is a symbolic link is refused, and its target left as it was (issue 72:
    /// it was truncated).
    #[cfg(unix)]
    #[test]
    fn a_linked_lock_file_is_refused_and_its_target_kept() {
        let tmp = tempfile::tempdir().unwrap();
        let target = tmp.path().join("precious");
        std::fs::write(&target, b"keep").unwrap();
        let dir = tmp.path().join("run");
        std::fs::create_dir_all(&dir).unwrap();
        std::os::unix::fs::symlink(&target, dir.join(LOCK_FILE)).unwrap();
        let err = FolderLock::acquire(&dir).unwrap_err().to_string();
        assert!(
            err.contains("symbolic link") && err.contains(LOCK_FILE),
            "{err}"
        );
        assert_eq!(std::fs::read(&target).unwrap(), b"keep");
    }
}
