//! A checkpoint's seal: `checksums.json` lists the SHA-256 of every file the checkpoint was
//! written with. It is written inside the checkpoint's temporary folder, so it appears with the
//! checkpoint in one rename; a file that later differs (a damaged disk, a partial copy, an edit)
//! makes the checkpoint refused as damaged, never loaded or called good.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use sha2::{Digest, Sha256};

use crate::io_error::PathIoError;

/// The seal's file name inside a checkpoint folder.
pub const CHECKSUMS_FILE: &str = "checksums.json";

/// Why a checkpoint's files could not be sealed or did not match their seal; every message names
/// the file.
#[derive(Debug, thiserror::Error)]
pub enum ChecksumError {
    /// A file differs from the one the checkpoint was written with, is missing, or was not
    /// written with it.
    #[error(
        "{}: a damaged checkpoint ({what}); it is not loaded: restore the file or start the \
         stage over with --fresh",
        path.display()
    )]
    Damaged {
        /// The file.
        path: PathBuf,
        /// How it differs.
        what: String,
    },
    /// The checkpoint has no seal, and unsealed checkpoints were not trusted.
    #[error(
        "{}: a checkpoint without {CHECKSUMS_FILE} (written before checkpoints were sealed, or its \
         seal was removed): its files cannot be checked, so it is not loaded; pass \
         --trust-unsealed to load it unchecked, or start the stage over with --fresh",
        dir.display()
    )]
    Unsealed {
        /// The checkpoint folder.
        dir: PathBuf,
    },
    /// The seal itself is not a map of file names to digests.
    #[error("{}: a damaged checkpoint (malformed seal)", path.display())]
    MalformedSeal {
        /// The seal.
        path: PathBuf,
        /// What the parser found.
        source: serde_json::Error,
    },
    /// A file or folder could not be read or written.
    #[error(transparent)]
    Io(#[from] PathIoError),
}

/// Whether checkpoints without a seal are loaded (unchecked, with a warning); the programs'
/// `--trust-unsealed` sets it. Off, such a checkpoint is refused with [`ChecksumError::Unsealed`].
static TRUST_UNSEALED: AtomicBool = AtomicBool::new(false);

/// Sets whether checkpoints without a seal are loaded (`--trust-unsealed`).
pub fn set_trust_unsealed(trust: bool) {
    TRUST_UNSEALED.store(trust, Ordering::SeqCst);
}

/// SHA-256 of a file, as 64 hex digits (a regular file within the per-file limit:
/// [`crate::input_file`]).
pub fn file_sha256(path: &Path) -> Result<String, ChecksumError> {
    let mut file = crate::input_file::open(path).map_err(PathIoError::on("reading", path))?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = file
            .read(&mut buf)
            .map_err(PathIoError::on("reading", path))?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
    }
    Ok(hasher
        .finalize()
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect())
}

/// Writes the seal of every file in `dir` (the checkpoint being written).
pub fn seal(dir: &Path) -> Result<(), ChecksumError> {
    let mut sums = BTreeMap::new();
    for entry in std::fs::read_dir(dir).map_err(PathIoError::on("reading", dir))? {
        let entry = entry.map_err(PathIoError::on("reading", dir))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if name != CHECKSUMS_FILE && entry.file_type().is_ok_and(|t| t.is_file()) {
            sums.insert(name, file_sha256(&entry.path())?);
        }
    }
    let path = dir.join(CHECKSUMS_FILE);
    let text = serde_json::to_string_pretty(&sums).expect("a map of strings serialises");
    std::fs::write(&path, text).map_err(PathIoError::on("writing", &path))?;
    Ok(())
}

/// The seal of the checkpoint `dir`, if it has one (checkpoints of earlier releases do not).
fn read_seal(dir: &Path) -> Result<Option<BTreeMap<String, String>>, ChecksumError> {
    let path = dir.join(CHECKSUMS_FILE);
    if !path.is_file() {
        return Ok(None);
    }
    let text = crate::input_file::read_string(&path).map_err(PathIoError::on("reading", &path))?;
    serde_json::from_str(&text)
        .map(Some)
        .map_err(|source| ChecksumError::MalformedSeal { path, source })
}

fn damaged(path: &Path, what: &str) -> ChecksumError {
    ChecksumError::Damaged {
        path: path.to_path_buf(),
        what: what.to_string(),
    }
}

/// Checks the file `path` of a checkpoint against its folder's seal. A checkpoint without a
/// seal is refused unless `--trust-unsealed` was given ([`set_trust_unsealed`]).
pub fn verify_file(path: &Path) -> Result<(), ChecksumError> {
    verify_file_trusting(path, TRUST_UNSEALED.load(Ordering::SeqCst))
}

