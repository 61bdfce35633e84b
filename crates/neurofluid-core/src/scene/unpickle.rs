//! Reads the released scenes' `box.pt` directly: a joblib file (an uncompressed pickle whose
//! numpy arrays are `NumpyArrayWrapper`s followed by their raw bytes, with the alignment padding
//! of joblib ≥ 1.2) or a plain pickle of numpy arrays (`_reconstruct` + state, as
//! [`super::box_pickle`] writes). Only what such files hold is understood: dicts, lists, tuples,
//! strings, bytes, numbers, and float32/float64 little-endian arrays; anything else is rejected
//! with the byte offset and what was found.

use std::collections::BTreeMap;

/// A value on the unpickler's stack.
#[derive(Debug, Clone, PartialEq)]
enum Value {
    None,
    Bool(bool),
    Int(i64),
    Float(f64),
    Str(String),
    Bytes(Vec<u8>),
    Tuple(Vec<Value>),
    List(Vec<Value>),
    Dict(Vec<(Value, Value)>),
    /// `module.name`.
    Global(String),
    /// `callable(*args)`, and the state a BUILD gave it.
    Object {
        callable: Box<Value>,
        args: Vec<Value>,
        state: Option<Box<Value>>,
    },
    /// A decoded numeric array.
    Array {
        shape: Vec<usize>,
        data: Vec<f64>,
    },
    Mark,
}

/// A decoded array: its shape and values.
#[derive(Debug, Clone, PartialEq)]
pub struct PickledArray {
    /// The shape.
    pub shape: Vec<usize>,
    /// The values, row-major.
    pub data: Vec<f64>,
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let end = self
            .at
            .checked_add(n)
            .filter(|&e| e <= self.bytes.len())
            .ok_or_else(|| format!("the file ends inside a value at byte {}", self.at))?;
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }

    fn u8(&mut self) -> Result<u8, String> {
        Ok(self.take(1)?[0])
    }

    fn u32(&mut self) -> Result<usize, String> {
        Ok(u32::from_le_bytes(self.take(4)?.try_into().expect("4 bytes")) as usize)
    }

    fn u64(&mut self) -> Result<usize, String> {
        let v = u64::from_le_bytes(self.take(8)?.try_into().expect("8 bytes"));
        usize::try_from(v).map_err(|_| format!("length {v} too large at byte {}", self.at))
    }

    fn line(&mut self) -> Result<String, String> {
        let rest = &self.bytes[self.at..];
        let n = rest
            .iter()
            .position(|&b| b == b'\n')
            .ok_or_else(|| format!("unterminated line at byte {}", self.at))?;
        let s = String::from_utf8_lossy(&rest[..n]).into_owned();
        self.at += n + 1;
        Ok(s)
    }

    fn utf8(&mut self, n: usize) -> Result<String, String> {
        let at = self.at;
        String::from_utf8(self.take(n)?.to_vec()).map_err(|_| format!("invalid UTF-8 at byte {at}"))
    }
}

fn global_name(v: &Value) -> Option<&str> {
    match v {
        Value::Global(name) => Some(name),
        _ => None,
    }
}

fn dict_get<'v>(d: &'v [(Value, Value)], key: &str) -> Option<&'v Value> {
    d.iter()
        .find(|(k, _)| matches!(k, Value::Str(s) if s == key))
        .map(|(_, v)| v)
}

/// The item size of a numpy dtype object (`dtype('f4', False, True)` with its state), little
/// endian float32 or float64 only.
fn float_dtype(v: &Value) -> Result<usize, String> {
    let Value::Object {
        callable,
        args,
        state,
    } = v
    else {
        return Err(format!("expected a numpy dtype, found {v:?}"));
    };
    if !global_name(callable).is_some_and(|n| n.ends_with(".dtype")) {
        return Err(format!("expected a numpy dtype, found {callable:?}"));
    }
    let size = match args.first() {
        Some(Value::Str(s)) if s == "f4" => 4,
        Some(Value::Str(s)) if s == "f8" => 8,
        other => {
            return Err(format!(
                "expected a float32 or float64 array, found dtype {other:?}"
            ));
        }
    };
    if let Some(state) = state
        && let Value::Tuple(t) = state.as_ref()
        && let Some(Value::Str(order)) = t.get(1)
        && order == ">"
    {
        return Err("big-endian arrays are not supported".into());
    }
    Ok(size)
}

