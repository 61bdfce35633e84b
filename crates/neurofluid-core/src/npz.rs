//! NumPy `.npz` archives (a zip of `.npy` arrays): read and write, little-endian, C order.
//!
//! Reading converts on the fly: [`NpzReader::f32`] accepts `f4`/`f8` (and integers), and
//! [`NpzReader::i64`] accepts any integer or boolean width. Every error names the file, the array
//! and what was expected. Writing goes to a temporary file that is renamed into place, so a
//! crash never leaves a partly written archive.
//!
//! Why not the `npyz` crate: its `npz` feature (0.9.1) pins zip 0.6 with bzip2's C library, a
//! third zip beside Burn's and ours, and its errors name neither the file nor the array. The zip
//! container comes from the same maintained `zip` crate Burn uses; only the `.npy` header and
//! the dtype conversions are ours.

use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// Errors of `.npz` input and output, each naming the file (and the array where there is one).
#[derive(Debug, thiserror::Error)]
pub enum NpzError {
    /// The file could not be opened, read or written.
    #[error("{path}: {error}")]
    Io {
        /// The archive.
        path: PathBuf,
        /// The underlying error (shown in the message, not repeated as a source).
        error: std::io::Error,
    },
    /// The file is not a readable zip archive.
    #[error("{path}: not a valid .npz (zip) archive: {message}")]
    Zip {
        /// The archive.
        path: PathBuf,
        /// What the zip reader said.
        message: String,
    },
    /// A required array is absent.
    #[error("{path}: no array `{name}` (found: {found})")]
    Missing {
        /// The archive.
        path: PathBuf,
        /// The array asked for.
        name: String,
        /// The arrays the archive holds.
        found: String,
    },
    /// An array exists but is not what was expected.
    #[error("{path}: array `{name}`: {message}")]
    Invalid {
        /// The archive.
        path: PathBuf,
        /// The array.
        name: String,
        /// What is wrong and what was expected.
        message: String,
    },
}

/// An n-dimensional array in C order.
#[derive(Debug, Clone, PartialEq)]
pub struct Array<T> {
    /// Extent of every axis.
    pub shape: Vec<usize>,
    /// The elements, last axis fastest.
    pub data: Vec<T>,
}

impl<T: Copy> Array<T> {
    /// Number of elements.
    pub fn len(&self) -> usize {
        self.data.len()
    }

    /// True for an array without elements.
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }
}

impl Array<f32> {
    /// The rows of an `[N, 3]` array as points.
    pub fn to_points(&self) -> Option<Vec<[f32; 3]>> {
        if self.shape.len() != 2 || self.shape[1] != 3 {
            return None;
        }
        Some(
            self.data
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect(),
        )
    }
}

/// Element types an `.npy` header may declare that this reader understands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Dtype {
    F4,
    F8,
    I1,
    I2,
    I4,
    I8,
    U1,
    U2,
    U4,
    U8,
    B1,
}

