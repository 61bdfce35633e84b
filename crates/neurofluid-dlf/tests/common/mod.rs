//! Shared helpers of the DLF integration tests: paths to the stored reference cases and
//! comparison utilities.
#![allow(dead_code)]

use std::path::PathBuf;

use burn::prelude::*;
use neurofluid_core::npz::NpzReader;
use neurofluid_dlf::{Boundary, DlfConfig, DlfNet, load_dlf};

/// `tests/data/dlf/<name>` of the workspace.
pub fn case(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data/dlf")
        .join(name)
}

/// `assets/dlf_pretrained/<name>` of the workspace.
pub fn weights(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../assets/dlf_pretrained")
        .join(name)
}

/// The device the tests run on: `$NEUROFLUID_TEST_DEVICE`, else the CPU.
pub fn device() -> Device {
    neurofluid_core::device::test_device()
}

/// The pretrained network on `device`.
pub fn pretrained(device: &Device) -> DlfNet {
    load_dlf(
        &weights("pretrained_model_weights.pt"),
        DlfConfig::default(),
        device,
    )
    .expect("pretrained weights load")
}

/// The input scene of a stored case, as the crate's own scene type.
pub type Scene = neurofluid_dlf::scene::BoxScene;

/// Stored-case loading and the boundary of a scene, for the parity tests.
pub trait CaseScene: Sized {
    /// Reads `<name>_in.npz`.
    fn load(name: &str) -> Self;
    /// The boundary for `net`.
    fn boundary(&self, net: &DlfNet, device: &Device) -> Boundary;
}

impl CaseScene for Scene {
    fn load(name: &str) -> Self {
        let mut r = NpzReader::open(case(&format!("{name}_in.npz"))).expect("input case");
        let v3 = |a: Vec<f32>| [a[0], a[1], a[2]];
        Self {
            pos: r.points("pos").unwrap(),
            vel: r.points("vel").unwrap(),
            box_points: r.points("box").unwrap(),
            box_normals: r.points("box_normals").unwrap(),
            box_lo: v3(r.f32("box_lo").unwrap().data),
            box_hi: v3(r.f32("box_hi").unwrap().data),
        }
    }

    fn boundary(&self, net: &DlfNet, device: &Device) -> Boundary {
        net.boundary(&self.box_points, &self.box_normals, device)
    }
}

/// max |a − b| / max |b| (relative to the reference's largest magnitude).
pub fn rel_err(a: &[f32], b: &[f32]) -> f64 {
    assert_eq!(a.len(), b.len(), "lengths differ");
    let scale = b.iter().fold(0f64, |m, &x| m.max(x.abs() as f64)) + 1e-30;
    let diff = a
        .iter()
        .zip(b)
        .fold(0f64, |m, (&x, &y)| m.max((x as f64 - y as f64).abs()));
    diff / scale
}

/// Flattens points.
pub fn flat(points: &[[f32; 3]]) -> Vec<f32> {
    points.iter().flatten().copied().collect()
}

/// Host copy of a float tensor.
pub fn host(t: &Tensor<2>) -> Vec<f32> {
    t.to_data().convert::<f32>().try_into_vec::<f32>().unwrap()
}

/// A `[N, 3]` tensor from points.
pub fn to_tensor(points: &[[f32; 3]], device: &Device) -> Tensor<2> {
    neurofluid_core::tensors::points_tensor(points, device)
}
