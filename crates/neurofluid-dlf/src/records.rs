//! DLF's training records `*.msgpack.zst` (spec/dlf.md §6.2): zstd of a msgpack list with one
//! map per frame; arrays are msgpack-numpy maps {nd, type, kind, shape, data}.

use std::io::{Cursor, Read};
use std::path::{Path, PathBuf};

use rmpv::Value;

/// Why a record file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// I/O failed.
    #[error("{path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// The content is not what a DLF record holds.
    #[error("{path}: {what}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong, naming the frame and field.
        what: String,
    },
}

/// One frame of a record.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RecordFrame {
    /// Fluid positions `[N, 3]`.
    pub pos: Vec<[f32; 3]>,
    /// Fluid velocities `[N, 3]`.
    pub vel: Vec<[f32; 3]>,
    /// Particle masses `[N]`, if present.
    pub mass: Option<Vec<f32>>,
    /// Viscosity per particle `[N]`, if present.
    pub viscosity: Option<Vec<f32>>,
    /// Frame index in the simulation, if present.
    pub frame_id: Option<i64>,
    /// Scene name (`sim_0001`), if present.
    pub scene_id: Option<String>,
    /// Static boundary points (only in the first frame of a file).
    pub box_points: Option<Vec<[f32; 3]>>,
    /// Boundary normals (only in the first frame of a file).
    pub box_normals: Option<Vec<[f32; 3]>>,
}

/// A decoded msgpack-numpy array.
#[derive(Debug, Clone, PartialEq)]
enum NdArray {
    F32(Vec<f32>, Vec<usize>),
    I64(Vec<i64>, Vec<usize>),
}

fn key_is(k: &Value, name: &str) -> bool {
    match k {
        Value::String(s) => s.as_str() == Some(name),
        Value::Binary(b) => b.as_slice() == name.as_bytes(),
        _ => false,
    }
}

fn get<'a>(map: &'a [(Value, Value)], name: &str) -> Option<&'a Value> {
    map.iter().find(|(k, _)| key_is(k, name)).map(|(_, v)| v)
}

fn as_text(v: &Value) -> Option<String> {
    match v {
        Value::String(s) => s.as_str().map(str::to_string),
        Value::Binary(b) => String::from_utf8(b.clone()).ok(),
        _ => None,
    }
}

fn decode_nd(v: &Value) -> Result<NdArray, String> {
    let map = v.as_map().ok_or("expected a msgpack-numpy map")?;
    let ty = get(map, "type").and_then(as_text).ok_or("no `type`")?;
    let data = match get(map, "data") {
        Some(Value::Binary(b)) => b.as_slice(),
        _ => return Err("no binary `data`".into()),
    };
    let nd = matches!(get(map, "nd"), Some(Value::Boolean(true)));
    let shape: Vec<usize> = if nd {
        get(map, "shape")
            .and_then(Value::as_array)
            .ok_or("no `shape`")?
            .iter()
            .map(|d| d.as_u64().map(|x| x as usize).ok_or("non-integer shape"))
            .collect::<Result<_, _>>()?
    } else {
        vec![]
    };
    let count: usize = shape.iter().product();
    let check = |size: usize| -> Result<(), String> {
        if data.len() != count * size {
            return Err(format!(
                "{} data bytes for shape {shape:?} of {ty}",
                data.len()
            ));
        }
        Ok(())
    };
    let le4 = |c: &[u8]| [c[0], c[1], c[2], c[3]];
    let le8 = |c: &[u8]| [c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]];
    match ty.as_str() {
        "<f4" => {
            check(4)?;
            Ok(NdArray::F32(
                data.chunks_exact(4)
                    .map(|c| f32::from_le_bytes(le4(c)))
                    .collect(),
                shape,
            ))
        }
        "<f8" => {
            check(8)?;
            Ok(NdArray::F32(
                data.chunks_exact(8)
                    .map(|c| f64::from_le_bytes(le8(c)) as f32)
                    .collect(),
                shape,
            ))
        }
        "<i8" => {
            check(8)?;
            Ok(NdArray::I64(
                data.chunks_exact(8)
                    .map(|c| i64::from_le_bytes(le8(c)))
                    .collect(),
                shape,
            ))
        }
        "<i4" => {
            check(4)?;
            Ok(NdArray::I64(
                data.chunks_exact(4)
                    .map(|c| i32::from_le_bytes(le4(c)) as i64)
                    .collect(),
                shape,
            ))
        }
        other => Err(format!("unsupported dtype `{other}`")),
    }
}

