//! Weight files: the nerf_pl / NeuroFluid state-dict layout (`nerf_coarse.xyz_encoding_1.0.weight`,
//! …, PyTorch `[out, in]` weights, any float storage) for import, and the same layout (plus the
//! renderer configuration as metadata) for our own checkpoints.

use std::collections::BTreeSet;
use std::path::Path;

use burn::module::Param;
use burn::nn::Linear;
use burn::prelude::*;
use burn::tensor::{DType, TensorData};

use crate::config::PhysNerfConfig;
use crate::error::{PhysNerfError, Result};
use crate::mlp::{NerfMlp, layer_shapes};
use crate::renderer::PhysNerf;
use crate::safetensors_file::{StFile, StWriter};

/// Metadata key holding the JSON renderer configuration in files we write.
pub const CONFIG_KEY: &str = "physnerf_config";
/// Metadata keys of the ray segment the weights were trained with (not part of the config).
const NEAR_KEY: &str = "near";
const FAR_KEY: &str = "far";
/// The two network prefixes.
pub const NETS: [&str; 2] = ["nerf_coarse", "nerf_fine"];

fn to_tensor(values: Vec<f64>, shape: Vec<usize>, device: &Device, dtype: DType) -> Tensor<2> {
    neurofluid_core::transfer::upload(TensorData::new(values, shape), (device, dtype))
}

fn load_net(
    file: &StFile,
    prefix: &str,
    config: &PhysNerfConfig,
    device: &Device,
    dtype: DType,
) -> Result<NerfMlp> {
    let mut layers = Vec::new();
    for (name, [d_in, d_out]) in layer_shapes(&config.mlp_shape()) {
        let wname = format!("{prefix}.{name}.weight");
        let bname = format!("{prefix}.{name}.bias");
        let (_, w) = file.floats(&wname, Some(&[d_out, d_in]))?;
        let (_, b) = file.floats(&bname, Some(&[d_out]))?;
        // PyTorch [out, in] → Burn [in, out]
        let mut wt = vec![0.0f64; w.len()];
        for o in 0..d_out {
            for i in 0..d_in {
                wt[i * d_out + o] = w[o * d_in + i];
            }
        }
        let weight = to_tensor(wt, vec![d_in, d_out], device, dtype);
        let bias = to_tensor(b, vec![1, d_out], device, dtype).reshape([d_out]);
        layers.push(Linear {
            weight: Param::from_tensor(weight),
            bias: Some(Param::from_tensor(bias)),
        });
    }
    Ok(NerfMlp::from_layers(&mut layers, config.skip))
}

/// The parameter names a renderer with `config` has, in file order.
pub fn parameter_names(config: &PhysNerfConfig) -> Vec<String> {
    let mut v = Vec::new();
    for net in NETS {
        for (name, _) in layer_shapes(&config.mlp_shape()) {
            v.push(format!("{net}.{name}.weight"));
            v.push(format!("{net}.{name}.bias"));
        }
    }
    v
}

impl PhysNerf {
    /// Loads nerf_pl-named weights (both networks) with `config`'s widths, in `dtype` (F32 or
    /// F64) on `device`. Every expected tensor must be present with its exact shape, and no
    /// other tensor may be in the file.
    pub fn from_nerf_pl(
        path: impl AsRef<Path>,
        config: PhysNerfConfig,
        device: &Device,
        dtype: DType,
    ) -> Result<Self> {
        config.validate().map_err(PhysNerfError::Invalid)?;
        if !matches!(dtype, DType::F32 | DType::F64) {
            return Err(PhysNerfError::Invalid(format!(
                "weights dtype must be F32 or F64, got {dtype:?}"
            )));
        }
        let file = StFile::open(path)?;
        let known: BTreeSet<String> = parameter_names(&config).into_iter().collect();
        let extra: Vec<String> = file
            .names()
            .into_iter()
            .filter(|n| !known.contains(n))
            .collect();
        if !extra.is_empty() {
            return Err(PhysNerfError::Unexpected {
                path: file.path().to_path_buf(),
                names: extra,
            });
        }
        let model = Self {
            coarse: load_net(&file, NETS[0], &config, device, dtype)?,
            fine: load_net(&file, NETS[1], &config, device, dtype)?,
            config,
        };
        if let Some(param) = neurofluid_core::params::first_non_finite(&model) {
            return Err(PhysNerfError::Invalid(format!(
                "{}: parameter `{param}` holds NaN or infinite values",
                file.path().display()
            )));
        }
        Ok(model)
    }

    /// Loads a file written by [`PhysNerf::save`] (the configuration comes from its metadata).
    pub fn load(path: impl AsRef<Path>, device: &Device, dtype: DType) -> Result<Self> {
        let path = path.as_ref();
        let file = StFile::open(path)?;
        let meta = file.metadata()?;
        let json = meta
            .get(CONFIG_KEY)
            .ok_or_else(|| PhysNerfError::Metadata {
                path: path.to_path_buf(),
                field: CONFIG_KEY.into(),
                message: "missing; a nerf_pl file without it loads with PhysNerf::from_nerf_pl"
                    .into(),
            })?;
        let mut config: PhysNerfConfig =
            serde_json::from_str(json).map_err(|e| PhysNerfError::Metadata {
                path: path.to_path_buf(),
                field: CONFIG_KEY.into(),
                message: e.to_string(),
            })?;
        // the ray segment is the scene's, kept beside the config so the file is self-contained
        for (key, slot) in [(NEAR_KEY, &mut config.near), (FAR_KEY, &mut config.far)] {
            if let Some(v) = meta.get(key) {
                *slot = v.parse().map_err(|e| PhysNerfError::Metadata {
                    path: path.to_path_buf(),
                    field: key.into(),
                    message: format!("expected a number: {e}"),
                })?;
            }
        }
        Self::from_nerf_pl(path, config, device, dtype)
    }

    /// Writes both networks in the nerf_pl layout (PyTorch `[out, in]` weights, F32, or F64 for
    /// an F64 model) with the configuration as metadata, atomically.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<()> {
        if let Some(param) = neurofluid_core::params::first_non_finite(self) {
            return Err(PhysNerfError::Invalid(format!(
                "{}: not written: parameter `{param}` holds NaN or infinite values",
                path.as_ref().display()
            )));
        }
        let as_f64 = self.dtype() == DType::F64;
        let mut w = StWriter::new();
        for (prefix, net) in NETS.iter().zip([&self.coarse, &self.fine]) {
            for (name, layer) in net.named_layers() {
                let [d_in, d_out] = layer.weight.val().dims();
                let wt: Vec<f64> =
                    neurofluid_core::transfer::read_vec(layer.weight.val().transpose())
                        .map_err(|e| PhysNerfError::Readback(format!("{e:?}")))?;
                w.float(
                    &format!("{prefix}.{name}.weight"),
                    &[d_out, d_in],
                    &wt,
                    as_f64,
                );
                if let Some(b) = &layer.bias {
                    let bv: Vec<f64> = neurofluid_core::transfer::read_vec(b.val())
                        .map_err(|e| PhysNerfError::Readback(format!("{e:?}")))?;
                    w.float(&format!("{prefix}.{name}.bias"), &[d_out], &bv, as_f64);
                }
            }
        }
        w.meta(
            CONFIG_KEY,
            serde_json::to_string(&self.config).expect("config serialises"),
        );
        w.meta(NEAR_KEY, self.config.near.to_string());
        w.meta(FAR_KEY, self.config.far.to_string());
        w.meta("format", "neurofluid-physnerf/1".into());
        w.write(path)
    }
}
