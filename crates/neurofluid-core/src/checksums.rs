//! A checkpoint's seal: `checksums.json` lists the SHA-256 of every file the checkpoint was
//! written with. It is written inside the checkpoint's temporary folder, so it appears with the
//! checkpoint in one rename; a file that later differs (a damaged disk, a partial copy, an edit)
//! makes the checkpoint refused as damaged, never loaded or called good.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};

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

/// SHA-256 of a file, as 64 hex digits.
pub fn file_sha256(path: &Path) -> Result<String, ChecksumError> {
    let mut file = std::fs::File::open(path).map_err(PathIoError::on("reading", path))?;
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
    let text = std::fs::read_to_string(&path).map_err(PathIoError::on("reading", &path))?;
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

/// Checks the file `path` of a checkpoint against its folder's seal (unsealed checkpoints of
/// earlier releases pass with a warning).
pub fn verify_file(path: &Path) -> Result<(), ChecksumError> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let Some(seal) = read_seal(dir)? else {
        tracing::warn!(
            "{}: the checkpoint has no {CHECKSUMS_FILE}; loading it unchecked",
            dir.display()
        );
        return Ok(());
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

/// Checks every file the seal of `dir` lists.
pub fn verify(dir: &Path) -> Result<(), ChecksumError> {
    let Some(seal) = read_seal(dir)? else {
        return Ok(());
    };
    for name in seal.keys() {
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
    }
}
