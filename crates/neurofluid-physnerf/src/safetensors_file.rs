//! Minimal safetensors reading and writing (weight files; the reference cases of the developer
//! tools). Reading converts any float dtype (F16/BF16/F32/F64) to f64 and any integer dtype to
//! i64; writing goes through [`neurofluid_core::atomic`].

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use safetensors::tensor::{Dtype, SafeTensors, TensorView};

use crate::error::{PhysNerfError, Result};

/// A safetensors file read into memory.
#[derive(Debug, Clone)]
pub struct StFile {
    path: PathBuf,
    bytes: Vec<u8>,
}

fn format_err(path: &Path, e: impl std::fmt::Display) -> PhysNerfError {
    PhysNerfError::Format {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

impl StFile {
    /// Reads and validates the file.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let bytes = std::fs::read(&path).map_err(|e| PhysNerfError::io(&path, e))?;
        SafeTensors::deserialize(&bytes).map_err(|e| format_err(&path, e))?;
        Ok(Self { path, bytes })
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn tensors(&self) -> SafeTensors<'_> {
        SafeTensors::deserialize(&self.bytes).expect("validated in open")
    }

    /// The `__metadata__` entries (empty when there are none).
    pub fn metadata(&self) -> Result<HashMap<String, String>> {
        let (_, meta) =
            SafeTensors::read_metadata(&self.bytes).map_err(|e| format_err(&self.path, e))?;
        Ok(meta.metadata().clone().unwrap_or_default())
    }

    /// The tensor names, sorted.
    pub fn names(&self) -> Vec<String> {
        let mut v: Vec<String> = self
            .tensors()
            .names()
            .into_iter()
            .map(String::from)
            .collect();
        v.sort();
        v
    }

    /// True when the file holds `name`.
    pub fn contains(&self, name: &str) -> bool {
        self.tensors().tensor(name).is_ok()
    }

    fn view(&self, name: &str, expected: &str) -> Result<(Dtype, Vec<usize>, Vec<u8>)> {
        let st = self.tensors();
        let v = st.tensor(name).map_err(|_| PhysNerfError::Missing {
            path: self.path.clone(),
            name: name.into(),
            expected: expected.into(),
        })?;
        Ok((v.dtype(), v.shape().to_vec(), v.data().to_vec()))
    }

    fn check_shape(&self, name: &str, shape: &[usize], expected: Option<&[usize]>) -> Result<()> {
        if let Some(e) = expected
            && e != shape
        {
            return Err(PhysNerfError::Mismatch {
                path: self.path.clone(),
                name: name.into(),
                expected: format!("shape {e:?}"),
                found: format!("shape {shape:?}"),
            });
        }
        Ok(())
    }

    /// A float tensor as f64 (F16, BF16, F32 or F64 storage); `expected` checks the shape.
    pub fn floats(&self, name: &str, expected: Option<&[usize]>) -> Result<(Vec<usize>, Vec<f64>)> {
        let (dtype, shape, data) =
            self.view(name, &format!("a float tensor of shape {expected:?}"))?;
        self.check_shape(name, &shape, expected)?;
        let v: Vec<f64> = match dtype {
            Dtype::F64 => data
                .chunks_exact(8)
                .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
                .collect(),
            Dtype::F32 => data
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes(c.try_into().unwrap()) as f64)
                .collect(),
            Dtype::F16 => data
                .chunks_exact(2)
                .map(|c| half::f16::from_le_bytes([c[0], c[1]]).to_f64())
                .collect(),
            Dtype::BF16 => data
                .chunks_exact(2)
                .map(|c| half::bf16::from_le_bytes([c[0], c[1]]).to_f64())
                .collect(),
            other => {
                return Err(PhysNerfError::Mismatch {
                    path: self.path.clone(),
                    name: name.into(),
                    expected: "a float dtype (F16, BF16, F32, F64)".into(),
                    found: format!("{other:?}"),
                });
            }
        };
        Ok((shape, v))
    }

    /// An integer tensor as i64 (U8, U16, I32, I64, …); `expected` checks the shape.
    pub fn ints(&self, name: &str, expected: Option<&[usize]>) -> Result<(Vec<usize>, Vec<i64>)> {
        let (dtype, shape, data) =
            self.view(name, &format!("an integer tensor of shape {expected:?}"))?;
        self.check_shape(name, &shape, expected)?;
        let v: Vec<i64> = match dtype {
            Dtype::U8 | Dtype::BOOL => data.iter().map(|&b| b as i64).collect(),
            Dtype::I8 => data.iter().map(|&b| b as i8 as i64).collect(),
            Dtype::U16 => data
                .chunks_exact(2)
                .map(|c| u16::from_le_bytes([c[0], c[1]]) as i64)
                .collect(),
            Dtype::I16 => data
                .chunks_exact(2)
                .map(|c| i16::from_le_bytes([c[0], c[1]]) as i64)
                .collect(),
            Dtype::I32 => data
                .chunks_exact(4)
                .map(|c| i32::from_le_bytes(c.try_into().unwrap()) as i64)
                .collect(),
            Dtype::U32 => data
                .chunks_exact(4)
                .map(|c| u32::from_le_bytes(c.try_into().unwrap()) as i64)
                .collect(),
            Dtype::I64 => data
                .chunks_exact(8)
                .map(|c| i64::from_le_bytes(c.try_into().unwrap()))
                .collect(),
            other => {
                return Err(PhysNerfError::Mismatch {
                    path: self.path.clone(),
                    name: name.into(),
                    expected: "an integer dtype".into(),
                    found: format!("{other:?}"),
                });
            }
        };
        Ok((shape, v))
    }
}

