//! Whole-view rendering in chunks: agrees with the reference colours at the case's own
//! resolution, does not depend on the chunk size, shows an opaque blob on exact white, and
//! round-trips through PNG.

use crate::common;

use burn::tensor::DType;
use common::*;
use neurofluid_physnerf::{render_image, save_png};

#[test]
fn chunked_view_matches_reference_and_chunk_size() {
    let (inputs, file) = case();
    let device = neurofluid_core::device::test_device();
    let model = model(&inputs, &device, DType::F32);
    let p = inputs.particles_tensor(&device, DType::F32);
    let cam = inputs.camera(None);
    let mut calls = 0;
    let a = render_image(&model, &cam, &p, 37, &mut |_, _| calls += 1).expect("render");
    assert_eq!(calls, 256usize.div_ceil(37));
    let b = render_image(&model, &cam, &p, 4096, &mut |_, _| {}).expect("render");
    let to64 = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<_>>();
    assert_close(
        "chunk 37 vs 4096 (fine)",
        &to64(&a.fine),
        &to64(&b.fine),
        1e-5,
    );
    assert_close(
        "chunk 37 vs 4096 (coarse)",
        &to64(&a.coarse),
        &to64(&b.coarse),
        1e-5,
    );
    // the same rays as the case: table C statistics against the reference
    let want = refv(&file, "fine/rgb_map");
    let errs: Vec<f64> = to64(&a.fine)
        .chunks(3)
        .zip(want.chunks(3))
        .map(|(x, y)| max_abs(x, y))
        .collect();
    let within = errs.iter().filter(|&&e| e <= 3e-3).count() as f64 / errs.len() as f64;
    assert!(
        within >= 0.95,
        "only {within} of the pixels within 3e-3 of the reference"
    );
    assert_close(
        "coarse view vs reference",
        &to64(&a.coarse),
        &refv(&file, "coarse/rgb_map"),
        1e-3,
    );
}

#[test]
fn blob_is_opaque_on_white_and_png_roundtrips() {
    let (inputs, _) = case();
    let device = neurofluid_core::device::test_device();
    let model = model(&inputs, &device, DType::F32);
    let p = inputs.particles_tensor(&device, DType::F32);
    let cam = inputs.camera(Some([24, 24]));
    let img = render_image(&model, &cam, &p, 256, &mut |_, _| {}).expect("render");
    let px = |r: usize, c: usize| &img.fine[(r * 24 + c) * 3..(r * 24 + c) * 3 + 3];
    for (r, c) in [(0, 0), (0, 23), (23, 0), (23, 23)] {
        assert_eq!(
            px(r, c),
            &[1.0, 1.0, 1.0],
            "background pixel ({r}, {c}) must be exact white"
        );
    }
    let centre = px(12, 12);
    assert!(
        centre.iter().any(|&v| v < 0.9),
        "the blob centre must not be white: {centre:?}"
    );
    // textured: the blob's pixels are not all one colour
    let hit: Vec<&[f32]> = img
        .fine
        .chunks(3)
        .filter(|c| c.iter().any(|&v| v < 0.99))
        .collect();
    assert!(hit.len() > 20, "{} blob pixels", hit.len());
    let spread = hit.iter().map(|c| c[0]).fold(f32::MIN, f32::max)
        - hit.iter().map(|c| c[0]).fold(f32::MAX, f32::min);
    assert!(spread > 0.1, "red channel spread {spread}");

    let dir = std::env::temp_dir().join(format!("nf_render_{}", std::process::id()));
    let path = dir.join("blob.png");
    save_png(&path, 24, 24, &img.fine).expect("png");
    let back = image::open(&path).expect("read png").to_rgb8();
    assert_eq!(back.dimensions(), (24, 24));
    let c = back.get_pixel(12, 12).0;
    for a in 0..3 {
        assert_eq!(c[a], (centre[a].clamp(0.0, 1.0) * 255.0).round() as u8);
    }
    assert!(
        save_png(&path, 24, 23, &img.fine).is_err(),
        "a wrong size must be rejected"
    );
    std::fs::remove_dir_all(dir).ok();
}

/// A model and particles that live on an autodiff device (as during training) render too.
#[test]
fn renders_from_an_autodiff_model() {
    let (inputs, _) = case();
    let device = neurofluid_core::device::test_device().autodiff();
    let model = model(&inputs, &device, DType::F32);
    let p = inputs.particles_tensor(&device, DType::F32).require_grad();
    let cam = inputs.camera(Some([8, 8]));
    let img = render_image(&model, &cam, &p, 16, &mut |_, _| {}).expect("render");
    assert_eq!(img.fine.len(), 8 * 8 * 3);
    assert!(img.fine.iter().any(|&v| v < 0.9), "the blob must show");
}
