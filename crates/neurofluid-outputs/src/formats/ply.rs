//! Particles as PLY point clouds (`x y z` and optionally `vx vy vz`, float32), ASCII or binary
//! little-endian, written atomically; plus a reader for these files.

use std::io::Write;
use std::path::{Path, PathBuf};

/// PLY encodings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlyFormat {
    /// `format ascii 1.0`.
    Ascii,
    /// `format binary_little_endian 1.0`.
    BinaryLittleEndian,
}

/// Errors of the PLY writer and reader.
#[derive(Debug, thiserror::Error)]
pub enum PlyError {
    /// The file could not be read or written.
    #[error("PLY file {}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The IO error.
        source: std::io::Error,
    },
    /// The file is not a PLY this reader understands.
    #[error("PLY file {}: {message}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// Positions and velocities differ in length.
    #[error("{positions} positions but {velocities} velocities")]
    Mismatch {
        /// Number of positions.
        positions: usize,
        /// Number of velocities.
        velocities: usize,
    },
}

/// A point cloud read back from a PLY file.
#[derive(Debug, Clone, PartialEq)]
pub struct PlyData {
    /// Positions.
    pub positions: Vec<[f32; 3]>,
    /// Velocities, when the file has `vx vy vz`.
    pub velocities: Option<Vec<[f32; 3]>>,
}

/// The PLY file's bytes.
pub fn encode_ply(
    positions: &[[f32; 3]],
    velocities: Option<&[[f32; 3]]>,
    format: PlyFormat,
) -> Result<Vec<u8>, PlyError> {
    if let Some(v) = velocities
        && v.len() != positions.len()
    {
        return Err(PlyError::Mismatch {
            positions: positions.len(),
            velocities: v.len(),
        });
    }
    let mut out = Vec::with_capacity(positions.len() * 24 + 256);
    let fmt = match format {
        PlyFormat::Ascii => "ascii",
        PlyFormat::BinaryLittleEndian => "binary_little_endian",
    };
    let mut header = format!(
        "ply\nformat {fmt} 1.0\ncomment NeuroFluid-rs particles\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n",
        positions.len()
    );
    if velocities.is_some() {
        header.push_str("property float vx\nproperty float vy\nproperty float vz\n");
    }
    header.push_str("end_header\n");
    out.extend_from_slice(header.as_bytes());
    for (i, p) in positions.iter().enumerate() {
        let v = velocities.map(|v| v[i]);
        let values = p.iter().chain(v.iter().flatten());
        match format {
            PlyFormat::Ascii => {
                let line: Vec<String> = values.map(|x| x.to_string()).collect();
                writeln!(out, "{}", line.join(" ")).expect("writing to a Vec");
            }
            PlyFormat::BinaryLittleEndian => {
                for x in values {
                    out.extend_from_slice(&x.to_le_bytes());
                }
            }
        }
    }
    Ok(out)
}

