//! End-to-end float32 parity with the stored reference case (README table C).

use crate::common;

use burn::tensor::DType;
use common::*;
use neurofluid_dev::physnerf_case::run_case;

/// Per-ray max-abs colour differences.
fn ray_errors(a: &[f64], b: &[f64]) -> Vec<f64> {
    a.chunks(3)
        .zip(b.chunks(3))
        .map(|(x, y)| max_abs(x, y))
        .collect()
}

fn frac_within(errs: &[f64], tol: f64) -> f64 {
    errs.iter().filter(|&&e| e <= tol).count() as f64 / errs.len() as f64
}

#[test]
fn float32_case_matches_reference_statistically() {
    let (inputs, file) = case();
    let device = neurofluid_core::device::test_device().autodiff();
    let model = model(&inputs, &device, DType::F32);
    let out = run_case(&inputs, &model).expect("run");

    assert_close("rays/o", out.float("rays/o"), &refv(&file, "rays/o"), 1e-6);
    assert_close("rays/d", out.float("rays/d"), &refv(&file, "rays/d"), 1e-6);
    assert_close(
        "coarse/z",
        out.float("coarse/z"),
        &refv(&file, "coarse/z"),
        1e-6,
    );

    let ec = ray_errors(out.float("coarse/rgb_map"), &refv(&file, "coarse/rgb_map"));
    let ef = ray_errors(out.float("fine/rgb_map"), &refv(&file, "fine/rgb_map"));
    let (c3, f3, f33) = (
        frac_within(&ec, 3e-4),
        frac_within(&ef, 3e-4),
        frac_within(&ef, 3e-3),
    );
    let worst = ec.iter().chain(&ef).copied().fold(0.0, f64::max);
    eprintln!("coarse ≤3e-4: {c3:.4}; fine ≤3e-4: {f3:.4}, ≤3e-3: {f33:.4}; worst {worst:.3e}");
    assert!(c3 >= 0.99, "coarse rgb: only {c3} of rays within 3e-4");
    assert!(f3 >= 0.85, "fine rgb: only {f3} of rays within 3e-4");
    assert!(f33 >= 0.95, "fine rgb: only {f33} of rays within 3e-3");
    assert!(worst <= 5e-2, "a ray is off by {worst}");

    let (l, lr) = (out.float("loss/value")[0], refv(&file, "loss/value")[0]);
    eprintln!("loss {l} vs {lr}");
    assert!(((l - lr) / lr).abs() <= 1e-4, "loss {l} vs reference {lr}");

    for key in ["grad/particles", "grad/nerf_coarse.xyz_encoding_1.0.weight"] {
        let (a, b) = (out.float(key), refv(&file, key));
        let (rn, cs) = (rel_norm(a, &b), cosine(a, &b));
        eprintln!("{key}: rel norm {rn:.3e}, cosine {cs:.6}");
        assert!(
            rn <= 0.05 && cs >= 0.998,
            "{key}: rel norm {rn}, cosine {cs}"
        );
    }
    for net in ["nerf_coarse", "nerf_fine"] {
        for k in [
            "sigma.weight",
            "rgb.0.weight",
            "dir_encoding.0.bias",
            "xyz_encoding_5.0.bias",
        ] {
            let key = format!("grad/{net}.{k}");
            let (a, b) = (out.float(&key), refv(&file, &key));
            let rn = rel_norm(a, &b);
            eprintln!("{key}: rel norm {rn:.3e}");
            assert!(rn <= 0.05, "{key}: rel norm {rn}");
        }
    }
    // the gradient norms of all 48 parameters, in the reference's (sorted) order
    let gn = refv(&file, "gradnorm/values");
    assert_eq!(out.gradnorm_names.len(), gn.len());
    let rn = rel_norm(out.float("gradnorm/values"), &gn);
    assert!(rn <= 0.05, "gradnorm/values: rel norm {rn}");
}

/// `physnerf-case` (through `run_case_file`) writes every reference key of the per-ray,
/// loss and gradient groups with the reference's shape, and values that match it.
#[test]
fn case_file_runner_writes_the_reference_keys() {
    let dir = std::env::temp_dir().join(format!("nf_case_{}", std::process::id()));
    let out_path = dir.join("out.safetensors");
    let out = neurofluid_dev::physnerf_case::run_case_file(
        &case_path(),
        None,
        &out_path,
        &neurofluid_core::device::test_device(),
        DType::F32,
    )
    .expect("run");
    let written =
        neurofluid_physnerf::safetensors_file::StFile::open(&out_path).expect("output file");
    let (_, reference) = case();
    let groups = [
        "rays/",
        "coarse/",
        "fine/",
        "loss/value",
        "loss/mse",
        "grad/",
        "gradnorm/",
    ];
    let keys: Vec<String> = reference
        .names()
        .into_iter()
        .filter(|k| groups.iter().any(|g| k.starts_with(g)))
        .collect();
    assert!(keys.len() > 30, "{} reference keys", keys.len());
    for k in &keys {
        let want = if reference.floats(k, None).is_ok() {
            reference.floats(k, None).unwrap().0
        } else {
            reference.ints(k, None).unwrap().0
        };
        let got = if written.floats(k, None).is_ok() {
            written.floats(k, None).unwrap().0
        } else {
            written.ints(k, None).unwrap_or_else(|e| panic!("{e}")).0
        };
        assert_eq!(got, want, "{k}: shape");
    }
    let names: Vec<String> =
        serde_json::from_str(&written.metadata().unwrap()["gradnorm_names"]).unwrap();
    let ref_names: Vec<String> =
        serde_json::from_str(&reference.metadata().unwrap()["gradnorm_names"]).unwrap();
    assert_eq!(names, ref_names, "gradnorm/values order");
    assert_eq!(
        out.float("loss/value"),
        written.floats("loss/value", None).unwrap().1.as_slice()
    );
    let (l, lr) = (
        out.float("loss/value")[0],
        refv(&reference, "loss/value")[0],
    );
    assert!(((l - lr) / lr).abs() <= 1e-4);
    std::fs::remove_dir_all(dir).ok();
}
