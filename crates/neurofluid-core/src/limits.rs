//! Caps on what one input file may make the tool allocate, checked against the sizes a file
//! declares (array shapes, image dimensions, vertex counts, decompressed lengths) before the
//! allocation, so a hostile or damaged file gets a clear error instead of exhausting memory.
//!
//! One knob raises them: `NEUROFLUID_MAX_FILE_MB` (default 1024) is the most one file's decoded
//! content may take, in MiB; an image may hold at most that many bytes at 16 bytes a pixel
//! (8192 × 8192 by default). Nesting depth and pickle value counts are fixed: the files this
//! tool reads need a handful of each.

/// The environment variable that sets [`max_decoded_bytes`] in MiB.
pub const MAX_FILE_MB_ENV: &str = "NEUROFLUID_MAX_FILE_MB";

/// The default of [`max_decoded_bytes`], in MiB.
pub const DEFAULT_MAX_FILE_MB: u64 = 1024;

/// The deepest nesting of containers a structured file may hold (pickles).
pub const MAX_NESTING: usize = 64;

/// The most values (numbers, strings, containers) a pickle may build, memo copies included.
pub const MAX_PICKLE_VALUES: usize = 1 << 20;

/// Bytes a decoded image pixel takes (RGBA, float32).
const BYTES_PER_PIXEL: u64 = 16;

/// `NEUROFLUID_MAX_FILE_MB`'s value `text` read as MiB: a whole number ≥ 1, or an error that
/// names the variable, what it holds (cut to 40 characters) and what was expected.
pub fn parse_max_file_mb(text: &str) -> Result<u64, String> {
    match text.trim().parse::<u64>() {
        Ok(mb) if mb > 0 => Ok(mb),
        _ => {
            let shown: String = text.chars().take(40).collect();
            let cut = if text.chars().count() > 40 { "…" } else { "" };
            Err(format!(
                "{MAX_FILE_MB_ENV}={shown:?}{cut}: expected a whole number of MiB ≥ 1 (the most \
                 one file's decoded content may take; unset: {DEFAULT_MAX_FILE_MB})"
            ))
        }
    }
}

/// The setting of `NEUROFLUID_MAX_FILE_MB` in MiB: [`DEFAULT_MAX_FILE_MB`] when unset, an error
/// when set to anything but a whole number ≥ 1. The programs check it when they start, so a
/// bad value stops them with that error instead of being ignored.
pub fn max_file_mb() -> Result<u64, String> {
    match std::env::var(MAX_FILE_MB_ENV) {
        Err(std::env::VarError::NotPresent) => Ok(DEFAULT_MAX_FILE_MB),
        Err(std::env::VarError::NotUnicode(v)) => parse_max_file_mb(&v.to_string_lossy()),
        Ok(v) => parse_max_file_mb(&v),
    }
}

/// The most bytes one file's decoded content may take: `NEUROFLUID_MAX_FILE_MB` MiB (default
/// [`DEFAULT_MAX_FILE_MB`]; a bad value, which the programs refuse when they start, counts as
/// the default here).
pub fn max_decoded_bytes() -> u64 {
    max_file_mb()
        .unwrap_or(DEFAULT_MAX_FILE_MB)
        .saturating_mul(1 << 20)
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
    }
}