fn shape_of(v: &Value) -> Result<Vec<usize>, String> {
    match v {
        Value::Tuple(t) => t
            .iter()
            .map(|d| match d {
                Value::Int(n) if *n >= 0 => Ok(*n as usize),
                other => Err(format!("expected an array dimension, found {other:?}")),
            })
            .collect(),
        other => Err(format!("expected an array shape, found {other:?}")),
    }
}

fn decode_floats(raw: &[u8], size: usize) -> Vec<f64> {
    match size {
        4 => raw
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")) as f64)
            .collect(),
        _ => raw
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect(),
    }
}

fn element_count(shape: &[usize], size: usize, available: usize) -> Result<usize, String> {
    let n = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .filter(|n| n.checked_mul(size).is_some_and(|b| b <= available))
        .ok_or_else(|| format!("array of shape {shape:?} is larger than the file"))?;
    Ok(n)
}

/// A joblib `NumpyArrayWrapper` has been built: its raw bytes follow in the stream.
fn joblib_array(r: &mut Reader<'_>, state: &Value) -> Result<Value, String> {
    let Value::Dict(d) = state else {
        return Err("a joblib array without its description".into());
    };
    let shape = shape_of(dict_get(d, "shape").ok_or("a joblib array without `shape`")?)?;
    let size = float_dtype(dict_get(d, "dtype").ok_or("a joblib array without `dtype`")?)?;
    if let Some(Value::Str(order)) = dict_get(d, "order")
        && order != "C"
    {
        return Err(format!(
            "only C-ordered arrays are supported, found order {order}"
        ));
    }
    if dict_get(d, "numpy_array_alignment_bytes").is_some() {
        let pad = r.u8()? as usize;
        r.take(pad)?;
    }
    let n = element_count(&shape, size, r.bytes.len() - r.at)?;
    let raw = r.take(n * size)?;
    Ok(Value::Array {
        shape,
        data: decode_floats(raw, size),
    })
}

/// `numpy.core.multiarray._reconstruct(ndarray, …)` with BUILD state
/// `(version, shape, dtype, is_fortran, raw bytes)`.
fn numpy_array(state: &Value) -> Result<Value, String> {
    let Value::Tuple(t) = state else {
        return Err(format!("expected a numpy array state, found {state:?}"));
    };
    let [_, shape, dtype, fortran, raw] = t.as_slice() else {
        return Err(format!(
            "expected a 5-tuple numpy array state, found {} items",
            t.len()
        ));
    };
    if fortran == &Value::Bool(true) {
        return Err("Fortran-ordered arrays are not supported".into());
    }
    let shape = shape_of(shape)?;
    let size = float_dtype(dtype)?;
    let Value::Bytes(raw) = raw else {
        return Err("expected the array's raw bytes".into());
    };
    let n = element_count(&shape, size, raw.len())?;
    Ok(Value::Array {
        shape,
        data: decode_floats(&raw[..n * size], size),
    })
}

fn pop(stack: &mut Vec<Value>, at: usize) -> Result<Value, String> {
    stack
        .pop()
        .ok_or_else(|| format!("stack underflow at byte {at}"))
}

fn pop_mark(stack: &mut Vec<Value>, at: usize) -> Result<Vec<Value>, String> {
    let m = stack
        .iter()
        .rposition(|v| matches!(v, Value::Mark))
        .ok_or_else(|| format!("no MARK before byte {at}"))?;
    let items = stack.split_off(m + 1);
    stack.pop();
    Ok(items)
}