impl Dtype {
    fn parse(descr: &str) -> Option<Self> {
        // the byte order is one ASCII character; an empty or non-ASCII `descr` is no dtype
        let code = descr
            .strip_prefix('<')
            .or_else(|| descr.strip_prefix('|'))
            .or_else(|| descr.strip_prefix('='))?;
        Some(match code {
            "f4" => Self::F4,
            "f8" => Self::F8,
            "i1" => Self::I1,
            "i2" => Self::I2,
            "i4" => Self::I4,
            "i8" => Self::I8,
            "u1" => Self::U1,
            "u2" => Self::U2,
            "u4" => Self::U4,
            "u8" => Self::U8,
            "b1" => Self::B1,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I1 | Self::U1 | Self::B1 => 1,
            Self::I2 | Self::U2 => 2,
            Self::F4 | Self::I4 | Self::U4 => 4,
            Self::F8 | Self::I8 | Self::U8 => 8,
        }
    }

    fn is_float(self) -> bool {
        matches!(self, Self::F4 | Self::F8)
    }

    /// Element `i` of little-endian raw bytes as f64 (exact for every supported type but u8/i8
    /// beyond 2^53, which never occur in particle data).
    fn get_f64(self, b: &[u8], i: usize) -> f64 {
        let s = &b[i * self.size()..(i + 1) * self.size()];
        match self {
            Self::F4 => f32::from_le_bytes(s.try_into().unwrap()) as f64,
            Self::F8 => f64::from_le_bytes(s.try_into().unwrap()),
            _ => self.get_i64(b, i) as f64,
        }
    }

    fn get_i64(self, b: &[u8], i: usize) -> i64 {
        let s = &b[i * self.size()..(i + 1) * self.size()];
        match self {
            Self::I1 => s[0] as i8 as i64,
            Self::U1 | Self::B1 => s[0] as i64,
            Self::I2 => i16::from_le_bytes(s.try_into().unwrap()) as i64,
            Self::U2 => u16::from_le_bytes(s.try_into().unwrap()) as i64,
            Self::I4 => i32::from_le_bytes(s.try_into().unwrap()) as i64,
            Self::U4 => u32::from_le_bytes(s.try_into().unwrap()) as i64,
            Self::I8 => i64::from_le_bytes(s.try_into().unwrap()),
            Self::U8 => u64::from_le_bytes(s.try_into().unwrap()) as i64,
            Self::F4 | Self::F8 => self.get_f64(b, i) as i64,
        }
    }
}

/// A parsed `.npy` payload.
struct RawArray {
    dtype: Dtype,
    shape: Vec<usize>,
    bytes: Vec<u8>,
}

/// The longest `.npy` header read (numpy writes under 200 bytes; its own reader allows 10 000).
const MAX_NPY_HEADER: usize = 1 << 16;

/// Reads an `.npy` array from `r`, whose entry declares `declared` bytes: the header first, then
/// exactly the bytes its shape needs, once that size is checked against the limit and the entry;
/// `Err` carries a message for [`NpzError::Invalid`].
fn read_npy(r: &mut impl Read, declared: u64) -> Result<RawArray, String> {
    let mut exact = |n: usize| -> Result<Vec<u8>, String> {
        let mut b = Vec::with_capacity(n);
        r.take(n as u64)
            .read_to_end(&mut b)
            .map_err(|e| format!("reading it: {e}"))?;
        if b.len() < n {
            return Err(format!("the entry ends after {} of {n} bytes", b.len()));
        }
        Ok(b)
    };
    let lead = exact(10).map_err(|_| "not an .npy array (too short)".to_string())?;
    if &lead[..6] != b"\x93NUMPY" {
        return Err("not an .npy array (bad magic)".into());
    }
    let header_len = match lead[6] {
        1 => u16::from_le_bytes([lead[8], lead[9]]) as usize,
        2 | 3 => {
            let more = exact(2)?;
            u32::from_le_bytes([lead[8], lead[9], more[0], more[1]]) as usize
        }
        v => return Err(format!("unsupported .npy version {v}")),
    };
    if header_len > MAX_NPY_HEADER {
        return Err(format!(
            "an .npy header of {header_len} bytes (expected at most {MAX_NPY_HEADER})"
        ));
    }
    let start = if lead[6] == 1 { 10 } else { 12 };
    let header = exact(header_len).map_err(|_| "truncated .npy header".to_string())?;
    let header = std::str::from_utf8(&header).map_err(|_| "non-text .npy header".to_string())?;
    let field = |key: &str| -> Result<&str, String> {
        let at = header
            .find(&format!("'{key}'"))
            .ok_or(format!("header has no '{key}'"))?;
        Ok(header[at + key.len() + 2..]
            .trim_start()
            .trim_start_matches(':')
            .trim_start())
    };
    let descr_text = field("descr")?;
    let descr = descr_text
        .strip_prefix('\'')
        .and_then(|s| s.split('\'').next())
        .ok_or("malformed 'descr'")?;
    let dtype = Dtype::parse(descr).ok_or(format!(
        "unsupported dtype '{descr}' (expected little-endian float32/64, integer or bool)"
    ))?;
    if field("fortran_order")?.starts_with("True") {
        return Err("Fortran-ordered arrays are not supported (save with C order)".into());
    }
    let shape_text = field("shape")?;
    let inner = shape_text
        .strip_prefix('(')
        .and_then(|s| s.split(')').next())
        .ok_or("malformed 'shape'")?;
    let shape = inner
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.trim_end_matches('L').parse::<usize>())
        .collect::<Result<Vec<_>, _>>()
        .map_err(|_| format!("malformed shape ({inner})"))?;
    let need = crate::limits::array_bytes(&shape, dtype.size())?;
    crate::limits::check_decoded(&format!("shape {shape:?} of {descr}"), need)?;
    let held = declared.saturating_sub((start + header_len) as u64);
    if held < need {
        return Err(format!(
            "holds {held} bytes, shape {shape:?} of {descr} needs {need}"
        ));
    }
    let bytes = exact(need as usize).map_err(|e| {
        format!("{e}: shape {shape:?} of {descr} needs {need} bytes after the header")
    })?;
    Ok(RawArray {
        dtype,
        shape,
        bytes,
    })
}

