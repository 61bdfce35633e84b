//! Caps on what one input file may make the tool allocate, checked against the sizes a file
//! declares (array shapes, image dimensions, vertex counts, decompressed lengths) before the
//! allocation, so a hostile or damaged file gets a clear error instead of exhausting memory.
//!
//! Two knobs raise them: `NEUROFLUID_MAX_FILE_MB` (default 1024) is the most one file's decoded
//! content may take, in MiB; an image may hold at most that many bytes at 16 bytes a pixel
//! (8192 × 8192 by default). `NEUROFLUID_MAX_DATASET_MB` (default 3072) is the most the decoded
//! images a scene's views use may take together, checked when the scene is opened. Nesting
//! depth and pickle value counts are fixed: the files this tool reads need a handful of each.

/// The environment variable that sets [`max_decoded_bytes`] in MiB.
pub const MAX_FILE_MB_ENV: &str = "NEUROFLUID_MAX_FILE_MB";

/// The default of [`max_decoded_bytes`], in MiB.
pub const DEFAULT_MAX_FILE_MB: u64 = 1024;

/// The environment variable that sets [`max_dataset_bytes`] in MiB.
pub const MAX_DATASET_MB_ENV: &str = "NEUROFLUID_MAX_DATASET_MB";

/// The default of [`max_dataset_bytes`], in MiB: five times the 240 decoded 400² images of a
/// built-in scene's four views (614 MB).
pub const DEFAULT_MAX_DATASET_MB: u64 = 3072;

/// The deepest nesting of containers a structured file may hold (pickles).
pub const MAX_NESTING: usize = 64;

/// The most values (numbers, strings, containers) a pickle may build, memo copies included.
pub const MAX_PICKLE_VALUES: usize = 1 << 20;

/// Bytes a decoded image pixel takes (RGBA, float32).
pub const BYTES_PER_PIXEL: u64 = 16;

/// A size limit set in MiB by an environment variable: its name, default and meaning.
struct MibSetting {
    var: &'static str,
    default: u64,
    meaning: &'static str,
}

const MAX_FILE: MibSetting = MibSetting {
    var: MAX_FILE_MB_ENV,
    default: DEFAULT_MAX_FILE_MB,
    meaning: "the most one file's decoded content may take",
};

const MAX_DATASET: MibSetting = MibSetting {
    var: MAX_DATASET_MB_ENV,
    default: DEFAULT_MAX_DATASET_MB,
    meaning: "the most a scene's decoded images may take together",
};

impl MibSetting {
    /// `text` read as MiB: a whole number ≥ 1, or an error that names the variable, what it
    /// holds (cut to 40 characters) and what was expected.
    fn parse(&self, text: &str) -> Result<u64, String> {
        match text.trim().parse::<u64>() {
            Ok(mb) if mb > 0 => Ok(mb),
            _ => Err(format!(
                "{}={}: expected a whole number of MiB ≥ 1 ({}; unset: {})",
                self.var,
                crate::paths::quoted(text, 40),
                self.meaning,
                self.default
            )),
        }
    }

    /// The setting in MiB: the default when unset, an error when set to anything but a whole
    /// number ≥ 1.
    fn mib(&self) -> Result<u64, String> {
        match std::env::var(self.var) {
            Err(std::env::VarError::NotPresent) => Ok(self.default),
            Err(std::env::VarError::NotUnicode(v)) => self.parse(&v.to_string_lossy()),
            Ok(v) => self.parse(&v),
        }
    }

    /// The setting in bytes (a bad value, which the programs refuse when they start, counts as
    /// the default here).
    fn bytes(&self) -> u64 {
        self.mib().unwrap_or(self.default).saturating_mul(1 << 20)
    }
}

/// `NEUROFLUID_MAX_FILE_MB`'s value `text` read as MiB: a whole number ≥ 1, or an error that
/// names the variable, what it holds (cut to 40 characters) and what was expected.
pub fn parse_max_file_mb(text: &str) -> Result<u64, String> {
    MAX_FILE.parse(text)
}

/// Checks the limits' environment variables; the programs call it when they start, so a bad
/// value stops them with its error instead of being ignored.
pub fn check_environment() -> Result<(), String> {
    MAX_FILE.mib()?;
    MAX_DATASET.mib()?;
    Ok(())
}

/// The most bytes one file's decoded content may take: `NEUROFLUID_MAX_FILE_MB` MiB (default
/// [`DEFAULT_MAX_FILE_MB`]).
pub fn max_decoded_bytes() -> u64 {
    MAX_FILE.bytes()
}