fn unpickle(bytes: &[u8]) -> Result<Value, String> {
    if bytes.first() != Some(&0x80) {
        return Err(
            "not an uncompressed pickle (a compressed joblib file? save it with compress=0)".into(),
        );
    }
    let mut r = Reader { bytes, at: 0 };
    let mut stack: Vec<Value> = Vec::new();
    let mut memo: BTreeMap<usize, Value> = BTreeMap::new();
    loop {
        let at = r.at;
        let op = r.u8()?;
        match op {
            0x80 => {
                r.u8()?;
            }
            0x95 => {
                r.u64()?;
            }
            b'.' => return pop(&mut stack, at),
            b'(' => stack.push(Value::Mark),
            b'}' => stack.push(Value::Dict(Vec::new())),
            b']' => stack.push(Value::List(Vec::new())),
            b')' => stack.push(Value::Tuple(Vec::new())),
            b'N' => stack.push(Value::None),
            0x88 => stack.push(Value::Bool(true)),
            0x89 => stack.push(Value::Bool(false)),
            b'K' => stack.push(Value::Int(r.u8()? as i64)),
            b'M' => {
                let v = u16::from_le_bytes(r.take(2)?.try_into().expect("2 bytes"));
                stack.push(Value::Int(v as i64));
            }
            b'J' => {
                let v = i32::from_le_bytes(r.take(4)?.try_into().expect("4 bytes"));
                stack.push(Value::Int(v as i64));
            }
            0x8a => {
                let n = r.u8()? as usize;
                let b = r.take(n)?;
                if n > 8 {
                    return Err(format!("integer of {n} bytes at byte {at}"));
                }
                let mut v: i64 = 0;
                for (i, &x) in b.iter().enumerate() {
                    v |= (x as i64) << (8 * i);
                }
                if n > 0 && n < 8 && b[n - 1] & 0x80 != 0 {
                    v -= 1i64 << (8 * n);
                }
                stack.push(Value::Int(v));
            }
            b'G' => {
                let v = f64::from_be_bytes(r.take(8)?.try_into().expect("8 bytes"));
                stack.push(Value::Float(v));
            }
            0x8c => {
                let n = r.u8()? as usize;
                stack.push(Value::Str(r.utf8(n)?));
            }
            b'X' => {
                let n = r.u32()?;
                stack.push(Value::Str(r.utf8(n)?));
            }
            0x8d => {
                let n = r.u64()?;
                stack.push(Value::Str(r.utf8(n)?));
            }
            b'C' => {
                let n = r.u8()? as usize;
                stack.push(Value::Bytes(r.take(n)?.to_vec()));
            }
            b'B' => {
                let n = r.u32()?;
                stack.push(Value::Bytes(r.take(n)?.to_vec()));
            }
            0x8e => {
                let n = r.u64()?;
                stack.push(Value::Bytes(r.take(n)?.to_vec()));
            }
            0x94 => {
                let top = stack
                    .last()
                    .ok_or_else(|| format!("MEMOIZE on empty stack at {at}"))?;
                memo.insert(memo.len(), top.clone());
            }
            b'q' | b'r' => {
                let i = if op == b'q' {
                    r.u8()? as usize
                } else {
                    r.u32()?
                };
                let top = stack
                    .last()
                    .ok_or_else(|| format!("PUT on empty stack at {at}"))?;
                memo.insert(i, top.clone());
            }
            b'h' | b'j' => {
                let i = if op == b'h' {
                    r.u8()? as usize
                } else {
                    r.u32()?
                };
                let v = memo
                    .get(&i)
                    .ok_or_else(|| format!("unknown memo entry {i} at byte {at}"))?;
                stack.push(v.clone());
            }
            b'c' => {
                let module = r.line()?;
                let name = r.line()?;
                stack.push(Value::Global(format!("{module}.{name}")));
            }
            0x93 => {
                let name = pop(&mut stack, at)?;
                let module = pop(&mut stack, at)?;
                match (module, name) {
                    (Value::Str(m), Value::Str(n)) => stack.push(Value::Global(format!("{m}.{n}"))),
                    _ => return Err(format!("STACK_GLOBAL without names at byte {at}")),
                }
            }
            b't' => {
                let items = pop_mark(&mut stack, at)?;
                stack.push(Value::Tuple(items));
            }
            0x85..=0x87 => {
                let n = (op - 0x84) as usize;
                if stack.len() < n {
                    return Err(format!("stack underflow at byte {at}"));
                }
                let items = stack.split_off(stack.len() - n);
                stack.push(Value::Tuple(items));
            }
            b'R' | 0x81 => {
                let args = pop(&mut stack, at)?;
                let callable = pop(&mut stack, at)?;
                let Value::Tuple(args) = args else {
                    return Err(format!("call without an argument tuple at byte {at}"));
                };
                // protocol 2 writes bytes as `_codecs.encode(latin-1 text, 'latin1')`
                if global_name(&callable) == Some("_codecs.encode")
                    && let [Value::Str(text), Value::Str(codec)] = args.as_slice()
                    && matches!(codec.as_str(), "latin1" | "latin-1")
                {
                    let bytes = text
                        .chars()
                        .map(|c| u8::try_from(c as u32))
                        .collect::<Result<Vec<u8>, _>>()
                        .map_err(|_| format!("not latin-1 text at byte {at}"))?;
                    stack.push(Value::Bytes(bytes));
                    continue;
                }
                stack.push(Value::Object {
                    callable: Box::new(callable),
                    args,
                    state: None,
                });
            }
            b'b' => {
                let state = pop(&mut stack, at)?;
                let obj = pop(&mut stack, at)?;
                let built = match obj {
                    Value::Object { callable, .. }
                        if global_name(&callable)
                            .is_some_and(|n| n.ends_with("NumpyArrayWrapper")) =>
                    {
                        joblib_array(&mut r, &state)?
                    }
                    Value::Object { callable, .. }
                        if global_name(&callable).is_some_and(|n| n.ends_with("._reconstruct")) =>
                    {
                        numpy_array(&state)?
                    }
                    Value::Object { callable, args, .. } => Value::Object {
                        callable,
                        args,
                        state: Some(Box::new(state)),
                    },
                    other => return Err(format!("BUILD of {other:?} at byte {at}")),
                };
                stack.push(built);
            }
            b's' => {
                let v = pop(&mut stack, at)?;
                let k = pop(&mut stack, at)?;
                match stack.last_mut() {
                    Some(Value::Dict(d)) => d.push((k, v)),
                    _ => return Err(format!("SETITEM outside a dict at byte {at}")),
                }
            }
            b'u' => {
                let items = pop_mark(&mut stack, at)?;
                if items.len() % 2 != 0 {
                    return Err(format!("odd SETITEMS at byte {at}"));
                }
                let Some(Value::Dict(d)) = stack.last_mut() else {
                    return Err(format!("SETITEMS outside a dict at byte {at}"));
                };
                let mut it = items.into_iter();
                while let (Some(k), Some(v)) = (it.next(), it.next()) {
                    d.push((k, v));
                }
            }
            b'a' => {
                let v = pop(&mut stack, at)?;
                match stack.last_mut() {
                    Some(Value::List(l)) => l.push(v),
                    _ => return Err(format!("APPEND outside a list at byte {at}")),
                }
            }
            b'e' => {
                let items = pop_mark(&mut stack, at)?;
                match stack.last_mut() {
                    Some(Value::List(l)) => l.extend(items),
                    _ => return Err(format!("APPENDS outside a list at byte {at}")),
                }
            }
            other => {
                return Err(format!(
                    "unsupported pickle opcode 0x{other:02x} at byte {at}"
                ));
            }
        }
    }
}