fn encode_nd_f32(data: &[f32], shape: &[usize]) -> Value {
    let bytes: Vec<u8> = data.iter().flat_map(|v| v.to_le_bytes()).collect();
    Value::Map(vec![
        (Value::Binary(b"nd".to_vec()), Value::Boolean(true)),
        (Value::Binary(b"type".to_vec()), Value::String("<f4".into())),
        (Value::Binary(b"kind".to_vec()), Value::Binary(vec![])),
        (
            Value::Binary(b"shape".to_vec()),
            Value::Array(shape.iter().map(|&d| Value::from(d as u64)).collect()),
        ),
        (Value::Binary(b"data".to_vec()), Value::Binary(bytes)),
    ])
}

fn encode_scalar_i64(v: i64) -> Value {
    Value::Map(vec![
        (Value::Binary(b"nd".to_vec()), Value::Boolean(false)),
        (Value::Binary(b"type".to_vec()), Value::String("<i8".into())),
        (Value::Binary(b"kind".to_vec()), Value::Binary(vec![])),
        (
            Value::Binary(b"data".to_vec()),
            Value::Binary(v.to_le_bytes().to_vec()),
        ),
    ])
}

fn points(data: Vec<f32>, shape: &[usize]) -> Result<Vec<[f32; 3]>, String> {
    if shape.len() != 2 || shape[1] != 3 {
        return Err(format!("shape {shape:?}, expected [N, 3]"));
    }
    if data.iter().any(|v| !v.is_finite()) {
        return Err("holds NaN or infinite values".into());
    }
    Ok(data.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// Decodes the (decompressed) msgpack bytes of a record.
pub fn decode_frames(bytes: &[u8], path: &Path) -> Result<Vec<RecordFrame>, RecordError> {
    let fmt = |what: String| RecordError::Format {
        path: path.to_path_buf(),
        what,
    };
    let value = rmpv::decode::read_value(&mut Cursor::new(bytes))
        .map_err(|e| fmt(format!("not msgpack: {e}")))?;
    let list = value
        .as_array()
        .ok_or_else(|| fmt("expected a msgpack list of frames".into()))?;
    let mut frames = Vec::with_capacity(list.len());
    for (f, v) in list.iter().enumerate() {
        let map = v
            .as_map()
            .ok_or_else(|| fmt(format!("frame {f}: expected a map")))?;
        let field = |name: &str| -> Result<Option<NdArray>, RecordError> {
            get(map, name)
                .map(decode_nd)
                .transpose()
                .map_err(|e| fmt(format!("frame {f}: field `{name}`: {e}")))
        };
        let pts = |name: &str, required: bool| -> Result<Option<Vec<[f32; 3]>>, RecordError> {
            match field(name)? {
                Some(NdArray::F32(d, s)) => points(d, &s)
                    .map(Some)
                    .map_err(|e| fmt(format!("frame {f}: field `{name}`: {e}"))),
                Some(NdArray::I64(..)) => Err(fmt(format!(
                    "frame {f}: field `{name}`: integer array, expected float"
                ))),
                None if required => Err(fmt(format!("frame {f}: no field `{name}`"))),
                None => Ok(None),
            }
        };
        let vec1 = |name: &str| -> Result<Option<Vec<f32>>, RecordError> {
            match field(name)? {
                Some(NdArray::F32(d, _)) => Ok(Some(d)),
                Some(NdArray::I64(d, _)) => Ok(Some(d.into_iter().map(|x| x as f32).collect())),
                None => Ok(None),
            }
        };
        let pos = pts("pos", true)?.unwrap_or_default();
        let vel = pts("vel", true)?.unwrap_or_default();
        if pos.len() != vel.len() {
            return Err(fmt(format!(
                "frame {f}: `vel` has {} rows, `pos` {}",
                vel.len(),
                pos.len()
            )));
        }
        let frame_id = match field("frame_id")? {
            Some(NdArray::I64(d, _)) => d.first().copied(),
            Some(NdArray::F32(d, _)) => d.first().map(|&x| x as i64),
            None => match get(map, "frame_id") {
                Some(v) => v.as_i64(),
                None => None,
            },
        };
        frames.push(RecordFrame {
            pos,
            vel,
            mass: vec1("m")?,
            viscosity: vec1("viscosity")?,
            frame_id,
            scene_id: get(map, "scene_id").and_then(as_text),
            box_points: pts("box", false)?,
            box_normals: pts("box_normals", false)?,
        });
    }
    Ok(frames)
}

/// Reads a `*.msgpack.zst` record.
pub fn read_record(path: &Path) -> Result<Vec<RecordFrame>, RecordError> {
    let io = |source| RecordError::Io {
        path: path.to_path_buf(),
        source,
    };
    let compressed = std::fs::read(path).map_err(io)?;
    let bytes = decompress(&compressed).map_err(|e| RecordError::Format {
        path: path.to_path_buf(),
        what: format!("not zstd data: {e}"),
    })?;
    decode_frames(&bytes, path)
}

/// Every zstd frame of `compressed`, decoded and concatenated.
fn decompress(compressed: &[u8]) -> std::io::Result<Vec<u8>> {
    let mut input = compressed;
    let mut bytes = Vec::new();
    while !input.is_empty() {
        let mut frame =
            ruzstd::decoding::StreamingDecoder::new(&mut input).map_err(std::io::Error::other)?;
        frame.read_to_end(&mut bytes)?;
    }
    Ok(bytes)
}

/// Writes frames as a DLF record (same encoding; zstd at its fastest level), atomically.
pub fn write_record(path: &Path, frames: &[RecordFrame]) -> Result<(), RecordError> {
    let io = |source| RecordError::Io {
        path: path.to_path_buf(),
        source,
    };
    let flat = |p: &[[f32; 3]]| -> Vec<f32> { p.iter().flatten().copied().collect() };
    let list: Vec<Value> = frames
        .iter()
        .map(|fr| {
            let mut m = vec![
                (
                    Value::from("pos"),
                    encode_nd_f32(&flat(&fr.pos), &[fr.pos.len(), 3]),
                ),
                (
                    Value::from("vel"),
                    encode_nd_f32(&flat(&fr.vel), &[fr.vel.len(), 3]),
                ),
            ];
            if let Some(x) = &fr.mass {
                m.push((Value::from("m"), encode_nd_f32(x, &[x.len()])));
            }
            if let Some(x) = &fr.viscosity {
                m.push((Value::from("viscosity"), encode_nd_f32(x, &[x.len()])));
            }
            if let Some(id) = fr.frame_id {
                m.push((Value::from("frame_id"), encode_scalar_i64(id)));
            }
            if let Some(s) = &fr.scene_id {
                m.push((Value::from("scene_id"), Value::from(s.as_str())));
            }
            if let Some(b) = &fr.box_points {
                m.push((Value::from("box"), encode_nd_f32(&flat(b), &[b.len(), 3])));
            }
            if let Some(b) = &fr.box_normals {
                m.push((
                    Value::from("box_normals"),
                    encode_nd_f32(&flat(b), &[b.len(), 3]),
                ));
            }
            Value::Map(m)
        })
        .collect();
    let mut bytes = Vec::new();
    rmpv::encode::write_value(&mut bytes, &Value::Array(list))
        .map_err(|e| io(std::io::Error::other(e)))?;
    let compressed = ruzstd::encoding::compress_to_vec(
        bytes.as_slice(),
        ruzstd::encoding::CompressionLevel::Fastest,
    );
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(format!(".tmp{}", std::process::id()));
    let tmp = PathBuf::from(tmp);
    std::fs::write(&tmp, compressed).map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(k: usize, with_box: bool) -> RecordFrame {
        RecordFrame {
            pos: vec![[k as f32, 1.5, -2.0], [0.25, 0.5, 0.75]],
            vel: vec![[0.0, -1.0, 0.0], [1.0, 2.0, 3.0]],
            mass: Some(vec![0.125, 0.125]),
            viscosity: Some(vec![0.01, 0.01]),
            frame_id: Some(k as i64),
            scene_id: Some("sim_0001".into()),
            box_points: with_box.then(|| vec![[0.0, 0.0, 0.0]]),
            box_normals: with_box.then(|| vec![[0.0, 1.0, 0.0]]),
        }
    }

    #[test]
    fn record_roundtrip_with_msgpack_numpy_encoding() {
        let dir = std::env::temp_dir().join(format!("nf_dlf_rec_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("sim_0001_00.msgpack.zst");
        let frames = vec![frame(0, true), frame(1, false), frame(2, false)];
        write_record(&path, &frames).unwrap();
        let back = read_record(&path).unwrap();
        assert_eq!(back, frames);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A record written by the reference harness the way DLF's data scripts write one
    /// (Python `zstandard` at level 22, `msgpack_numpy`; `dlf_reference.py make-record`).
    #[test]
    fn reads_a_record_written_by_dlfs_python_tools() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../tests/data/dlf/sim_0001_00.msgpack.zst");
        let frames = read_record(&path).unwrap();
        assert_eq!(frames.len(), 3);
        let n = 40;
        for (k, fr) in frames.iter().enumerate() {
            let expect = |scale: f32, shift: f32| -> Vec<[f32; 3]> {
                (0..n)
                    .map(|p| std::array::from_fn(|c| scale * (3 * p + c) as f32 + shift))
                    .collect()
            };
            assert_eq!(fr.pos, expect(0.01, k as f32), "frame {k} pos");
            assert_eq!(fr.vel, expect(-0.5, 0.25 * k as f32), "frame {k} vel");
            assert_eq!(fr.mass.as_deref(), Some(&[0.125; 40][..]));
            assert_eq!(fr.viscosity.as_deref(), Some(&[0.01; 40][..]));
            assert_eq!(fr.frame_id, Some(k as i64));
            assert_eq!(fr.scene_id.as_deref(), Some("sim_0001"));
            let first = k == 0;
            assert_eq!(fr.box_points.is_some(), first);
            assert_eq!(fr.box_normals.is_some(), first);
        }
        assert_eq!(
            frames[0].box_normals.as_deref(),
            Some(&[[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]][..])
        );
    }

    #[test]
    fn bad_arrays_are_named() {
        // pos with a wrong shape
        let bad = Value::Array(vec![Value::Map(vec![
            (Value::from("pos"), encode_nd_f32(&[1.0, 2.0], &[1, 2])),
            (Value::from("vel"), encode_nd_f32(&[1.0, 2.0, 3.0], &[1, 3])),
        ])]);
        let mut bytes = Vec::new();
        rmpv::encode::write_value(&mut bytes, &bad).unwrap();
        let err = decode_frames(&bytes, Path::new("x.msgpack.zst"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("frame 0") && err.contains("`pos`") && err.contains("[N, 3]"),
            "{err}"
        );
        // missing vel
        let bad = Value::Array(vec![Value::Map(vec![(
            Value::from("pos"),
            encode_nd_f32(&[1.0, 2.0, 3.0], &[1, 3]),
        )])]);
        let mut bytes = Vec::new();
        rmpv::encode::write_value(&mut bytes, &bad).unwrap();
        let err = decode_frames(&bytes, Path::new("x.msgpack.zst"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("no field `vel`"), "{err}");
    }
}
