//! End-to-end float64 parity with the `f64/` keys of the reference case (README table A):
//! the precise test. Skipped (with a message) on a device without F64.

use crate::common;

use burn::tensor::DType;
use common::*;
use neurofluid_dev::physnerf_case::run_case;

#[test]
fn float64_case_matches_reference_precisely() {
    let device = neurofluid_core::device::test_device();
    if !neurofluid_core::device::test_device_has_float64() {
        eprintln!("skipped: the device has no F64");
        return;
    }
    let device = device.autodiff();
    let (inputs, file) = case();
    let model = model(&inputs, &device, DType::F64);
    let out = run_case(&inputs, &model).expect("run");

    for key in [
        "rays/o",
        "rays/d",
        "coarse/weights",
        "coarse/rgb_map",
        "coarse/acc",
        "fine/rgb_map",
        "fine/acc",
        "loss/value",
        "loss/mse_coarse",
        "loss/mse_fine",
    ] {
        assert_close(
            key,
            out.float(key),
            &refv(&file, &format!("f64/{key}")),
            1e-9,
        );
    }
    for key in [
        "coarse/num_nn",
        "coarse/nbr_idx_sum",
        "fine/num_nn",
        "fine/nbr_idx_sum",
    ] {
        assert_eq!(
            out.int(key),
            refi(&file, &format!("f64/{key}")).as_slice(),
            "{key}"
        );
    }
    // importance depths: columns 0..126 tight; column 127 (u = 1) may legitimately sit anywhere
    // in [bins[61], bins[62]] (tests/data/physnerf/README.md, "sample_pdf has a threshold")
    let (zi, zr) = (
        out.float("fine/z_importance"),
        refv(&file, "f64/fine/z_importance"),
    );
    let z = out.float("coarse/z");
    let (b61, b62) = (0.5 * (z[61] + z[62]), 0.5 * (z[62] + z[63]));
    let mut worst = 0.0f64;
    for (a, b) in zi.chunks(128).zip(zr.chunks(128)) {
        worst = worst.max(max_abs(&a[..127], &b[..127]));
        let last = a[127];
        assert!(
            (last - b62).abs() <= 1e-9 || (b61 - 1e-9..=b62 + 1e-9).contains(&last),
            "u = 1 sample {last} outside [bins[61], bins[62]]"
        );
    }
    eprintln!("fine/z_importance cols 0..126: max |Δ| = {worst:.3e}");
    assert!(worst <= 1e-9, "fine/z_importance: {worst}");

    let mut keys = vec![
        "grad/particles".to_string(),
        "grad/nerf_coarse.xyz_encoding_1.0.weight".into(),
        "grad/nerf_fine.xyz_encoding_1.0.weight".into(),
        "gradnorm/values".into(),
    ];
    for net in ["nerf_coarse", "nerf_fine"] {
        for k in neurofluid_dev::physnerf_case::GRAD_SMALL {
            keys.push(format!("grad/{net}.{k}"));
        }
    }
    for key in keys {
        let (a, b) = (out.float(&key), refv(&file, &format!("f64/{key}")));
        let rn = rel_norm(a, &b);
        let maxref = b.iter().map(|v| v.abs()).fold(0.0, f64::max);
        let ma = max_abs(a, &b);
        eprintln!(
            "{key}: rel norm {rn:.3e}, max-abs/max|ref| {:.3e}",
            ma / maxref.max(1e-300)
        );
        assert!(rn <= 1e-7, "{key}: rel norm {rn}");
        assert!(
            ma <= 1e-7 * maxref,
            "{key}: max-abs {ma} vs max|ref| {maxref}"
        );
    }
}
