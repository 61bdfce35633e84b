//! Reads the released scenes' `box.pt` directly: a joblib file (an uncompressed pickle whose
//! numpy arrays are `NumpyArrayWrapper`s followed by their raw bytes, with the alignment padding
//! of joblib ≥ 1.2) or a plain pickle of numpy arrays (`_reconstruct` + state, as
//! [`super::box_pickle`] writes). Only what such files hold is understood: dicts, lists, tuples,
//! strings, bytes, numbers, and float32/float64 little-endian arrays; anything else is rejected
//! with the byte offset and what was found. Nothing is called, and what a pickle builds is
//! bounded as it is built ([`crate::limits`]): nesting depth, the number of values (memo copies
//! included) and their bytes.

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

/// A value on the stack with what it holds: its nesting depth, its number of values and its
/// payload bytes, so every limit is checked as the value is built, never by walking it.
#[derive(Debug, Clone)]
struct Node {
    v: Value,
    depth: usize,
    values: usize,
    bytes: u64,
}

impl Node {
    fn leaf(v: Value) -> Self {
        let bytes = match &v {
            Value::Str(s) | Value::Global(s) => s.len() as u64,
            Value::Bytes(b) => b.len() as u64,
            Value::Array { data, .. } => 8 * data.len() as u64,
            _ => 0,
        };
        Self {
            v,
            depth: 1,
            values: 1,
            bytes,
        }
    }

    /// A container of `items`' values (`make` builds it).
    fn parent(items: Vec<Node>, make: impl FnOnce(Vec<Value>) -> Value) -> Self {
        let mut n = Self {
            v: Value::None,
            depth: 1,
            values: 1,
            bytes: 0,
        };
        let values = items
            .into_iter()
            .map(|c| {
                n.absorb(&c);
                c.v
            })
            .collect();
        n.v = make(values);
        n
    }

    /// Counts `child` as held by this node.
    fn absorb(&mut self, child: &Node) {
        self.depth = self.depth.max(child.depth + 1);
        self.values = self.values.saturating_add(child.values);
        self.bytes = self.bytes.saturating_add(child.bytes);
    }
}

/// What the pickle has built so far, checked against the limits of [`crate::limits`].
#[derive(Default)]
struct Budget {
    values: usize,
    bytes: u64,
}

impl Budget {
    /// Counts `n` (a new value, or a copy of one) and checks its depth.
    fn charge(&mut self, n: &Node, at: usize) -> Result<(), String> {
        use crate::limits::{MAX_PICKLE_VALUES, check_decoded};
        check_depth(n, at)?;
        self.values = self.values.saturating_add(n.values);
        self.bytes = self.bytes.saturating_add(n.bytes);
        if self.values > MAX_PICKLE_VALUES {
            return Err(format!(
                "more than {MAX_PICKLE_VALUES} values built by byte {at} (copies of memo \
                 entries included: a memo bomb?)"
            ));
        }
        check_decoded(&format!("the values built by byte {at}"), self.bytes)
    }

    /// Counts a new container made of values already counted.
    fn charge_new(&mut self, n: &Node, at: usize) -> Result<(), String> {
        self.charge(
            &Node {
                v: Value::None,
                depth: n.depth,
                values: 1,
                bytes: 0,
            },
            at,
        )
    }
}

/// Checks that `n` nests no deeper than [`crate::limits::MAX_NESTING`].
fn check_depth(n: &Node, at: usize) -> Result<(), String> {
    use crate::limits::MAX_NESTING;
    if n.depth > MAX_NESTING {
        return Err(format!(
            "values nested deeper than {MAX_NESTING} levels at byte {at} (a box file nests 5)"
        ));
    }
    Ok(())
}

fn pop(stack: &mut Vec<Node>, at: usize) -> Result<Node, String> {
    stack
        .pop()
        .ok_or_else(|| format!("stack underflow at byte {at}"))
}

fn pop_mark(stack: &mut Vec<Node>, at: usize) -> Result<Vec<Node>, String> {
    let m = stack
        .iter()
        .rposition(|n| matches!(n.v, Value::Mark))
        .ok_or_else(|| format!("no MARK before byte {at}"))?;
    let items = stack.split_off(m + 1);
    stack.pop();
    Ok(items)
}

