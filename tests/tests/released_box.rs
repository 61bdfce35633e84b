//! The released scenes' `box.pt` loads directly: joblib files of the release era and of today
//! and plain pickles give the arrays Python wrote (`tests/data/box/make_boxes.py`); a compressed
//! joblib file is refused with a clear error.

use neurofluid_core::scene::BoxParticles;
use neurofluid_tests::workspace_root;

fn read_as_box_pt(fixture: &str) -> Result<BoxParticles, String> {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("box.pt");
    std::fs::copy(workspace_root().join("tests/data/box").join(fixture), &path).unwrap();
    BoxParticles::read(&path).map_err(|e| e.to_string())
}

#[test]
fn joblib_and_pickle_boxes_load_as_python_wrote_them() {
    let text =
        std::fs::read_to_string(workspace_root().join("tests/data/box/expected.json")).unwrap();
    let expected: serde_json::Value = serde_json::from_str(&text).unwrap();
    let rows = |key: &str| -> Vec<[f32; 3]> {
        expected[key]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| std::array::from_fn(|k| r[k].as_f64().unwrap() as f32))
            .collect()
    };
    for fixture in [
        "box_joblib-1.1.pt",
        "box_joblib-1.6.pt",
        "box_pickle-p2.pt",
        "box_pickle-p4.pt",
    ] {
        let b = read_as_box_pt(fixture).unwrap_or_else(|e| panic!("{fixture}: {e}"));
        assert_eq!(b.points, rows("box"), "{fixture}");
        assert_eq!(b.normals, rows("box_normals"), "{fixture}");
    }
}

#[test]
fn a_compressed_joblib_box_is_refused_clearly() {
    let err = read_as_box_pt("box_joblib-compressed.pt").unwrap_err();
    assert!(err.contains("box.pt") && err.contains("compress"), "{err}");
}
