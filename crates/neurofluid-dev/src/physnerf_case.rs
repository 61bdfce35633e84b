//! The PhysNeRF reference-case harness. Case files (`tests/data/physnerf/*.safetensors`, made by
//! `physnerf_reference.py`): read the inputs, render them, and produce the same output keys
//! (`rays/*`, `coarse/*`, `fine/*`, `loss/*`, `grad/*`, `gradnorm/values`), so a case can be
//! checked from the command line (`neurofluid-dev physnerf-case`) and by the parity tests.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use burn::prelude::*;
use burn::tensor::{DType, Gradients, TensorData};
use neurofluid_core::rows::{RowIndex, gather_rows};
use serde::Deserialize;

use neurofluid_physnerf::real::{Real, linspace};
use neurofluid_physnerf::renderer::{RenderOutput, mse};
use neurofluid_physnerf::safetensors_file::{StFile, StWriter};
use neurofluid_physnerf::weights::{CONFIG_KEY, NETS};
use neurofluid_physnerf::{
    EncodingTerms, PhysNerf, PhysNerfConfig, PhysNerfError, RayBatch, Result,
};

/// The `render_config` metadata entry of a case file.
#[derive(Debug, Clone, Deserialize)]
struct RenderConfigMeta {
    near: f64,
    far: f64,
    n_samples: usize,
    n_importance: usize,
    radius: f64,
    k: usize,
    flags: EncodingTerms,
    white_back: bool,
}

/// The inputs stored in a case file.
#[derive(Debug, Clone)]
pub struct CaseInputs {
    /// The case file.
    pub path: PathBuf,
    /// Renderer configuration from the `render_config` metadata.
    pub config: PhysNerfConfig,
    /// Image height and width (`camera/hw`).
    pub hw: [usize; 2],
    /// Focal length in pixels (`camera/focal`).
    pub focal: f64,
    /// Camera-to-world matrix, row-major (`camera/c2w`).
    pub c2w: [[f64; 4]; 4],
    /// Particle positions (`particles`).
    pub particles: Vec<[f64; 3]>,
    /// Rays of the loss (`loss/ray_ids`).
    pub ray_ids: Vec<usize>,
    /// Target colours of those rays (`loss/target`).
    pub target: Vec<[f64; 3]>,
}

fn rows3(v: &[f64]) -> Vec<[f64; 3]> {
    v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}

