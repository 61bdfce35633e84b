//! Weights: the public DLF PyTorch `.pt` / `.safetensors` files (by tensor name, strictly), and
//! our own burnpack checkpoints (written atomically).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use burn::module::Param;
use burn::nn::Linear;
use burn::prelude::*;

use crate::config::DlfConfig;
use crate::conv::ContinuousConv;
use crate::mapping::KERNEL_SIZE;
use crate::net::{DlfNet, LAYER_CHANNELS};

/// Why weights could not be read or applied.
#[derive(Debug, thiserror::Error)]
pub enum WeightsError {
    /// The file could not be read or parsed.
    #[error("{path}: cannot read weights: {reason}")]
    Read {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        reason: String,
    },
    /// The file extension names no format we read.
    #[error("{path}: unknown weights format: expected .pt, .pth, .safetensors or .bpk")]
    UnknownFormat {
        /// The file.
        path: PathBuf,
    },
    /// A tensor the model needs is not in the file.
    #[error("{path}: tensor `{name}` is missing (expected shape {expected:?})")]
    Missing {
        /// The file.
        path: PathBuf,
        /// The tensor name.
        name: String,
        /// The shape the model expects.
        expected: Vec<usize>,
    },
    /// The file holds a tensor the model does not have.
    #[error(
        "{path}: unexpected tensor `{name}` (shape {shape:?}); the DLF model has no such parameter"
    )]
    Unexpected {
        /// The file.
        path: PathBuf,
        /// The tensor name.
        name: String,
        /// Its shape.
        shape: Vec<usize>,
    },
    /// A tensor has the wrong shape.
    #[error("{path}: tensor `{name}` has shape {got:?}, expected {expected:?}")]
    Shape {
        /// The file.
        path: PathBuf,
        /// The tensor name.
        name: String,
        /// Its shape in the file.
        got: Vec<usize>,
        /// The shape the model expects.
        expected: Vec<usize>,
    },
    /// A tensor holds values we cannot use (non-float dtype, non-zero conv offset, NaN).
    #[error("{path}: tensor `{name}`: {reason}")]
    Value {
        /// The file.
        path: PathBuf,
        /// The tensor name.
        name: String,
        /// What is wrong with it.
        reason: String,
    },
    /// Writing a checkpoint failed.
    #[error("{path}: cannot write checkpoint: {reason}")]
    Write {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        reason: String,
    },
}

/// A named float tensor read from a weights file.
#[derive(Debug, Clone, PartialEq)]
pub struct NamedTensor {
    /// Shape.
    pub shape: Vec<usize>,
    /// Values, row-major.
    pub data: Vec<f32>,
}

fn read_err(path: &Path, reason: impl ToString) -> WeightsError {
    WeightsError::Read {
        path: path.to_path_buf(),
        reason: reason.to_string(),
    }
}