/// The most bytes the decoded images of a scene's views may take together:
/// `NEUROFLUID_MAX_DATASET_MB` MiB (default [`DEFAULT_MAX_DATASET_MB`]).
pub fn max_dataset_bytes() -> u64 {
    MAX_DATASET.bytes()
}

/// Checks that the decoded images of a dataset (`what`) take at most [`max_dataset_bytes`].
pub fn check_dataset(what: &str, bytes: u64) -> Result<(), String> {
    let limit = max_dataset_bytes();
    if bytes <= limit {
        return Ok(());
    }
    Err(format!(
        "{what} would take {bytes} bytes decoded, over the limit of {limit} bytes per scene \
         ({MAX_DATASET_MB_ENV}={}; set it higher for larger scenes)",
        limit >> 20
    ))
}

/// The most pixels one image may hold.
pub fn max_image_pixels() -> u64 {
    max_decoded_bytes() / BYTES_PER_PIXEL
}

/// Checks that `bytes` of decoded content (what `what` declares) is within
/// [`max_decoded_bytes`]; the error says what, how much, the limit and the knob.
pub fn check_decoded(what: &str, bytes: u64) -> Result<(), String> {
    let limit = max_decoded_bytes();
    if bytes <= limit {
        return Ok(());
    }
    Err(format!(
        "{what} would take {bytes} bytes, over the limit of {limit} bytes per file \
         ({MAX_FILE_MB_ENV}={}; set it higher for larger files)",
        limit >> 20
    ))
}

/// The bytes of an array of `shape` with `item`-byte elements, or an error when the product
/// overflows (a shape no file can hold).
pub fn array_bytes(shape: &[usize], item: usize) -> Result<u64, String> {
    shape
        .iter()
        .try_fold(item as u64, |acc, &d| acc.checked_mul(d as u64))
        .ok_or_else(|| format!("shape {shape:?} is too large to exist (its size overflows)"))
}

/// Checks an image's declared dimensions against [`max_image_pixels`].
pub fn check_image(width: u32, height: u32) -> Result<(), String> {
    let pixels = width as u64 * height as u64;
    let limit = max_image_pixels();
    if pixels <= limit {
        return Ok(());
    }
    Err(format!(
        "a {width}×{height} image has {pixels} pixels, over the limit of {limit} \
         ({MAX_FILE_MB_ENV}={}; set it higher for larger images)",
        max_decoded_bytes() >> 20
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_overflow_into_errors_and_the_cap_is_named() {
        assert_eq!(array_bytes(&[2, 3], 4), Ok(24));
        assert_eq!(array_bytes(&[], 8), Ok(8));
        assert!(
            array_bytes(&[1 << 62, 4], 4)
                .unwrap_err()
                .contains("overflows")
        );
        let e = check_decoded("x", u64::MAX).unwrap_err();
        assert!(e.contains(MAX_FILE_MB_ENV), "{e}");
        assert!(check_decoded("x", 1 << 20).is_ok());
        assert!(check_image(800, 800).is_ok());
        assert!(check_image(u32::MAX, u32::MAX).is_err());
    }

    /// A value that is not a whole number of MiB ≥ 1 is an error naming the variable and the
    /// value (it was ignored without a word; issue 72), cut to 40 characters.
    #[test]
    fn a_bad_cap_is_an_error_not_ignored() {
        assert_eq!(parse_max_file_mb(" 2048 "), Ok(2048));
        for bad in ["abc", "0", "-5", "1.5", ""] {
            let e = parse_max_file_mb(bad).unwrap_err();
            assert!(
                e.contains(MAX_FILE_MB_ENV) && e.contains("whole number"),
                "{bad:?}: {e}"
            );
        }
        let long = "9".repeat(10_000) + "x";
        let e = parse_max_file_mb(&long).unwrap_err();
        assert!(e.len() < 300, "{} bytes", e.len());
        let e = MAX_DATASET.parse("0").unwrap_err();
        assert!(e.contains(MAX_DATASET_MB_ENV), "{e}");
    }

    #[test]
    fn the_dataset_budget_is_named() {
        assert!(check_dataset("x", 600 << 20).is_ok());
        let e = check_dataset("4 views", 4 * 8000 * 8000 * BYTES_PER_PIXEL).unwrap_err();
        assert!(
            e.contains(MAX_DATASET_MB_ENV) && e.contains("4 views"),
            "{e}"
        );
    }
}