/// Deflate's largest expansion: no honest entry decompresses to more than this many times its
/// compressed size.
const DEFLATE_MAX_RATIO: u64 = 1032;

/// Reads arrays from an `.npz` archive by name. The arrays read from one archive take at most
/// [`crate::limits::max_decoded_bytes`] together, as one file's content.
pub struct NpzReader {
    path: PathBuf,
    zip: zip::ZipArchive<File>,
    /// Bytes of the arrays read so far.
    taken: u64,
    /// The most bytes the arrays read may take together.
    budget: u64,
}

impl std::fmt::Debug for NpzReader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NpzReader")
            .field("path", &self.path)
            .finish()
    }
}

impl NpzReader {
    /// Opens an archive.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, NpzError> {
        let path = path.as_ref().to_path_buf();
        let file = crate::input_file::open(&path).map_err(|error| NpzError::Io {
            path: path.clone(),
            error,
        })?;
        let zip = zip::ZipArchive::new(file).map_err(|e| NpzError::Zip {
            path: path.clone(),
            message: e.to_string(),
        })?;
        Ok(Self {
            path,
            zip,
            taken: 0,
            budget: crate::limits::max_decoded_bytes(),
        })
    }

    /// The path the archive was opened from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Names of the arrays in the archive (without `.npy`), sorted.
    pub fn names(&self) -> Vec<String> {
        let mut names: Vec<String> = self
            .zip
            .file_names()
            .filter_map(Result::ok)
            .map(|n| n.strip_suffix(".npy").unwrap_or(&n).to_string())
            .collect();
        names.sort();
        names
    }

    /// True when the archive holds an array of that name.
    pub fn contains(&self, name: &str) -> bool {
        self.zip.index_for_name(&format!("{name}.npy")).is_some()
    }

    fn invalid(&self, name: &str, message: impl Into<String>) -> NpzError {
        NpzError::Invalid {
            path: self.path.clone(),
            name: name.to_string(),
            message: message.into(),
        }
    }

    fn raw(&mut self, name: &str) -> Result<RawArray, NpzError> {
        let found = self.names().join(", ");
        let budget = self.budget;
        let mut entry = match self.zip.by_name(&format!("{name}.npy")) {
            Ok(e) => e,
            Err(zip::result::ZipError::FileNotFound) => {
                return Err(NpzError::Missing {
                    path: self.path.clone(),
                    name: name.to_string(),
                    found,
                });
            }
            Err(e) => {
                return Err(NpzError::Zip {
                    path: self.path.clone(),
                    message: e.to_string(),
                });
            }
        };
        // the declared size is checked against the limit and the stored bytes before reading;
        // then only what the array's header declares is read
        let declared = entry.size();
        let stored = entry.compressed_size();
        let what = format!("{declared} bytes declared from {stored} stored");
        let taken = self.taken.saturating_add(declared);
        let read = crate::limits::check_decoded(&format!("the array ({what})"), declared)
            .and_then(|()| {
                if taken <= budget {
                    return Ok(());
                }
                Err(format!(
                    "with the arrays read before it ({what}), the archive's arrays would take \
                     {taken} bytes, over the limit of {budget} bytes per file ({}; set it \
                     higher for larger files)",
                    crate::limits::MAX_FILE_MB_ENV
                ))
            })
            .and_then(|()| {
                if declared > stored.saturating_mul(DEFLATE_MAX_RATIO) {
                    return Err(format!(
                        "{what}: more than deflate's {DEFLATE_MAX_RATIO}:1 (a damaged archive)"
                    ));
                }
                read_npy(&mut entry, declared)
            });
        drop(entry);
        self.taken = taken;
        read.map_err(|m| self.invalid(name, m))
    }

    /// A float array as f32 (float64 is rounded, integers converted).
    pub fn f32(&mut self, name: &str) -> Result<Array<f32>, NpzError> {
        let raw = self.raw(name)?;
        let n = raw.bytes.len() / raw.dtype.size();
        let data = (0..n)
            .map(|i| raw.dtype.get_f64(&raw.bytes, i) as f32)
            .collect();
        Ok(Array {
            shape: raw.shape,
            data,
        })
    }

    /// A float array as f64.
    pub fn f64(&mut self, name: &str) -> Result<Array<f64>, NpzError> {
        let raw = self.raw(name)?;
        let n = raw.bytes.len() / raw.dtype.size();
        let data = (0..n).map(|i| raw.dtype.get_f64(&raw.bytes, i)).collect();
        Ok(Array {
            shape: raw.shape,
            data,
        })
    }

    /// An integer (or boolean) array as i64; a float array is an error.
    pub fn i64(&mut self, name: &str) -> Result<Array<i64>, NpzError> {
        let raw = self.raw(name)?;
        if raw.dtype.is_float() {
            return Err(self.invalid(name, "expected an integer array, found floats"));
        }
        let n = raw.bytes.len() / raw.dtype.size();
        let data = (0..n).map(|i| raw.dtype.get_i64(&raw.bytes, i)).collect();
        Ok(Array {
            shape: raw.shape,
            data,
        })
    }

    /// An `[N, 3]` float array as points, checking the shape and that every value is finite.
    pub fn points(&mut self, name: &str) -> Result<Vec<[f32; 3]>, NpzError> {
        let a = self.f32(name)?;
        let pts = a.to_points().ok_or_else(|| {
            self.invalid(name, format!("expected shape [N, 3], found {:?}", a.shape))
        })?;
        if let Some(i) = pts.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
            return Err(self.invalid(name, format!("row {i} is not finite: {:?}", pts[i])));
        }
        Ok(pts)
    }
}

