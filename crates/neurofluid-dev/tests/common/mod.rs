//! Shared helpers of the parity tests: the stored reference case and comparisons.
#![allow(dead_code)]

use std::path::PathBuf;

use burn::prelude::*;
use burn::tensor::DType;
use neurofluid_dev::physnerf_case::CaseInputs;
use neurofluid_physnerf::PhysNerf;
use neurofluid_physnerf::safetensors_file::StFile;

/// `tests/data/physnerf` of the workspace.
pub fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/physnerf")
}

/// The stored case file.
pub fn case_path() -> PathBuf {
    data_dir().join("physnerf_cube2197.safetensors")
}

/// The case inputs and the reference file.
pub fn case() -> (CaseInputs, StFile) {
    let inputs = CaseInputs::load(case_path()).expect("case inputs");
    let file = StFile::open(case_path()).expect("case file");
    (inputs, file)
}

/// The case's weights on `device` in `dtype`.
pub fn model(inputs: &CaseInputs, device: &Device, dtype: DType) -> PhysNerf {
    PhysNerf::from_nerf_pl(inputs.weights_path(), inputs.config.clone(), device, dtype)
        .expect("weights")
}

/// A float array of the reference.
pub fn refv(f: &StFile, key: &str) -> Vec<f64> {
    f.floats(key, None).unwrap_or_else(|e| panic!("{e}")).1
}

/// An integer array of the reference.
pub fn refi(f: &StFile, key: &str) -> Vec<i64> {
    f.ints(key, None).unwrap_or_else(|e| panic!("{e}")).1
}

/// Max |a − b|.
pub fn max_abs(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len(), "length mismatch");
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

/// Asserts max |a − b| ≤ atol, naming the quantity.
pub fn assert_close(name: &str, a: &[f64], b: &[f64], atol: f64) {
    let m = max_abs(a, b);
    assert!(m <= atol, "{name}: max |Δ| = {m:e} > {atol:e}");
    eprintln!("{name}: max |Δ| = {m:.3e} (atol {atol:e})");
}

/// ‖a − b‖ / ‖b‖.
pub fn rel_norm(a: &[f64], b: &[f64]) -> f64 {
    let num: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt();
    let den: f64 = b.iter().map(|y| y * y).sum::<f64>().sqrt();
    num / den.max(1e-300)
}

/// Cosine similarity.
pub fn cosine(a: &[f64], b: &[f64]) -> f64 {
    let dot: f64 = a.iter().zip(b).map(|(x, y)| x * y).sum();
    let na: f64 = a.iter().map(|x| x * x).sum::<f64>().sqrt();
    let nb: f64 = b.iter().map(|y| y * y).sum::<f64>().sqrt();
    dot / (na * nb).max(1e-300)
}

/// A tensor's values as f64.
pub fn vals<const D: usize>(t: Tensor<D>) -> Vec<f64> {
    t.try_into_vec_as::<f64>().expect("read back")
}