/// Adds `items` to the dict or list on top of the stack.
fn extend_top(stack: &mut [Node], items: Vec<Node>, at: usize, op: &str) -> Result<(), String> {
    let Some(top) = stack.last_mut() else {
        return Err(format!("{op} on an empty stack at byte {at}"));
    };
    let pairs = matches!(top.v, Value::Dict(_));
    if pairs && !items.len().is_multiple_of(2) {
        return Err(format!("odd {op} at byte {at}"));
    }
    for c in &items {
        top.absorb(c);
    }
    check_depth(top, at)?;
    let mut values = items.into_iter().map(|n| n.v);
    match &mut top.v {
        Value::Dict(d) => {
            while let (Some(k), Some(v)) = (values.next(), values.next()) {
                d.push((k, v));
            }
        }
        Value::List(l) => l.extend(values),
        _ => return Err(format!("{op} outside a dict or list at byte {at}")),
    }
    Ok(())
}

fn unpickle(bytes: &[u8]) -> Result<Value, String> {
    if bytes.first() != Some(&0x80) {
        return Err(
            "not an uncompressed pickle (a compressed joblib file? save it with compress=0)".into(),
        );
    }
    let mut r = Reader { bytes, at: 0 };
    let mut stack: Vec<Node> = Vec::new();
    let mut memo: BTreeMap<usize, Node> = BTreeMap::new();
    let mut budget = Budget::default();
    loop {
        let at = r.at;
        let op = r.u8()?;
        let leaf = match op {
            0x80 => {
                r.u8()?;
                continue;
            }
            0x95 => {
                r.u64()?;
                continue;
            }
            b'.' => return pop(&mut stack, at).map(|n| n.v),
            b'(' => Value::Mark,
            b'}' => Value::Dict(Vec::new()),
            b']' => Value::List(Vec::new()),
            b')' => Value::Tuple(Vec::new()),
            b'N' => Value::None,
            0x88 => Value::Bool(true),
            0x89 => Value::Bool(false),
            b'K' => Value::Int(r.u8()? as i64),
            b'M' => Value::Int(u16::from_le_bytes(r.take(2)?.try_into().expect("2 bytes")) as i64),
            b'J' => Value::Int(i32::from_le_bytes(r.take(4)?.try_into().expect("4 bytes")) as i64),
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
                Value::Int(v)
            }
            b'G' => Value::Float(f64::from_be_bytes(r.take(8)?.try_into().expect("8 bytes"))),
            0x8c => {
                let n = r.u8()? as usize;
                Value::Str(r.utf8(n)?)
            }
            b'X' => {
                let n = r.u32()?;
                Value::Str(r.utf8(n)?)
            }
            0x8d => {
                let n = r.u64()?;
                Value::Str(r.utf8(n)?)
            }
            b'C' => {
                let n = r.u8()? as usize;
                Value::Bytes(r.take(n)?.to_vec())
            }
            b'B' => {
                let n = r.u32()?;
                Value::Bytes(r.take(n)?.to_vec())
            }
            0x8e => {
                let n = r.u64()?;
                Value::Bytes(r.take(n)?.to_vec())
            }
            b'c' => {
                let module = r.line()?;
                let name = r.line()?;
                Value::Global(format!("{module}.{name}"))
            }
            0x94 | b'q' | b'r' => {
                let i = match op {
                    0x94 => memo.len(),
                    b'q' => r.u8()? as usize,
                    _ => r.u32()?,
                };
                let top = stack
                    .last()
                    .ok_or_else(|| format!("MEMOIZE/PUT on an empty stack at byte {at}"))?;
                budget.charge(top, at)?;
                memo.insert(i, top.clone());
                continue;
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
                budget.charge(v, at)?;
                stack.push(v.clone());
                continue;
            }
            0x93 => {
                let name = pop(&mut stack, at)?;
                let module = pop(&mut stack, at)?;
                match (module.v, name.v) {
                    (Value::Str(m), Value::Str(n)) => Value::Global(format!("{m}.{n}")),
                    _ => return Err(format!("STACK_GLOBAL without names at byte {at}")),
                }
            }
            b't' | 0x85..=0x87 => {
                let items = if op == b't' {
                    pop_mark(&mut stack, at)?
                } else {
                    let n = (op - 0x84) as usize;
                    if stack.len() < n {
                        return Err(format!("stack underflow at byte {at}"));
                    }
                    stack.split_off(stack.len() - n)
                };
                let node = Node::parent(items, Value::Tuple);
                budget.charge_new(&node, at)?;
                stack.push(node);
                continue;
            }
            b'R' | 0x81 => {
                let args = pop(&mut stack, at)?;
                let callable = pop(&mut stack, at)?;
                let Value::Tuple(arg_values) = &args.v else {
                    return Err(format!("call without an argument tuple at byte {at}"));
                };
                // protocol 2 writes bytes as `_codecs.encode(latin-1 text, 'latin1')`
                if global_name(&callable.v) == Some("_codecs.encode")
                    && let [Value::Str(text), Value::Str(codec)] = arg_values.as_slice()
                    && matches!(codec.as_str(), "latin1" | "latin-1")
                {
                    let bytes = text
                        .chars()
                        .map(|c| u8::try_from(c as u32))
                        .collect::<Result<Vec<u8>, _>>()
                        .map_err(|_| format!("not latin-1 text at byte {at}"))?;
                    Value::Bytes(bytes)
                } else {
                    let node = call(callable, args);
                    budget.charge_new(&node, at)?;
                    stack.push(node);
                    continue;
                }
            }
            b'b' => {
                let state = pop(&mut stack, at)?;
                let mut obj = pop(&mut stack, at)?;
                let Value::Object {
                    callable,
                    state: slot,
                    ..
                } = &mut obj.v
                else {
                    return Err(format!("BUILD of {:?} at byte {at}", obj.v));
                };
                if global_name(callable).is_some_and(|n| n.ends_with("NumpyArrayWrapper")) {
                    joblib_array(&mut r, &state.v)?
                } else if global_name(callable).is_some_and(|n| n.ends_with("._reconstruct")) {
                    numpy_array(&state.v)?
                } else {
                    *slot = Some(Box::new(state.v.clone()));
                    obj.absorb(&state);
                    check_depth(&obj, at)?;
                    stack.push(obj);
                    continue;
                }
            }
            b's' | b'u' | b'a' | b'e' => {
                let items = match op {
                    b's' => {
                        let v = pop(&mut stack, at)?;
                        let k = pop(&mut stack, at)?;
                        vec![k, v]
                    }
                    b'a' => vec![pop(&mut stack, at)?],
                    _ => pop_mark(&mut stack, at)?,
                };
                extend_top(&mut stack, items, at, &format!("opcode {:?}", op as char))?;
                continue;
            }
            other => {
                return Err(format!(
                    "unsupported pickle opcode 0x{other:02x} at byte {at}"
                ));
            }
        };
        let node = Node::leaf(leaf);
        budget.charge(&node, at)?;
        stack.push(node);
    }
}

