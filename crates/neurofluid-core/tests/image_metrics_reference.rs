//! PSNR and SSIM against scikit-image on a stored case (tests/data/metrics).

use neurofluid_core::metrics::{RgbImage, psnr, ssim};
use neurofluid_core::npz::NpzReader;

#[test]
fn psnr_and_ssim_match_scikit_image() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/data/metrics/image_metrics_case.npz"
    );
    let mut npz = NpzReader::open(path).unwrap();
    let image = |a: neurofluid_core::npz::Array<f32>| {
        assert_eq!(a.shape.len(), 3);
        RgbImage::new(a.shape[1], a.shape[0], a.data).unwrap()
    };
    let a = image(npz.f32("a").unwrap());
    let b = image(npz.f32("b").unwrap());
    let ssim_ref = npz.f64("ssim").unwrap().data[0];
    let psnr_ref = npz.f64("psnr").unwrap().data[0];
    let s = ssim(&a, &b).unwrap();
    let p = psnr(&a, &b).unwrap();
    assert!(
        (s - ssim_ref).abs() < 1e-6,
        "ssim {s} vs scikit-image {ssim_ref}"
    );
    assert!(
        (p - psnr_ref).abs() < 1e-6,
        "psnr {p} vs scikit-image {psnr_ref}"
    );
}