/// [`verify_file`], with `trust_unsealed` saying whether an unsealed checkpoint is loaded
/// (with a warning) or refused.
fn verify_file_trusting(path: &Path, trust_unsealed: bool) -> Result<(), ChecksumError> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let Some(seal) = read_seal(dir)? else {
        return unsealed(dir, trust_unsealed);
    };
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let expected = seal
        .get(&name)
        .ok_or_else(|| damaged(path, "a file the checkpoint was not written with"))?;
    let found = file_sha256(path)?;
    if &found != expected {
        return Err(damaged(
            path,
            &format!("SHA-256 {found}, written as {expected}"),
        ));
    }
    Ok(())
}

/// The checkpoint `dir` has no seal: refused, or with `trust_unsealed` loaded with a warning.
fn unsealed(dir: &Path, trust_unsealed: bool) -> Result<(), ChecksumError> {
    if !trust_unsealed {
        return Err(ChecksumError::Unsealed {
            dir: dir.to_path_buf(),
        });
    }
    tracing::warn!(
        "{}: the checkpoint has no {CHECKSUMS_FILE}; loading it unchecked (--trust-unsealed)",
        dir.display()
    );
    Ok(())
}

/// Checks every file the seal of `dir` lists (an unsealed `dir` as [`verify_file`] does).
pub fn verify(dir: &Path) -> Result<(), ChecksumError> {
    let Some(seal) = read_seal(dir)? else {
        return unsealed(dir, TRUST_UNSEALED.load(Ordering::SeqCst));
    };
    for name in seal.keys() {
        // a seal names the checkpoint's own files: a path elsewhere is a forged seal
        if crate::paths::one_component(name).is_err() {
            return Err(damaged(
                &dir.join(CHECKSUMS_FILE),
                &format!(
                    "its seal names {}, not a file of the checkpoint",
                    crate::paths::shown(name)
                ),
            ));
        }
        let path = dir.join(name);
        if !path.is_file() {
            return Err(damaged(&path, "missing"));
        }
        verify_file(&path)?;
    }
    Ok(())
}

/// The seal's own digest: it names the exact files of the checkpoint `dir` (`None` for an
/// unsealed checkpoint of an earlier release).
pub fn seal_digest(dir: &Path) -> Result<Option<String>, ChecksumError> {
    let path = dir.join(CHECKSUMS_FILE);
    path.is_file().then(|| file_sha256(&path)).transpose()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_changed_byte_breaks_the_seal() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("a.bpk"), vec![7u8; 5000]).unwrap();
        std::fs::write(dir.path().join("state.json"), "{}").unwrap();
        seal(dir.path()).unwrap();
        verify(dir.path()).unwrap();
        // the digest of a known input (FIPS 180-2's "abc")
        std::fs::write(dir.path().join("abc"), "abc").unwrap();
        assert_eq!(
            file_sha256(&dir.path().join("abc")).unwrap(),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        let e = verify_file(&dir.path().join("abc"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("not written with"), "{e}");
        let mut bytes = std::fs::read(dir.path().join("a.bpk")).unwrap();
        bytes[4000] ^= 1;
        std::fs::write(dir.path().join("a.bpk"), bytes).unwrap();
        let e = verify(dir.path()).unwrap_err().to_string();
        assert!(e.contains("a.bpk") && e.contains("damaged"), "{e}");
        std::fs::remove_file(dir.path().join("a.bpk")).unwrap();
        let e = verify(dir.path()).unwrap_err().to_string();
        assert!(e.contains("missing"), "{e}");
        // a seal that names a file outside the checkpoint is refused without reading it
        std::fs::write(
            dir.path().join(CHECKSUMS_FILE),
            r#"{"../../etc/passwd": "00"}"#,
        )
        .unwrap();
        let e = verify(dir.path()).unwrap_err().to_string();
        assert!(e.contains("not a file of the checkpoint"), "{e}");
    }

    /// Without its seal a checkpoint is refused, unless trusted (issue 72: with
    /// `checksums.json` deleted, damaged weights loaded with a warning and eval said rc 0).
    #[test]
    fn an_unsealed_checkpoint_is_refused_unless_trusted() {
        let dir = tempfile::tempdir().unwrap();
        let weights = dir.path().join("nerf.bpk");
        std::fs::write(&weights, vec![7u8; 100]).unwrap();
        let e = verify_file_trusting(&weights, false)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains(CHECKSUMS_FILE) && e.contains("--trust-unsealed"),
            "{e}"
        );
        assert!(verify(dir.path()).is_err());
        verify_file_trusting(&weights, true).unwrap();
    }
}
