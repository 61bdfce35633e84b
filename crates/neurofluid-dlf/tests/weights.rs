//! Weight import (PyTorch `.pt`, `.safetensors`), strict name/shape checking, and our own
//! checkpoints.

use crate::common;

use std::path::Path;

use burn::module::Module;
use burn::prelude::*;
use common::*;
use neurofluid_dlf::weights::{
    NamedTensor, WeightsError, net_from_tensors, read_pytorch, read_safetensors,
};
use neurofluid_dlf::{DlfConfig, DlfNet, load_checkpoint, load_dlf, save_checkpoint};

fn flat_params(net: &DlfNet) -> Vec<f32> {
    let mut v = Vec::new();
    for c in [
        &net.conv0_fluid,
        &net.conv0_obstacle,
        &net.conv1,
        &net.conv2,
        &net.conv3,
    ] {
        let k = c.kernel.val();
        let n = k.shape().num_elements();
        v.extend(host(&k.reshape([1, n])));
        v.extend(host(&c.bias.val().unsqueeze_dim::<2>(0)));
    }
    for l in [&net.dense0_fluid, &net.dense1, &net.dense2, &net.dense3] {
        v.extend(host(&l.weight.val()));
        v.extend(host(&l.bias.as_ref().unwrap().val().unsqueeze_dim::<2>(0)));
    }
    v
}

#[test]
fn pt_and_safetensors_hold_the_same_model() {
    let device = device();
    let a = load_dlf(
        &weights("pretrained_model_weights.pt"),
        DlfConfig::default(),
        &device,
    )
    .unwrap();
    let b = load_dlf(
        &weights("pretrained_model_weights.safetensors"),
        DlfConfig::default(),
        &device,
    )
    .unwrap();
    assert_eq!(a.num_params(), 692_902);
    assert_eq!(flat_params(&a), flat_params(&b));
    let raw = read_pytorch(&weights("pretrained_model_weights.pt")).unwrap();
    assert_eq!(raw.len(), 24);
    // torch Linear [out, in] is stored transposed in Burn
    let w = &raw["dense1.weight"];
    assert_eq!(w.shape, vec![64, 96]);
    let burn_w = host(&a.dense1.weight.val());
    assert_eq!(burn_w[5 * 64 + 7], w.data[7 * 96 + 5]);
}

fn apply(map: std::collections::BTreeMap<String, NamedTensor>) -> Result<DlfNet, WeightsError> {
    net_from_tensors(
        map,
        Path::new("w.safetensors"),
        DlfConfig::default(),
        &device(),
    )
}

#[test]
fn missing_unexpected_misshaped_and_bad_tensors_are_named() {
    let base = read_safetensors(&weights("pretrained_model_weights.safetensors")).unwrap();
    let mut m = base.clone();
    m.remove("conv2.kernel");
    let e = apply(m).unwrap_err().to_string();
    assert!(
        e.contains("w.safetensors") && e.contains("`conv2.kernel` is missing"),
        "{e}"
    );

    let mut m = base.clone();
    m.insert(
        "conv4.kernel".into(),
        NamedTensor {
            shape: vec![1],
            data: vec![0.0],
        },
    );
    let e = apply(m).unwrap_err().to_string();
    assert!(e.contains("unexpected tensor `conv4.kernel`"), "{e}");

    let mut m = base.clone();
    let t = m.get_mut("dense3.bias").unwrap();
    t.shape = vec![1, 3];
    let e = apply(m).unwrap_err().to_string();
    assert!(
        e.contains("`dense3.bias` has shape [1, 3], expected [3]"),
        "{e}"
    );

    let mut m = base.clone();
    m.get_mut("conv1.offset").unwrap().data[1] = 0.5;
    let e = apply(m).unwrap_err().to_string();
    assert!(
        e.contains("`conv1.offset`") && e.contains("not zero"),
        "{e}"
    );

    let mut m = base;
    m.get_mut("conv3.bias").unwrap().data[0] = f32::NAN;
    let e = apply(m).unwrap_err().to_string();
    assert!(e.contains("`conv3.bias`") && e.contains("NaN"), "{e}");

    let e = load_dlf(
        Path::new("nope/missing.pt"),
        DlfConfig::default(),
        &device(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("nope/missing.pt"), "{e}");
}

#[test]
fn checkpoints_roundtrip_atomically() {
    let device = device();
    let net = pretrained(&device);
    let dir = std::env::temp_dir().join(format!("nf_dlf_ckpt_{}", std::process::id()));
    let path = dir.join("sub").join("model.bpk");
    save_checkpoint(&net, &path).unwrap();
    let files: Vec<_> = std::fs::read_dir(path.parent().unwrap())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(
        files,
        vec![std::ffi::OsString::from("model.bpk")],
        "temp file left behind"
    );
    let back = load_checkpoint(&path, DlfConfig::default(), &device).unwrap();
    assert_eq!(flat_params(&back), flat_params(&net));
    let via_ext = load_dlf(&path, DlfConfig::default(), &device).unwrap();
    assert_eq!(flat_params(&via_ext), flat_params(&net));
    std::fs::write(dir.join("junk.bpk"), b"not a burnpack").unwrap();
    let e = load_checkpoint(&dir.join("junk.bpk"), DlfConfig::default(), &device)
        .unwrap_err()
        .to_string();
    assert!(e.contains("junk.bpk"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
    let _ = Tensor::<1>::zeros([1], &device);
}
