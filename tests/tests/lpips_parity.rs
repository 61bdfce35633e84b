//! LPIPS (AlexNet, v0.1) against the Python `lpips` package on the pairs of
//! `tests/data/lpips/` (made by `make_lpips.py` with the same weights).

use neurofluid_core::metrics::{Lpips, RgbImage};
use neurofluid_core::scene::Image;
use neurofluid_tests::workspace_root;

fn rgb(name: &str) -> RgbImage {
    let img = Image::read(&workspace_root().join("tests/data/lpips").join(name)).unwrap();
    RgbImage::new(img.width as usize, img.height as usize, img.rgb).unwrap()
}

#[test]
fn lpips_matches_the_python_package() {
    let text =
        std::fs::read_to_string(workspace_root().join("tests/data/lpips/expected.json")).unwrap();
    let expected: serde_json::Value = serde_json::from_str(&text).unwrap();
    let lpips = Lpips::new(&neurofluid_core::device::cpu()).unwrap();
    let cases = expected["cases"].as_array().unwrap();
    assert!(cases.len() >= 5);
    for case in cases {
        let (a, b) = (
            rgb(case["a"].as_str().unwrap()),
            rgb(case["b"].as_str().unwrap()),
        );
        let want = case["lpips"].as_f64().unwrap();
        let got = lpips.distance(&a, &b).unwrap();
        assert!(
            (got - want).abs() <= 1e-5 + 1e-4 * want,
            "{}: {got} vs the package's {want}",
            case["a"]
        );
        // symmetric
        let back = lpips.distance(&b, &a).unwrap();
        assert!((back - got).abs() <= 1e-6 + 1e-5 * got);
    }
    let small = RgbImage::new(16, 16, vec![0.5; 16 * 16 * 3]).unwrap();
    assert!(
        lpips
            .distance(&small, &small)
            .unwrap_err()
            .to_string()
            .contains("31")
    );
}
