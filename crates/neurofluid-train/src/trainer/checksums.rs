//! A checkpoint's seal: `checksums.json` lists the SHA-256 of every file the checkpoint was
//! written with. It is written inside the checkpoint's temporary folder, so it appears with the
//! checkpoint in one rename; a file that later differs (a damaged disk, a partial copy, an edit)
//! makes the checkpoint refused as damaged, never loaded or called good.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

use anyhow::Context;
use sha2::{Digest, Sha256};

/// The seal's file name inside a checkpoint folder.
pub const CHECKSUMS_FILE: &str = "checksums.json";

/// SHA-256 of a file, as 64 hex digits.
pub fn file_sha256(path: &Path) -> anyhow::Result<String> {
    let mut file =
        std::fs::File::open(path).with_context(|| format!("reading {}", path.display()))?;
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = file
            .read(&mut buf)
            .with_context(|| format!("reading {}", path.display()))?;
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
pub fn seal(dir: &Path) -> anyhow::Result<()> {
    let mut sums = BTreeMap::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        let entry = entry.with_context(|| format!("reading {}", dir.display()))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if name != CHECKSUMS_FILE && entry.file_type().is_ok_and(|t| t.is_file()) {
            sums.insert(name, file_sha256(&entry.path())?);
        }
    }
    let path = dir.join(CHECKSUMS_FILE);
    std::fs::write(&path, serde_json::to_string_pretty(&sums)?)
        .with_context(|| format!("writing {}", path.display()))
}

/// The seal of the checkpoint `dir`, if it has one (checkpoints of earlier releases do not).
fn read_seal(dir: &Path) -> anyhow::Result<Option<BTreeMap<String, String>>> {
    let path = dir.join(CHECKSUMS_FILE);
    if !path.is_file() {
        return Ok(None);
    }
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text)
        .map(Some)
        .with_context(|| format!("{}: a damaged checkpoint (malformed seal)", path.display()))
}

fn damaged(path: &Path, what: &str) -> anyhow::Error {
    anyhow::anyhow!(
        "{}: a damaged checkpoint ({what}); it is not loaded: restore the file or start the \
         stage over with --fresh",
        path.display()
    )
}

/// Checks the file `path` of a checkpoint against its folder's seal (unsealed checkpoints of
/// earlier releases pass with a warning).
pub fn verify_file(path: &Path) -> anyhow::Result<()> {
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
pub fn verify(dir: &Path) -> anyhow::Result<()> {
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
pub fn seal_digest(dir: &Path) -> anyhow::Result<Option<String>> {
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