/// Collects arrays and writes them as one `.npz` archive.
#[derive(Debug, Default)]
pub struct NpzWriter {
    entries: Vec<(String, Vec<u8>)>,
}

fn npy_bytes(descr: &str, shape: &[usize], payload: &[u8]) -> Vec<u8> {
    let shape_text = match shape.len() {
        0 => "()".to_string(),
        1 => format!("({},)", shape[0]),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|s| s.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut header =
        format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape_text}, }}");
    // magic (6) + version (2) + length (2) + header + '\n' is padded to a multiple of 64
    let total = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - total % 64) % 64));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + payload.len());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(payload);
    out
}

impl NpzWriter {
    /// An empty archive.
    pub fn new() -> Self {
        Self::default()
    }

    fn add(&mut self, name: &str, descr: &str, shape: &[usize], len: usize, payload: Vec<u8>) {
        assert_eq!(
            shape.iter().product::<usize>(),
            len,
            "array `{name}`: shape {shape:?} does not match {len} elements"
        );
        self.entries.retain(|(n, _)| n != name);
        self.entries
            .push((name.to_string(), npy_bytes(descr, shape, &payload)));
    }

    /// Adds a float32 array.
    ///
    /// # Panics
    /// When the shape does not match the number of elements (a programming error).
    pub fn add_f32(&mut self, name: &str, shape: &[usize], data: &[f32]) {
        let payload = data.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.add(name, "<f4", shape, data.len(), payload);
    }