/// Collects tensors and writes them as one safetensors file.
#[derive(Debug, Default)]
pub struct StWriter {
    entries: Vec<(String, Dtype, Vec<usize>, Vec<u8>)>,
    metadata: HashMap<String, String>,
}

impl StWriter {
    /// An empty writer.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a metadata entry.
    pub fn meta(&mut self, key: &str, value: String) {
        self.metadata.insert(key.into(), value);
    }

    fn push(&mut self, name: &str, dtype: Dtype, shape: &[usize], bytes: Vec<u8>) {
        self.entries.retain(|e| e.0 != name);
        self.entries
            .push((name.into(), dtype, shape.to_vec(), bytes));
    }

    /// Adds an F32 tensor.
    pub fn f32(&mut self, name: &str, shape: &[usize], data: &[f32]) {
        self.push(
            name,
            Dtype::F32,
            shape,
            data.iter().flat_map(|v| v.to_le_bytes()).collect(),
        );
    }

    /// Adds an F64 tensor.
    pub fn f64(&mut self, name: &str, shape: &[usize], data: &[f64]) {
        self.push(
            name,
            Dtype::F64,
            shape,
            data.iter().flat_map(|v| v.to_le_bytes()).collect(),
        );
    }

    /// Adds a float tensor in F32 or F64 storage.
    pub fn float(&mut self, name: &str, shape: &[usize], data: &[f64], as_f64: bool) {
        if as_f64 {
            self.f64(name, shape, data);
        } else {
            let v: Vec<f32> = data.iter().map(|&x| x as f32).collect();
            self.f32(name, shape, &v);
        }
    }

    /// Adds a U8 tensor.
    pub fn u8(&mut self, name: &str, shape: &[usize], data: &[u8]) {
        self.push(name, Dtype::U8, shape, data.to_vec());
    }

    /// Adds a U16 tensor (values are saturated to 65535).
    pub fn u16(&mut self, name: &str, shape: &[usize], data: &[u32]) {
        self.push(
            name,
            Dtype::U16,
            shape,
            data.iter()
                .flat_map(|&v| (v.min(65535) as u16).to_le_bytes())
                .collect(),
        );
    }

    /// Adds an I32 tensor.
    pub fn i32(&mut self, name: &str, shape: &[usize], data: &[i32]) {
        self.push(
            name,
            Dtype::I32,
            shape,
            data.iter().flat_map(|v| v.to_le_bytes()).collect(),
        );
    }

    /// Serialises everything and writes `path` atomically.
    pub fn write(self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let mut views = Vec::with_capacity(self.entries.len());
        for (name, dtype, shape, bytes) in &self.entries {
            let v =
                TensorView::new(*dtype, shape.clone(), bytes).map_err(|e| format_err(path, e))?;
            views.push((name.clone(), v));
        }
        let meta = (!self.metadata.is_empty()).then_some(self.metadata);
        let bytes = safetensors::tensor::serialize(views, meta).map_err(|e| format_err(path, e))?;
        neurofluid_core::atomic::write_bytes(path, &bytes).map_err(|e| PhysNerfError::io(path, e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roundtrip_and_clear_errors() {
        let dir = std::env::temp_dir().join(format!("nf_st_{}", std::process::id()));
        let path = dir.join("a.safetensors");
        let mut w = StWriter::new();
        w.f32("x", &[2, 2], &[1.0, 2.0, 3.0, 4.5]);
        w.u16("s", &[3], &[1, 70000, 3]);
        w.meta("k", "v".into());
        w.write(&path).unwrap();
        let f = StFile::open(&path).unwrap();
        assert_eq!(
            f.floats("x", Some(&[2, 2])).unwrap().1,
            vec![1.0, 2.0, 3.0, 4.5]
        );
        assert_eq!(f.ints("s", None).unwrap().1, vec![1, 65535, 3]);
        assert_eq!(f.metadata().unwrap()["k"], "v");
        let e = f.floats("x", Some(&[4])).unwrap_err().to_string();
        assert!(
            e.contains("a.safetensors") && e.contains("`x`") && e.contains("[4]"),
            "{e}"
        );
        let e = f.floats("nope", None).unwrap_err().to_string();
        assert!(e.contains("nope") && e.contains("missing"), "{e}");
        std::fs::remove_dir_all(dir).ok();
    }
}