impl CaseInputs {
    /// Reads a case file; errors name the file and the missing or malformed entry.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let f = StFile::open(&path)?;
        let meta = f.metadata()?;
        let meta_err = |message: String| PhysNerfError::Metadata {
            path: path.clone(),
            field: "render_config".into(),
            message,
        };
        let rc = meta
            .get("render_config")
            .ok_or_else(|| meta_err("missing".into()))?;
        let rc: RenderConfigMeta = serde_json::from_str(rc).map_err(|e| meta_err(e.to_string()))?;
        let config = PhysNerfConfig {
            near: rc.near,
            far: rc.far,
            n_samples: rc.n_samples,
            n_importance: rc.n_importance,
            search_radius: rc.radius,
            k: rc.k,
            encoding: rc.flags,
            white_background: rc.white_back,
            ..PhysNerfConfig::default()
        };
        config.validate().map_err(meta_err)?;
        let (_, hw) = f.ints("camera/hw", Some(&[2]))?;
        if hw.iter().any(|&v| v <= 0) {
            return Err(PhysNerfError::Mismatch {
                path,
                name: "camera/hw".into(),
                expected: "two positive sizes".into(),
                found: format!("{hw:?}"),
            });
        }
        let (_, focal) = f.floats("camera/focal", Some(&[1]))?;
        let (_, c2w) = f.floats("camera/c2w", Some(&[4, 4]))?;
        let (pshape, particles) = f.floats("particles", None)?;
        if pshape.len() != 2 || pshape[1] != 3 {
            return Err(PhysNerfError::Mismatch {
                path,
                name: "particles".into(),
                expected: "shape [N, 3]".into(),
                found: format!("shape {pshape:?}"),
            });
        }
        let n_rays = (hw[0] * hw[1]) as usize;
        let (_, ids) = f.ints("loss/ray_ids", None)?;
        if let Some(bad) = ids.iter().find(|&&i| i < 0 || i as usize >= n_rays) {
            return Err(PhysNerfError::Mismatch {
                path,
                name: "loss/ray_ids".into(),
                expected: format!("ray indices in 0..{n_rays}"),
                found: format!("{bad}"),
            });
        }
        let (_, target) = f.floats("loss/target", Some(&[ids.len(), 3]))?;
        let mut m = [[0.0; 4]; 4];
        for (i, row) in m.iter_mut().enumerate() {
            row.copy_from_slice(&c2w[i * 4..i * 4 + 4]);
        }
        Ok(Self {
            path,
            config,
            hw: [hw[0] as usize, hw[1] as usize],
            focal: focal[0],
            c2w: m,
            particles: rows3(&particles),
            ray_ids: ids.into_iter().map(|i| i as usize).collect(),
            target: rows3(&target),
        })
    }

    /// The default weights file: `<case stem>_weights.safetensors` beside the case.
    pub fn weights_path(&self) -> PathBuf {
        let stem = self
            .path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        self.path
            .with_file_name(format!("{stem}_weights.safetensors"))
    }

    /// The particles as a `[N, 3]` tensor on `device` in `dtype` (rounded to nearest for F32).
    pub fn particles_tensor(&self, device: &Device, dtype: DType) -> Tensor<2> {
        let flat: Vec<f64> = self.particles.iter().flatten().copied().collect();
        neurofluid_core::transfer::upload(
            TensorData::new(flat, [self.particles.len(), 3]),
            (device, dtype),
        )
    }

    /// Every pixel's ray, row-major (`r = row·W + col`), computed in the precision T exactly as
    /// the reference does: `d_cam = ((i − W/2)/f, −(j − H/2)/f, −1)`, `d = R·d_cam`, normalised.
    pub fn rays<T: Real>(&self) -> RayBatch {
        let [h, w] = self.hw;
        let f = T::of(self.focal);
        let rm: Vec<[T; 3]> = (0..3)
            .map(|a| [0, 1, 2].map(|b| T::of(self.c2w[a][b])))
            .collect();
        let o = [0, 1, 2].map(|a| self.c2w[a][3]);
        let (hw2, hh2) = (T::of(w as f64 / 2.0), T::of(h as f64 / 2.0));
        let mut dirs = Vec::with_capacity(h * w);
        for j in 0..h {
            for i in 0..w {
                let dc = [
                    (T::of(i as f64) - hw2) / f,
                    -(T::of(j as f64) - hh2) / f,
                    -T::one(),
                ];
                let d: [T; 3] =
                    [0, 1, 2].map(|a| dc[0] * rm[a][0] + dc[1] * rm[a][1] + dc[2] * rm[a][2]);
                let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                dirs.push(d.map(|c| (c / n).f64()));
            }
        }
        RayBatch {
            origins: vec![o.map(|c| T::of(c).f64()); h * w],
            dirs,
        }
    }
}

/// A named float array: shape and values.
pub type FloatArrays = BTreeMap<String, (Vec<usize>, Vec<f64>)>;

/// The outputs of a case run, keyed as in the reference file.
#[derive(Debug, Clone, Default)]
pub struct CaseOutputs {
    /// Float arrays: shape and values.
    pub floats: FloatArrays,
    /// Integer arrays: shape, values and storage (`"u8"`, `"u16"`, `"i32"`).
    pub ints: BTreeMap<String, (Vec<usize>, Vec<i64>, &'static str)>,
    /// Names of `gradnorm/values`, sorted.
    pub gradnorm_names: Vec<String>,
    /// The dtype the case ran in.
    pub dtype: Option<DType>,
}

impl CaseOutputs {
    /// A float array by key.
    pub fn float(&self, key: &str) -> &[f64] {
        &self
            .floats
            .get(key)
            .unwrap_or_else(|| panic!("no output {key}"))
            .1
    }

    /// An integer array by key.
    pub fn int(&self, key: &str) -> &[i64] {
        &self
            .ints
            .get(key)
            .unwrap_or_else(|| panic!("no output {key}"))
            .1
    }