    /// Adds an `[N, 3]` float32 array of points.
    pub fn add_points(&mut self, name: &str, points: &[[f32; 3]]) {
        self.add_f32(name, &[points.len(), 3], points.as_flattened());
    }

    /// Adds an int32 array.
    ///
    /// # Panics
    /// When the shape does not match the number of elements (a programming error).
    pub fn add_i32(&mut self, name: &str, shape: &[usize], data: &[i32]) {
        let payload = data.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.add(name, "<i4", shape, data.len(), payload);
    }

    /// Adds an int64 array.
    ///
    /// # Panics
    /// When the shape does not match the number of elements (a programming error).
    pub fn add_i64(&mut self, name: &str, shape: &[usize], data: &[i64]) {
        let payload = data.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.add(name, "<i8", shape, data.len(), payload);
    }

    /// Writes the archive atomically (a temporary file in the same folder, then a rename).
    /// Entries are stored uncompressed, in the order they were added, with a fixed timestamp,
    /// so the same arrays always give the same bytes.
    pub fn write(self, path: impl AsRef<Path>) -> Result<(), NpzError> {
        let path = path.as_ref();
        let io = |error| NpzError::Io {
            path: path.to_path_buf(),
            error,
        };
        crate::atomic::write_with(path, |file| {
            let mut zip = zip::ZipWriter::new(file);
            let options = zip::write::SimpleFileOptions::default()
                .compression_method(zip::CompressionMethod::Stored)
                .last_modified_time(zip::DateTime::default());
            for (name, bytes) in &self.entries {
                zip.start_file(format!("{name}.npy"), options)
                    .map_err(std::io::Error::other)?;
                zip.write_all(bytes)?;
            }
            zip.finish().map_err(std::io::Error::other)?.flush()
        })
        .map_err(io)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_conversions() {
        let dir = std::env::temp_dir().join(format!("nf-npz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.npz");
        let mut w = NpzWriter::new();
        w.add_points("pos", &[[1.0, 2.0, 3.0], [4.0, 5.5, -6.0]]);
        w.add_i32("n", &[3], &[7, -1, 40]);
        w.add_i64("big", &[1, 2], &[1 << 40, 3]);
        w.add_f32("scalar", &[], &[2.5]);
        w.write(&path).unwrap();
        let mut r = NpzReader::open(&path).unwrap();
        assert_eq!(r.names(), vec!["big", "n", "pos", "scalar"]);
        assert_eq!(r.points("pos").unwrap()[1], [4.0, 5.5, -6.0]);
        assert_eq!(r.i64("n").unwrap().data, vec![7, -1, 40]);
        assert_eq!(r.i64("big").unwrap().shape, vec![1, 2]);
        assert_eq!(r.f32("n").unwrap().data, vec![7.0, -1.0, 40.0]);
        assert_eq!(r.f32("scalar").unwrap().shape, Vec::<usize>::new());
        // errors name the file and the array
        let e = r.f32("vel").unwrap_err().to_string();
        assert!(
            e.contains("a.npz") && e.contains("`vel`") && e.contains("pos"),
            "{e}"
        );
        let e = r.i64("pos").unwrap_err().to_string();
        assert!(e.contains("integer"), "{e}");
        let e = r.points("n").unwrap_err().to_string();
        assert!(e.contains("[N, 3]"), "{e}");
        // same content, same bytes
        let bytes = std::fs::read(&path).unwrap();
        let mut w = NpzWriter::new();
        w.add_points("pos", &[[1.0, 2.0, 3.0], [4.0, 5.5, -6.0]]);
        w.add_i32("n", &[3], &[7, -1, 40]);
        w.add_i64("big", &[1, 2], &[1 << 40, 3]);
        w.add_f32("scalar", &[], &[2.5]);
        w.write(&path).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), bytes);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn non_finite_points_and_missing_files_are_errors() {
        let dir = std::env::temp_dir().join(format!("nf-npz-nan-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("nan.npz");
        let mut w = NpzWriter::new();
        w.add_points("pos", &[[0.0, f32::NAN, 0.0]]);
        w.write(&path).unwrap();
        let e = NpzReader::open(&path).unwrap().points("pos").unwrap_err();
        assert!(e.to_string().contains("not finite"), "{e}");
        let e = NpzReader::open(dir.join("none.npz"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("none.npz"), "{e}");
        std::fs::write(dir.join("junk.npz"), b"hello").unwrap();
        let e = NpzReader::open(dir.join("junk.npz"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a valid .npz"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Declared shapes are checked before anything is allocated: one whose size overflows, one
    /// over the limit, one larger than the entry.
    #[test]
    fn huge_declared_shapes_are_errors() {
        let dir = tempfile_dir("huge");
        for (shape, needle) in [
            ("(4611686018427387904, 4)", "overflows"),
            ("(268435456, 3)", crate::limits::MAX_FILE_MB_ENV),
            ("(1000, 3)", "holds 0 bytes"),
        ] {
            let e = pos_error(&dir, "huge.npz", "<f4", shape, &[]);
            assert!(
                e.contains("huge.npz") && e.contains("`pos`") && e.contains(needle),
                "{e}"
            );
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Arrays each within the limit are refused once together they pass it, before the one
    /// that passes it is read (issue 72: two 1,000 MiB arrays in a 2 MB archive took 3.1 GB).
    #[test]
    fn the_arrays_of_one_archive_share_the_limit() {
        let dir = tempfile_dir("total");
        let path = dir.join("two.npz");
        let mut w = NpzWriter::new();
        w.add_f32("a", &[250], &[1.0; 250]);
        w.add_f32("b", &[250], &[2.0; 250]);
        w.write(&path).unwrap();
        let mut r = NpzReader::open(&path).unwrap();
        r.budget = 1500;
        assert_eq!(r.f32("a").unwrap().len(), 250);
        let e = r.f32("b").unwrap_err().to_string();
        assert!(
            e.contains("two.npz") && e.contains("`b`") && e.contains("limit of 1500"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A `descr` that is empty or starts with a multi-byte character is an error naming the
    /// entry, not a panic (it panicked in `split_at(1)`; issue 72).
    #[test]
    fn odd_dtype_descriptions_are_errors() {
        let dir = tempfile_dir("descr");
        for descr in ["", "é4", "€", ">f4", "<c8"] {
            let e = pos_error(&dir, "descr.npz", descr, "(1, 3)", &[0u8; 12]);
            assert!(
                e.contains("descr.npz") && e.contains("`pos`"),
                "{descr:?}: {e}"
            );
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// The error of reading `pos` as float32 from `dir/name`, an archive of that one entry whose
    /// npy header declares `descr` and `shape` (as Python writes a tuple), followed by `payload`.
    fn pos_error(dir: &Path, name: &str, descr: &str, shape: &str, payload: &[u8]) -> String {
        let header =
            format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}\n");
        let mut npy = b"\x93NUMPY\x01\x00".to_vec();
        npy.extend((header.len() as u16).to_le_bytes());
        npy.extend(header.as_bytes());
        npy.extend(payload);
        let path = dir.join(name);
        let mut w = NpzWriter::new();
        w.entries.push(("pos".into(), npy));
        w.write(&path).unwrap();
        let read = NpzReader::open(&path).unwrap().f32("pos");
        read.expect_err("the header is refused").to_string()
    }

    fn tempfile_dir(tag: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("nf-npz-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }
}