/// The arrays of a pickled dict of float arrays, by key.
pub fn pickled_arrays(bytes: &[u8]) -> Result<BTreeMap<String, PickledArray>, String> {
    let Value::Dict(items) = unpickle(bytes)? else {
        return Err("expected a pickled dict".into());
    };
    let mut out = BTreeMap::new();
    for (k, v) in items {
        if let (Value::Str(k), Value::Array { shape, data }) = (k, v) {
            out.insert(k, PickledArray { shape, data });
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Our own writer's pickle reads back exactly.
    #[test]
    fn reads_what_box_pickle_writes() {
        let b = super::super::BoxParticles {
            points: vec![[0.5, -1.0, 2.25], [3.0, 4.0, 5.0]],
            normals: vec![[0.0, 1.0, 0.0], [0.0, 0.0, -1.0]],
        };
        let arrays = pickled_arrays(&super::super::box_pickle(&b)).unwrap();
        assert_eq!(arrays["box"].shape, [2, 3]);
        assert_eq!(arrays["box"].data, [0.5, -1.0, 2.25, 3.0, 4.0, 5.0]);
        assert_eq!(arrays["box_normals"].data, [0.0, 1.0, 0.0, 0.0, 0.0, -1.0]);
    }

    #[test]
    fn truncated_and_foreign_files_are_errors() {
        let b = super::super::BoxParticles {
            points: vec![[0.5, -1.0, 2.25]],
            normals: vec![[0.0, 1.0, 0.0]],
        };
        let bytes = super::super::box_pickle(&b);
        for cut in 0..bytes.len() - 1 {
            assert!(pickled_arrays(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        let err = pickled_arrays(b"x\x9c compressed").unwrap_err();
        assert!(err.contains("compress"), "{err}");
        let err = pickled_arrays(b"\x80\x04\x95\x00\x00\x00\x00\x00\x00\x00\x00d.").unwrap_err();
        assert!(err.contains("opcode 0x64"), "{err}");
    }
}
