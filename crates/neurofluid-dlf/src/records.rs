//! DLF's training records `*.msgpack.zst` (docs/spec/dlf.md §6.2): zstd of a msgpack list with one
//! map per frame; arrays are msgpack-numpy maps {nd, type, kind, shape, data}.

use std::io::{Cursor, Read};
use std::path::{Path, PathBuf};

use rmpv::Value;

/// Why a record file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// I/O failed.
    #[error("{path}: {error}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error (shown in the message, not repeated as a source).
        error: std::io::Error,
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
    let check = |size: usize| -> Result<(), String> {
        if neurofluid_core::limits::array_bytes(&shape, size)? != data.len() as u64 {
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

/// The number of values the first msgpack value of `bytes` holds (itself, its elements, map
/// keys and values, recursively), counted without building them: a small file of nested empty
/// lists would otherwise make millions of values. Errors where the data ends early.
fn msgpack_values(bytes: &[u8]) -> Result<usize, String> {
    let mut at = 0usize;
    let mut pending: u64 = 1;
    let mut count = 0usize;
    let take = |at: &mut usize, n: usize| -> Result<u64, String> {
        let end = at
            .checked_add(n)
            .filter(|&e| e <= bytes.len())
            .ok_or_else(|| format!("the data ends inside a value at byte {at}"))?;
        let v = bytes[*at..end]
            .iter()
            .fold(0u64, |a, &b| (a << 8) | u64::from(b));
        *at = end;
        Ok(v)
    };
    while pending > 0 {
        pending -= 1;
        count += 1;
        let m = take(&mut at, 1)? as u8;
        // (payload bytes, elements), where a length prefix of `n` bytes precedes the payload
        let (skip, elements): (u64, u64) = match m {
            0x00..=0x7f | 0xe0..=0xff | 0xc0 | 0xc2 | 0xc3 => (0, 0),
            0x80..=0x8f => (0, 2 * u64::from(m & 0x0f)),
            0x90..=0x9f => (0, u64::from(m & 0x0f)),
            0xa0..=0xbf => (u64::from(m & 0x1f), 0),
            0xc4 | 0xd9 => (take(&mut at, 1)?, 0),
            0xc5 | 0xda => (take(&mut at, 2)?, 0),
            0xc6 | 0xdb => (take(&mut at, 4)?, 0),
            0xc7 => (take(&mut at, 1)? + 1, 0),
            0xc8 => (take(&mut at, 2)? + 1, 0),
            0xc9 => (take(&mut at, 4)? + 1, 0),
            0xca => (4, 0),
            0xcb => (8, 0),
            0xcc | 0xd0 => (1, 0),
            0xcd | 0xd1 => (2, 0),
            0xce | 0xd2 => (4, 0),
            0xcf | 0xd3 => (8, 0),
            0xd4..=0xd8 => (1 + (1u64 << (m - 0xd4)), 0),
            0xdc => (0, take(&mut at, 2)?),
            0xdd => (0, take(&mut at, 4)?),
            0xde => (0, 2 * take(&mut at, 2)?),
            0xdf => (0, 2 * take(&mut at, 4)?),
            0xc1 => return Err(format!("reserved marker 0xc1 at byte {}", at - 1)),
        };
        let skip = usize::try_from(skip).map_err(|_| "a length too large".to_string())?;
        at = at
            .checked_add(skip)
            .filter(|&e| e <= bytes.len())
            .ok_or_else(|| format!("the data ends inside a value at byte {at}"))?;
        // every element takes at least one byte: more than the bytes left cannot be there
        pending += elements;
        if pending > (bytes.len() - at) as u64 {
            return Err(format!(
                "{pending} values announced by byte {at}, with only {} bytes left",
                bytes.len() - at
            ));
        }
    }
    Ok(count)
}

/// Decodes the (decompressed) msgpack bytes of a record.
pub fn decode_frames(bytes: &[u8], path: &Path) -> Result<Vec<RecordFrame>, RecordError> {
    let fmt = |what: String| RecordError::Format {
        path: path.to_path_buf(),
        what,
    };
    let values = msgpack_values(bytes).map_err(|e| fmt(format!("not msgpack: {e}")))?;
    neurofluid_core::limits::check_decoded(
        &format!("{values} msgpack values"),
        (values as u64).saturating_mul(std::mem::size_of::<Value>() as u64),
    )
    .map_err(fmt)?;
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
    let io = |error| RecordError::Io {
        path: path.to_path_buf(),
        error,
    };
    let compressed = neurofluid_core::input_file::read(path).map_err(io)?;
    let limit = neurofluid_core::limits::max_decoded_bytes().min(
        (compressed.len() as u64)
            .saturating_mul(ZSTD_MAX_RATIO)
            .max(ZSTD_RATIO_FREE),
    );
    let bytes = decompress(&compressed, limit).map_err(|e| RecordError::Format {
        path: path.to_path_buf(),
        what: format!("not zstd data: {e}"),
    })?;
    if bytes.len() as u64 > limit {
        neurofluid_core::limits::check_decoded("the decompressed record", bytes.len() as u64)
            .and_then(|()| {
                Err(format!(
                    "decompresses to more than {limit} bytes, over {ZSTD_MAX_RATIO} times its {} \
                     compressed bytes (a compression bomb?): a DLF record of particle data \
                     compresses far less",
                    compressed.len()
                ))
            })
            .map_err(|what| RecordError::Format {
                path: path.to_path_buf(),
                what,
            })?;
    }
    decode_frames(&bytes, path)
}

/// The most a record may expand: particle data (floats) compresses a few times at most.
const ZSTD_MAX_RATIO: u64 = 256;
/// Records up to this size may expand further (small, highly regular files).
const ZSTD_RATIO_FREE: u64 = 64 << 20;

/// Every zstd frame of `compressed`, decoded and concatenated, stopping once past `limit`
/// bytes (the caller reports the excess).
fn decompress(compressed: &[u8], limit: u64) -> std::io::Result<Vec<u8>> {
    let mut input = compressed;
    let mut bytes = Vec::new();
    while !input.is_empty() && (bytes.len() as u64) <= limit {
        let frame =
            ruzstd::decoding::StreamingDecoder::new(&mut input).map_err(std::io::Error::other)?;
        let room = limit + 1 - bytes.len() as u64;
        frame.take(room).read_to_end(&mut bytes)?;
    }
    Ok(bytes)
}

/// Writes frames as a DLF record (same encoding; zstd at its fastest level), atomically.
pub fn write_record(path: &Path, frames: &[RecordFrame]) -> Result<(), RecordError> {
    let io = |error| RecordError::Io {
        path: path.to_path_buf(),
        error,
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

    /// A zstd frame of `blocks` RLE blocks, each 128 KiB of one byte: 4 bytes on disk per
    /// 128 KiB decoded.
    pub(crate) fn zstd_rle_bomb(blocks: usize, byte: u8) -> Vec<u8> {
        // magic, a frame header with a 128 KiB window and no content size
        let mut b = vec![0x28, 0xb5, 0x2f, 0xfd, 0x00, 7 << 3];
        for i in 0..blocks {
            let last = u32::from(i + 1 == blocks);
            let header = last | (1 << 1) | (131_072 << 3);
            b.extend(&header.to_le_bytes()[..3]);
            b.push(byte);
        }
        b
    }

    /// Compression bombs: 70 KB of zstd that would decode to 2.2 GiB, refused at the ratio cap;
    /// the value counts of the msgpack inside checked before anything is built.
    #[test]
    fn bombs_are_refused_with_the_file_and_the_limit() {
        let dir = std::env::temp_dir().join(format!("nf_dlf_bomb_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("bomb.msgpack.zst");
        let bomb = zstd_rle_bomb(17_600, 0x90);
        assert!(bomb.len() < 80_000);
        std::fs::write(&path, &bomb).unwrap();
        let err = read_record(&path).unwrap_err().to_string();
        assert!(
            err.contains("bomb.msgpack.zst") && err.contains("compression bomb"),
            "{err}"
        );
        // under the ratio: a list announcing 2³² - 1 frames, or nested lists
        let mut lying = vec![0xdd, 0xff, 0xff, 0xff, 0xff];
        lying.extend([0x90; 100]);
        let err = decode_frames(&lying, &path).unwrap_err().to_string();
        assert!(err.contains("announced"), "{err}");
        let nested = [0x91u8; 1 << 20];
        let err = decode_frames(&nested, &path).unwrap_err().to_string();
        assert!(err.contains("bomb.msgpack.zst"), "{err}");
        // a shape whose size overflows
        let bad = Value::Array(vec![Value::Map(vec![
            (Value::from("pos"), {
                let mut v = encode_nd_f32(&[1.0, 2.0, 3.0], &[1, 3]);
                if let Value::Map(m) = &mut v {
                    for (k, x) in m.iter_mut() {
                        if key_is(k, "shape") {
                            *x = Value::Array(vec![Value::from(1u64 << 62), Value::from(4)]);
                        }
                    }
                }
                v
            }),
            (Value::from("vel"), encode_nd_f32(&[1.0, 2.0, 3.0], &[1, 3])),
        ])]);
        let mut bytes = Vec::new();
        rmpv::encode::write_value(&mut bytes, &bad).unwrap();
        let err = decode_frames(&bytes, &path).unwrap_err().to_string();
        assert!(err.contains("overflows"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