fn f32_from_le(bytes: &[u8]) -> Vec<f32> {
    bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// Little-endian float64 bytes, rounded to f32.
fn f32_from_f64_le(bytes: &[u8]) -> Vec<f32> {
    bytes
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")) as f32)
        .collect()
}

/// Reads every tensor of a PyTorch `state_dict` file (`torch.save`, zip format) by name.
pub fn read_pytorch(path: &Path) -> Result<BTreeMap<String, NamedTensor>, WeightsError> {
    use burn::store::pytorch_reader::{DType, PytorchReader};
    let reader = PytorchReader::new(path).map_err(|e| read_err(path, e))?;
    let mut out = BTreeMap::new();
    for (name, t) in reader.into_tensors() {
        let shape = t.shape().to_vec();
        let bytes = t
            .read()
            .map_err(|e| read_err(path, format!("tensor `{name}`: {e}")))?;
        let data = match t.dtype() {
            DType::F32 => f32_from_le(&bytes),
            DType::F64 => f32_from_f64_le(&bytes),
            other => {
                return Err(WeightsError::Value {
                    path: path.to_path_buf(),
                    name,
                    reason: format!("dtype {other:?}, expected float32"),
                });
            }
        };
        out.insert(name, NamedTensor { shape, data });
    }
    Ok(out)
}

/// Reads every tensor of a `.safetensors` file by name.
pub fn read_safetensors(path: &Path) -> Result<BTreeMap<String, NamedTensor>, WeightsError> {
    use safetensors::{Dtype, SafeTensors};
    let bytes = neurofluid_core::input_file::read(path).map_err(|e| read_err(path, e))?;
    let st = SafeTensors::deserialize(&bytes).map_err(|e| read_err(path, e))?;
    let mut out = BTreeMap::new();
    for (name, view) in st.tensors() {
        let data = match view.dtype() {
            Dtype::F32 => f32_from_le(view.data()),
            Dtype::F64 => f32_from_f64_le(view.data()),
            other => {
                return Err(WeightsError::Value {
                    path: path.to_path_buf(),
                    name,
                    reason: format!("dtype {other:?}, expected float32"),
                });
            }
        };
        out.insert(
            name,
            NamedTensor {
                shape: view.shape().to_vec(),
                data,
            },
        );
    }
    Ok(out)
}

/// The parameter names and shapes of the DLF model in PyTorch layout (Linear weights `[out, in]`).
pub fn expected_tensors() -> Vec<(String, Vec<usize>)> {
    let [c0, c1, c2, c3] = LAYER_CHANNELS;
    let k = KERNEL_SIZE;
    let mut v = Vec::new();
    for (name, cin, cout) in [
        ("conv0_fluid", 4, c0),
        ("conv0_obstacle", 3, c0),
        ("conv1", 3 * c0, c1),
        ("conv2", c1, c2),
        ("conv3", c2, c3),
    ] {
        v.push((format!("{name}.kernel"), vec![k, k, k, cin, cout]));
        v.push((format!("{name}.bias"), vec![cout]));
    }
    for (name, cin, cout) in [
        ("dense0_fluid", 4, c0),
        ("dense1", 3 * c0, c1),
        ("dense2", c1, c2),
        ("dense3", c2, c3),
    ] {
        v.push((format!("{name}.weight"), vec![cout, cin]));
        v.push((format!("{name}.bias"), vec![cout]));
    }
    v
}

/// Builds a DLF network from named tensors (PyTorch names and layout), strictly: a missing,
/// unexpected or mis-shaped tensor is an error naming it. `gravity` is ignored (it is a setting,
/// see [`DlfConfig`]) and the `*.offset` buffers must be zero.
pub fn net_from_tensors(
    mut tensors: BTreeMap<String, NamedTensor>,
    path: &Path,
    config: DlfConfig,
    device: &Device,
) -> Result<DlfNet, WeightsError> {
    let path_buf = path.to_path_buf();
    let mut take = |name: &str, expected: &[usize]| -> Result<NamedTensor, WeightsError> {
        let t = tensors.remove(name).ok_or_else(|| WeightsError::Missing {
            path: path_buf.clone(),
            name: name.to_string(),
            expected: expected.to_vec(),
        })?;
        if t.shape != expected {
            return Err(WeightsError::Shape {
                path: path_buf.clone(),
                name: name.to_string(),
                got: t.shape,
                expected: expected.to_vec(),
            });
        }
        if t.data.iter().any(|v| !v.is_finite()) {
            return Err(WeightsError::Value {
                path: path_buf.clone(),
                name: name.to_string(),
                reason: "holds NaN or infinite values".into(),
            });
        }
        Ok(t)
    };
    let mut net = DlfNet::zeros(config, device);
    let expected: BTreeMap<String, Vec<usize>> = expected_tensors().into_iter().collect();
    let mut conv = |conv: &mut ContinuousConv, name: &str| -> Result<(), WeightsError> {
        let ks = &expected[&format!("{name}.kernel")];
        let bs = &expected[&format!("{name}.bias")];
        let k = take(&format!("{name}.kernel"), ks)?;
        let b = take(&format!("{name}.bias"), bs)?;
        let kshape: [usize; 5] = ks.clone().try_into().expect("5-d kernel");
        conv.kernel = Param::from_tensor(neurofluid_core::transfer::upload(
            TensorData::new(k.data, kshape),
            device,
        ));
        conv.bias = Param::from_tensor(neurofluid_core::transfer::upload(
            TensorData::new(b.data, [bs[0]]),
            device,
        ));
        Ok(())
    };
    conv(&mut net.conv0_fluid, "conv0_fluid")?;
    conv(&mut net.conv0_obstacle, "conv0_obstacle")?;
    conv(&mut net.conv1, "conv1")?;
    conv(&mut net.conv2, "conv2")?;
    conv(&mut net.conv3, "conv3")?;
    let mut dense = |lin: &mut Linear, name: &str| -> Result<(), WeightsError> {
        let ws = &expected[&format!("{name}.weight")];
        let bs = &expected[&format!("{name}.bias")];
        let w = take(&format!("{name}.weight"), ws)?;
        let b = take(&format!("{name}.bias"), bs)?;
        let (out, inp) = (ws[0], ws[1]);
        // torch Linear is [out, in]; Burn's is [in, out]
        let wt = neurofluid_core::transfer::upload::<2, burn::tensor::Float, _>(
            TensorData::new(w.data, [out, inp]),
            device,
        )
        .transpose();
        lin.weight = Param::from_tensor(wt);
        lin.bias = Some(Param::from_tensor(neurofluid_core::transfer::upload(
            TensorData::new(b.data, [out]),
            device,
        )));
        Ok(())
    };
    dense(&mut net.dense0_fluid, "dense0_fluid")?;
    dense(&mut net.dense1, "dense1")?;
    dense(&mut net.dense2, "dense2")?;
    dense(&mut net.dense3, "dense3")?;
    for (name, t) in tensors {
        if name == "gravity" && t.shape == [3] {
            tracing::debug!(
                "{}: ignoring stored gravity {:?} (gravity is a setting)",
                path.display(),
                t.data
            );
            continue;
        }
        if name.ends_with(".offset") && t.shape == [3] {
            if t.data.iter().any(|&v| v != 0.0) {
                return Err(WeightsError::Value {
                    path: path.to_path_buf(),
                    name,
                    reason: format!(
                        "conv offset {:?} is not zero; only zero offsets are supported",
                        t.data
                    ),
                });
            }
            continue;
        }
        return Err(WeightsError::Unexpected {
            path: path.to_path_buf(),
            name,
            shape: t.shape,
        });
    }
    Ok(net)
}

/// Loads a DLF network from a `.pt`/`.pth` (PyTorch), `.safetensors` or `.bpk` (our burnpack
/// checkpoint) file.
pub fn load_dlf(path: &Path, config: DlfConfig, device: &Device) -> Result<DlfNet, WeightsError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    match ext.as_str() {
        "pt" | "pth" => net_from_tensors(read_pytorch(path)?, path, config, device),
        "safetensors" => net_from_tensors(read_safetensors(path)?, path, config, device),
        "bpk" => load_checkpoint(path, config, device),
        _ => Err(WeightsError::UnknownFormat {
            path: path.to_path_buf(),
        }),
    }
}