/// Writes particles (and optionally velocities) to `path` atomically; parent folders are created.
pub fn write_ply(
    path: &Path,
    positions: &[[f32; 3]],
    velocities: Option<&[[f32; 3]]>,
    format: PlyFormat,
) -> Result<(), PlyError> {
    let bytes = encode_ply(positions, velocities, format)?;
    neurofluid_core::atomic::write_bytes(path, &bytes).map_err(|source| PlyError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads a PLY file with one `vertex` element of float32 properties including `x y z`
/// (and `vx vy vz` if present), ASCII or binary little-endian.
pub fn read_ply(path: &Path) -> Result<PlyData, PlyError> {
    let bytes = neurofluid_core::input_file::read(path).map_err(|source| PlyError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let bad = |message: String| PlyError::Format {
        path: path.to_path_buf(),
        message,
    };
    const END: &[u8] = b"end_header\n";
    let end = bytes
        .windows(END.len())
        .position(|w| w == END)
        .ok_or_else(|| bad("no `end_header` line".into()))?;
    let header =
        std::str::from_utf8(&bytes[..end]).map_err(|_| bad("header is not UTF-8".into()))?;
    let body = &bytes[end + END.len()..];
    let mut lines = header.lines();
    if lines.next() != Some("ply") {
        return Err(bad("does not start with `ply`".into()));
    }
    let mut format = None;
    let mut count = None;
    let mut props: Vec<String> = Vec::new();
    for line in lines {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["format", "ascii", _] => format = Some(PlyFormat::Ascii),
            ["format", "binary_little_endian", _] => format = Some(PlyFormat::BinaryLittleEndian),
            ["format", other, ..] => return Err(bad(format!("unsupported format `{other}`"))),
            ["element", "vertex", n] => {
                count = Some(
                    n.parse::<usize>()
                        .map_err(|_| bad(format!("bad vertex count `{n}`")))?,
                );
            }
            ["element", other, ..] => return Err(bad(format!("unsupported element `{other}`"))),
            ["property", ty, name] => {
                if !matches!(*ty, "float" | "float32") {
                    return Err(bad(format!("property `{name}` is `{ty}`, expected float")));
                }
                props.push(name.to_string());
            }
            ["comment", ..] | ["obj_info", ..] | [] => {}
            _ => return Err(bad(format!("unexpected header line `{line}`"))),
        }
    }
    let format = format.ok_or_else(|| bad("no `format` line".into()))?;
    let n = count.ok_or_else(|| bad("no `element vertex` line".into()))?;
    let col = |name: &str| props.iter().position(|p| p == name);
    let (x, y, z) = match (col("x"), col("y"), col("z")) {
        (Some(x), Some(y), Some(z)) => (x, y, z),
        _ => return Err(bad("expected properties x, y, z".into())),
    };
    let vel = match (col("vx"), col("vy"), col("vz")) {
        (Some(a), Some(b), Some(c)) => Some((a, b, c)),
        _ => None,
    };
    let np = props.len();
    // the declared count must fit the file before anything is allocated for it
    let floats = n
        .checked_mul(np)
        .filter(|&f| match format {
            PlyFormat::BinaryLittleEndian => f.checked_mul(4) == Some(body.len()),
            // an ASCII number takes at least two bytes with its separator
            PlyFormat::Ascii => f <= body.len().div_ceil(2),
        })
        .ok_or_else(|| {
            bad(format!(
                "expected {n} vertices × {np} floats, which do not fit the {} bytes after the \
                 header",
                body.len()
            ))
        })?;
    let values: Vec<f32> = match format {
        PlyFormat::Ascii => {
            let text =
                std::str::from_utf8(body).map_err(|_| bad("ASCII body is not UTF-8".into()))?;
            let v: Result<Vec<f32>, _> = text.split_whitespace().map(str::parse::<f32>).collect();
            v.map_err(|e| bad(format!("bad number in the body: {e}")))?
        }
        PlyFormat::BinaryLittleEndian => body
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
    };
    if values.len() != floats {
        return Err(bad(format!(
            "expected {n} vertices × {np} floats, found {} floats",
            values.len()
        )));
    }
    let positions = values
        .chunks_exact(np)
        .map(|r| [r[x], r[y], r[z]])
        .collect();
    let velocities = vel.map(|(a, b, c)| {
        values
            .chunks_exact(np)
            .map(|r| [r[a], r[b], r[c]])
            .collect()
    });
    Ok(PlyData {
        positions,
        velocities,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud(n: usize) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
        let p = (0..n)
            .map(|i| {
                let t = i as f32;
                [t * 0.1 + 1e-7, -t / 3.0, 1.0e6 + t]
            })
            .collect();
        let v = (0..n)
            .map(|i| [i as f32, f32::MIN_POSITIVE, -0.0])
            .collect();
        (p, v)
    }

    #[test]
    fn both_formats_round_trip_bit_exactly() {
        let dir = tempfile::tempdir().unwrap();
        let (p, v) = cloud(57);
        for format in [PlyFormat::Ascii, PlyFormat::BinaryLittleEndian] {
            let path = dir.path().join(format!("{format:?}/f0001.ply"));
            write_ply(&path, &p, Some(&v), format).unwrap();
            let back = read_ply(&path).unwrap();
            let bits = |a: &[[f32; 3]]| a.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&back.positions), bits(&p));
            assert_eq!(bits(back.velocities.as_ref().unwrap()), bits(&v));
            write_ply(&path, &p[..3], None, format).unwrap();
            let back = read_ply(&path).unwrap();
            assert_eq!(back.positions, p[..3]);
            assert!(back.velocities.is_none());
        }
    }

    #[test]
    fn header_and_sizes_follow_the_ply_spec() {
        let (p, v) = cloud(10);
        let bytes = encode_ply(&p, Some(&v), PlyFormat::BinaryLittleEndian).unwrap();
        let text = String::from_utf8_lossy(&bytes);
        assert!(text.starts_with("ply\nformat binary_little_endian 1.0\n"));
        assert!(text.contains("element vertex 10\n"));
        let header_len = text.find("end_header\n").unwrap() + "end_header\n".len();
        assert_eq!(bytes.len() - header_len, 10 * 6 * 4);
        // first float after the header is x of particle 0, little-endian
        assert_eq!(
            f32::from_le_bytes(bytes[header_len..header_len + 4].try_into().unwrap()),
            p[0][0]
        );
        let ascii =
            String::from_utf8(encode_ply(&p[..2], None, PlyFormat::Ascii).unwrap()).unwrap();
        assert!(
            ascii.ends_with("end_header\n0.0000001 -0 1000000\n0.1000001 -0.33333334 1000001\n"),
            "{ascii}"
        );
    }

    #[test]
    fn errors_are_clear() {
        let (p, v) = cloud(4);
        assert!(matches!(
            encode_ply(&p, Some(&v[..3]), PlyFormat::Ascii),
            Err(PlyError::Mismatch {
                positions: 4,
                velocities: 3
            })
        ));
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.ply");
        let mut bytes = encode_ply(&p, None, PlyFormat::BinaryLittleEndian).unwrap();
        bytes.truncate(bytes.len() - 4);
        std::fs::write(&path, &bytes).unwrap();
        let err = read_ply(&path).unwrap_err().to_string();
        assert!(
            err.contains("bad.ply") && err.contains("4 vertices"),
            "{err}"
        );
        assert!(read_ply(&dir.path().join("missing.ply")).is_err());
    }

    /// A header may declare any count: one that overflows or outgrows the file is an error
    /// before anything is allocated for it.
    #[test]
    fn huge_vertex_counts_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        for (format, n) in [
            ("binary_little_endian", "18446744073709551615"),
            ("binary_little_endian", "6148914691236517206"),
            ("ascii", "18446744073709551615"),
            ("ascii", "1000000"),
        ] {
            let path = dir.path().join("huge.ply");
            let text = format!(
                "ply\nformat {format} 1.0\nelement vertex {n}\nproperty float x\n\
                 property float y\nproperty float z\nend_header\n0 0 0\n"
            );
            std::fs::write(&path, text).unwrap();
            let err = read_ply(&path).unwrap_err().to_string();
            assert!(
                err.contains("huge.ply") && err.contains("vertices"),
                "{err}"
            );
        }
    }
}
