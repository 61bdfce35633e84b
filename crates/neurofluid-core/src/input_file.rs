//! Input files opened and read in bounded memory and time: only regular files (a FIFO would
//! block forever, `/dev/zero` never ends), not sparse ones (a file of holes claims gigabytes it
//! never wrote), and no longer than [`crate::limits::max_decoded_bytes`], all checked from the
//! file's metadata before a byte is read; the read itself stops one byte past the limit, so a
//! file that grows while it is read is refused too.
//!
//! The errors are `std::io::Error`s (kind `InvalidInput`) whose message says what the file is
//! and what was expected; the callers wrap them with the path, as for any other read error.

use std::fs::{File, Metadata};
use std::io::{Error, ErrorKind, Read};
use std::path::Path;

use crate::limits::{MAX_FILE_MB_ENV, max_decoded_bytes};

/// Files at least this long are checked for holes.
const SPARSE_CHECK_FROM: u64 = 1 << 20;

/// A file whose blocks on disk hold less than this share of its length is sparse.
const SPARSE_SHARE: u64 = 16;

/// What kind of file `meta` describes, in words, for one that is not a regular file.
fn kind(meta: &Metadata) -> &'static str {
    let t = meta.file_type();
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if t.is_char_device() {
            return "a character device";
        }
        if t.is_block_device() {
            return "a block device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    if t.is_dir() { "a folder" } else { "not a file" }
}

fn refused(message: String) -> Error {
    Error::new(ErrorKind::InvalidInput, message)
}

/// Checks `meta` (of a file about to be read) against the rules above and returns its length.
fn check_metadata(meta: &Metadata) -> std::io::Result<u64> {
    if !meta.is_file() {
        return Err(refused(format!(
            "{}, expected a regular file (special files are not read: they can block or never end)",
            kind(meta)
        )));
    }
    let len = meta.len();
    let limit = max_decoded_bytes();
    if len > limit {
        return Err(refused(format!(
            "{len} bytes long, over the limit of {limit} bytes per file ({MAX_FILE_MB_ENV}={}; \
             set it higher for larger files)",
            limit >> 20
        )));
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        let on_disk = meta.blocks().saturating_mul(512);
        if len >= SPARSE_CHECK_FROM && on_disk.saturating_mul(SPARSE_SHARE) < len {
            return Err(refused(format!(
                "a sparse file ({len} bytes long, {on_disk} bytes on disk): its holes were never \
                 written, expected data a tool wrote (a real copy: `cp --sparse=never`)"
            )));
        }
    }
    Ok(len)
}

/// Checks that `path` (its links followed) is a regular file that may be read, without opening
/// it, and returns its length.
pub fn check(path: impl AsRef<Path>) -> std::io::Result<u64> {
    check_metadata(&std::fs::metadata(path)?)
}

/// Opens `path` for reading once [`check`] passed, and checks the opened file again (the
/// path could have been replaced in between).
pub fn open(path: impl AsRef<Path>) -> std::io::Result<File> {
    Ok(open_with_length(path.as_ref())?.0)
}

/// [`open`], and the opened file's length.
fn open_with_length(path: &Path) -> std::io::Result<(File, u64)> {
    check(path)?;
    let file = File::open(path)?;
    let len = check_metadata(&file.metadata()?)?;
    Ok((file, len))
}

/// Reads all of `path` in bounded memory (see the module's rules).
pub fn read(path: impl AsRef<Path>) -> std::io::Result<Vec<u8>> {
    let (file, len) = open_with_length(path.as_ref())?;
    let limit = max_decoded_bytes();
    let mut bytes = Vec::with_capacity(len as usize);
    file.take(limit.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return Err(refused(format!(
            "grew past the limit of {limit} bytes per file while it was read ({MAX_FILE_MB_ENV})"
        )));
    }
    Ok(bytes)
}

/// Reads all of `path` as UTF-8 text in bounded memory (see the module's rules).
pub fn read_string(path: impl AsRef<Path>) -> std::io::Result<String> {
    String::from_utf8(read(path)?).map_err(|e| {
        Error::new(
            ErrorKind::InvalidData,
            format!("not UTF-8 text (byte {})", e.utf8_error().valid_up_to()),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(tag: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("nf-input-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn regular_files_are_read_whole() {
        let d = dir("plain");
        let p = d.join("a.json");
        std::fs::write(&p, "{\"a\": 1}").unwrap();
        assert_eq!(read_string(&p).unwrap(), "{\"a\": 1}");
        assert_eq!(check(&p).unwrap(), 8);
        std::fs::write(&p, [0xff, 0xfe]).unwrap();
        assert!(read_string(&p).unwrap_err().to_string().contains("UTF-8"));
        assert!(read(&d).unwrap_err().to_string().contains("a folder"));
    }

    /// `/dev/zero` never ends and a FIFO blocks its reader until a writer comes: both are
    /// refused from their type, at once (issue 72: `info` read 2.1 GB of zeros, or hung).
    #[cfg(unix)]
    #[test]
    fn special_files_are_refused_without_reading() {
        let e = read(Path::new("/dev/zero")).unwrap_err();
        assert!(e.to_string().contains("character device"), "{e}");
        let d = dir("fifo");
        let fifo = d.join("transforms_test.json");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        if made.is_ok_and(|s| s.success()) {
            let e = read_string(&fifo).unwrap_err();
            assert!(e.to_string().contains("FIFO"), "{e}");
        }
        // through a link too
        let link = d.join("box.pt");
        std::os::unix::fs::symlink("/dev/zero", &link).unwrap();
        assert!(read(&link).unwrap_err().to_string().contains("device"));
    }

    /// A file of holes whose length is within the limit is refused from its blocks on disk; one
    /// longer than the limit from its length, before anything is read (issue 72: a 4 KB sparse
    /// PNG of 3 GB was read to 3.1 GB).
    #[test]
    fn sparse_and_oversized_files_are_refused_from_their_metadata() {
        let d = dir("sparse");
        let p = d.join("big.png");
        let f = File::create(&p).unwrap();
        f.set_len(64 << 20).unwrap();
        let e = read(&p).unwrap_err();
        #[cfg(unix)]
        assert!(e.to_string().contains("sparse"), "{e}");
        f.set_len(max_decoded_bytes() + 1).unwrap();
        let e = read(&p).unwrap_err();
        assert!(
            e.to_string().contains("over the limit") && e.to_string().contains(MAX_FILE_MB_ENV),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&d);
    }
}