/// Saves the network's parameters as a burnpack file, atomically (temp file, then rename).
pub fn save_checkpoint(net: &DlfNet, path: &Path) -> Result<(), WeightsError> {
    let werr = |reason: String| WeightsError::Write {
        path: path.to_path_buf(),
        reason,
    };
    if let Some(name) = neurofluid_core::params::first_non_finite(net) {
        return Err(werr(format!(
            "not written: parameter `{name}` holds NaN or infinite values"
        )));
    }
    let bytes = net
        .clone()
        .into_record()
        .into_bytes()
        .map_err(|e| werr(e.to_string()))?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| werr(e.to_string()))?;
    }
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(format!(".tmp{}", std::process::id()));
    let tmp = PathBuf::from(tmp);
    std::fs::write(&tmp, &bytes[..]).map_err(|e| werr(e.to_string()))?;
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        werr(e.to_string())
    })
}

/// Loads a burnpack checkpoint written by [`save_checkpoint`].
pub fn load_checkpoint(
    path: &Path,
    config: DlfConfig,
    device: &Device,
) -> Result<DlfNet, WeightsError> {
    let bytes = neurofluid_core::input_file::read(path).map_err(|e| read_err(path, e))?;
    let record = burn::store::ModuleRecord::from_bytes(burn::tensor::Bytes::from_bytes_vec(bytes))
        .map_err(|e| read_err(path, e))?;
    let net = DlfNet::zeros(config, device)
        .try_load_record(record)
        .map_err(|e| read_err(path, e))?;
    match neurofluid_core::params::first_non_finite(&net) {
        Some(name) => Err(WeightsError::Value {
            path: path.to_path_buf(),
            name,
            reason: "holds NaN or infinite values".into(),
        }),
        None => Ok(net),
    }
}

#[cfg(test)]
mod non_finite_tests {
    use super::*;

    /// A model with a NaN parameter is not written, and a file holding one is not loaded.
    #[test]
    fn non_finite_weights_are_neither_written_nor_loaded() {
        let device = neurofluid_core::device::cpu();
        let net = DlfNet::new(DlfConfig::default(), &device);
        let mut bad = net.clone();
        bad.dense0_fluid.weight = bad.dense0_fluid.weight.map(|w| w.mul_scalar(f32::NAN));
        let dir = std::env::temp_dir().join(format!("nf-dlf-nan-{}", std::process::id()));
        let path = dir.join("bad.bpk");
        let err = save_checkpoint(&bad, &path).unwrap_err().to_string();
        assert!(err.contains("NaN") && !path.exists(), "{err}");
        // written around the check, as a foreign tool could
        std::fs::create_dir_all(&dir).unwrap();
        let bytes = bad.clone().into_record().into_bytes().unwrap();
        std::fs::write(&path, &bytes[..]).unwrap();
        let err = load_dlf(&path, DlfConfig::default(), &device)
            .unwrap_err()
            .to_string();
        assert!(err.contains("bad.bpk") && err.contains("NaN"), "{err}");
        let _ = std::fs::remove_dir_all(dir);
    }
}