    /// Writes every output to a safetensors file (floats as F64 for an F64 run, else F32).
    pub fn write(&self, path: impl AsRef<Path>) -> Result<()> {
        let as_f64 = self.dtype == Some(DType::F64);
        let mut w = StWriter::new();
        for (k, (shape, v)) in &self.floats {
            w.float(k, shape, v, as_f64);
        }
        for (k, (shape, v, kind)) in &self.ints {
            match *kind {
                "u8" => w.u8(k, shape, &v.iter().map(|&x| x as u8).collect::<Vec<_>>()),
                "u16" => w.u16(k, shape, &v.iter().map(|&x| x as u32).collect::<Vec<_>>()),
                _ => w.i32(k, shape, &v.iter().map(|&x| x as i32).collect::<Vec<_>>()),
            }
        }
        w.meta(
            "gradnorm_names",
            serde_json::to_string(&self.gradnorm_names).expect("names serialise"),
        );
        w.meta("generated_by", "neurofluid-physnerf".into());
        w.write(path)
    }
}

fn vec_of<const D: usize>(t: Tensor<D>) -> Result<Vec<f64>> {
    neurofluid_core::transfer::read_vec(t).map_err(|e| PhysNerfError::Readback(format!("{e:?}")))
}

/// Small gradients stored per network (besides the first layer).
pub const GRAD_SMALL: [&str; 7] = [
    "sigma.weight",
    "sigma.bias",
    "rgb.0.weight",
    "rgb.0.bias",
    "dir_encoding.0.bias",
    "xyz_encoding_5.0.bias",
    "xyz_encoding_final.bias",
];

/// Every parameter gradient of the model in PyTorch layout, keyed `nerf_{coarse,fine}.<name>`.
pub fn parameter_grads(model: &PhysNerf, grads: &Gradients) -> Result<FloatArrays> {
    let mut out = BTreeMap::new();
    for (prefix, net) in NETS.iter().zip([&model.coarse, &model.fine]) {
        for (name, layer) in net.named_layers() {
            let w = layer.weight.val();
            let [d_in, d_out] = w.dims();
            let g = match w.grad(grads) {
                Some(g) => vec_of(g.transpose())?,
                None => vec![0.0; d_in * d_out],
            };
            out.insert(format!("{prefix}.{name}.weight"), (vec![d_out, d_in], g));
            if let Some(b) = &layer.bias {
                let b = b.val();
                let g = match b.grad(grads) {
                    Some(g) => vec_of(g)?,
                    None => vec![0.0; d_out],
                };
                out.insert(format!("{prefix}.{name}.bias"), (vec![d_out], g));
            }
        }
    }
    Ok(out)
}

/// Renders a case with `model` (which must live on an autodiff device, in the dtype to run in),
/// computes the loss and its gradients, and collects the outputs.
pub fn run_case(inputs: &CaseInputs, model: &PhysNerf) -> Result<CaseOutputs> {
    let dtype = model.dtype();
    let device = model.coarse.sigma.weight.val().device();
    let rays = match dtype {
        DType::F64 => inputs.rays::<f64>(),
        _ => inputs.rays::<f32>(),
    };
    let n = inputs.particles.len();
    let particles = inputs.particles_tensor(&device, dtype).require_grad();
    let out: RenderOutput = model.render_rays(&particles, &rays, None)?;
    let r = rays.len();
    let mut res = CaseOutputs {
        dtype: Some(dtype),
        ..Default::default()
    };
    let flat3 = |v: &[[f64; 3]]| v.iter().flatten().copied().collect::<Vec<f64>>();
    res.floats
        .insert("rays/o".into(), (vec![r, 3], flat3(&rays.origins)));
    res.floats
        .insert("rays/d".into(), (vec![r, 3], flat3(&rays.dirs)));
    let s = out.coarse.samples;
    res.floats
        .insert("coarse/z".into(), (vec![s], out.coarse.z[..s].to_vec()));
    let mut passes = vec![("coarse", &out.coarse)];
    if let Some(f) = &out.fine {
        passes.push(("fine", f));
        let ni = out.z_importance.len() / r.max(1);
        res.floats.insert(
            "fine/z_importance".into(),
            (vec![r, ni], out.z_importance.clone()),
        );
        res.floats
            .insert("fine/z".into(), (vec![r, f.samples], f.z.clone()));
        let u: Vec<f64> = match dtype {
            DType::F64 => linspace(0.0f64, 1.0, ni),
            _ => linspace(0.0f32, 1.0, ni)
                .into_iter()
                .map(f64::from)
                .collect(),
        };
        res.floats.insert("fine/u".into(), (vec![ni], u));
    }
    for (tag, p) in &passes {
        let s = p.samples;
        res.floats.insert(
            format!("{tag}/weights"),
            (vec![r, s], vec_of(p.weights.clone())?),
        );
        res.floats.insert(
            format!("{tag}/rgb_map"),
            (vec![r, 3], vec_of(p.rgb_map.clone())?),
        );
        res.floats
            .insert(format!("{tag}/acc"), (vec![r], vec_of(p.acc.clone())?));
        res.ints.insert(
            format!("{tag}/num_nn"),
            (
                vec![r, s],
                p.num_nn.iter().map(|&v| v as i64).collect(),
                "u8",
            ),
        );
        res.ints.insert(
            format!("{tag}/mask"),
            (vec![r, s], p.mask.iter().map(|&v| v as i64).collect(), "u8"),
        );
        res.ints.insert(
            format!("{tag}/nbr_idx_sum"),
            (
                vec![r, s],
                p.nbr_idx_sum.iter().map(|&v| v as i64).collect(),
                "u16",
            ),
        );
    }
    // loss on the case's rays
    let ids = RowIndex::new(inputs.ray_ids.iter().copied(), &device);
    let target: Tensor<2> = neurofluid_core::transfer::upload(
        TensorData::new(flat3(&inputs.target), [inputs.target.len(), 3]),
        (&device, dtype),
    );
    let lc = mse(
        gather_rows(out.coarse.rgb_map.clone(), &ids),
        target.clone(),
    );
    let lf = match &out.fine {
        Some(f) => mse(gather_rows(f.rgb_map.clone(), &ids), target),
        None => lc.zeros_like(),
    };
    let loss = lc.clone() + lf.clone();
    res.floats.insert(
        "loss/mse_coarse".into(),
        (vec![1], vec_of(lc.clone().detach())?),
    );
    res.floats.insert(
        "loss/mse_fine".into(),
        (vec![1], vec_of(lf.clone().detach())?),
    );
    res.floats.insert(
        "loss/value".into(),
        (vec![1], vec_of(loss.clone().detach())?),
    );
    let grads = loss.backward();
    let gp = match particles.grad(&grads) {
        Some(g) => vec_of(g)?,
        None => vec![0.0; n * 3],
    };
    res.floats.insert("grad/particles".into(), (vec![n, 3], gp));
    let pg = parameter_grads(model, &grads)?;
    for prefix in NETS {
        let first = format!("{prefix}.xyz_encoding_1.0.weight");
        res.floats
            .insert(format!("grad/{first}"), pg[&first].clone());
        for k in GRAD_SMALL {
            let key = format!("{prefix}.{k}");
            res.floats.insert(format!("grad/{key}"), pg[&key].clone());
        }
    }
    let norms: Vec<f64> = pg
        .values()
        .map(|(_, v)| v.iter().map(|x| x * x).sum::<f64>().sqrt())
        .collect();
    res.gradnorm_names = pg.keys().cloned().collect();
    res.floats
        .insert("gradnorm/values".into(), (vec![norms.len()], norms));
    Ok(res)
}

/// Loads the weights for a case: `weights` if given, else the case's
/// `<stem>_weights.safetensors` sibling. A file written by [`PhysNerf::save`] brings its own
/// configuration; a plain nerf_pl file is read with the case's configuration.
pub fn load_case_model(
    inputs: &CaseInputs,
    weights: Option<&Path>,
    device: &Device,
    dtype: DType,
) -> Result<PhysNerf> {
    let path = weights
        .map(Path::to_path_buf)
        .unwrap_or_else(|| inputs.weights_path());
    let has_config = StFile::open(&path)?.metadata()?.contains_key(CONFIG_KEY);
    if has_config {
        PhysNerf::load(&path, device, dtype)
    } else {
        PhysNerf::from_nerf_pl(&path, inputs.config.clone(), device, dtype)
    }
}

/// Renders the case file `case` (weights as in [`load_case_model`]) with loss and gradients on
/// `device` (made autodiff here) in `dtype`, and writes the outputs to `output`.
pub fn run_case_file(
    case: &Path,
    weights: Option<&Path>,
    output: &Path,
    device: &Device,
    dtype: DType,
) -> Result<CaseOutputs> {
    let inputs = CaseInputs::load(case)?;
    let model = load_case_model(&inputs, weights, &device.clone().autodiff(), dtype)?;
    let out = run_case(&inputs, &model)?;
    out.write(output)?;
    Ok(out)
}

impl CaseInputs {
    /// The case's camera, optionally at another resolution `[H, W]` (focal scaled with W, so the
    /// field of view stays the same).
    pub fn camera(&self, hw: Option<[u32; 2]>) -> neurofluid_core::camera::Camera {
        let [h, w] = hw.unwrap_or([self.hw[0] as u32, self.hw[1] as u32]);
        let focal = self.focal * w as f64 / self.hw[1] as f64;
        neurofluid_core::camera::Camera::centred(
            w,
            h,
            focal as f32,
            self.c2w.map(|row| row.map(|v| v as f32)),
        )
    }
}