/// `callable(*args)`, as one node.
fn call(callable: Node, args: Node) -> Node {
    Node::parent(vec![callable, args], |mut v| {
        let args = match v.pop() {
            Some(Value::Tuple(a)) => a,
            _ => Vec::new(),
        };
        Value::Object {
            callable: Box::new(v.pop().unwrap_or(Value::None)),
            args,
            state: None,
        }
    })
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

    /// A megabyte of nested one-tuples: refused at the nesting limit, no stack overflow.
    #[test]
    fn deep_nesting_is_an_error() {
        let mut b = vec![0x80, 4, b'N'];
        b.extend(std::iter::repeat_n(0x85u8, 1 << 20));
        b.push(b'.');
        let err = pickled_arrays(&b).unwrap_err();
        assert!(err.contains("nested deeper than 64"), "{err}");
        // the same through lists and MARK/TUPLE
        let mut b = vec![0x80, 4];
        for _ in 0..100_000 {
            b.extend([b']', b'(']);
        }
        let err = pickled_arrays(&b).unwrap_err();
        assert!(err.contains("the file ends"), "{err}");
        let mut b = vec![0x80, 4, b'N'];
        for _ in 0..200 {
            b.extend([b']', 0x94]);
        }
        b.extend(std::iter::repeat_n(b'a', 200));
        let err = pickled_arrays(&b).unwrap_err();
        assert!(err.contains("APPEND") || err.contains("nested"), "{err}");
    }

    /// A list built from its own memo entry, doubled 24 times (200 bytes that would make 16
    /// million values): refused at the value limit.
    #[test]
    fn memo_bombs_are_errors() {
        let mut b = vec![0x80, 4, b']', b'K', 1, b'a', 0x94];
        for i in 0..24u8 {
            // a new list holding two copies of the previous one: [prev, prev]
            b.extend([b']', b'(', b'h', i, b'h', i, b'e', 0x94]);
        }
        b.push(b'.');
        assert!(b.len() <= 200);
        let err = pickled_arrays(&b).unwrap_err();
        assert!(err.contains("memo bomb"), "{err}");
        // big strings copied: refused by the byte limit, not the value count
        let mut b = vec![0x80, 4, 0x8e];
        b.extend((1u64 << 20).to_le_bytes());
        b.extend(std::iter::repeat_n(b'x', 1 << 20));
        b.push(0x94);
        b.extend(std::iter::repeat_n([b'h', 0], 2000).flatten());
        let err = pickled_arrays(&b).unwrap_err();
        assert!(err.contains(crate::limits::MAX_FILE_MB_ENV), "{err}");
    }
}
