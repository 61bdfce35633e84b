//! Camera files in both conventions: a generated scene's transforms carry NeRF's
//! `camera_angle_x` and nerfstudio's `fl_x`, `fl_y`, `cx`, `cy`, `w`, `h` for the same camera; either
//! alone gives the same rays; per-frame intrinsics override the file's; distortion and a size
//! that is not the images' are refused with the key named; a scene without images opens where the
//! transforms give their size.

use std::path::{Path, PathBuf};

use neurofluid_core::camera::Camera;
use neurofluid_core::scene::{Role, Scene, TransformsFile, transforms_path};
use neurofluid_tests::{files_under, seeded_turn, tiny_experiment};
use neurofluid_train::stage::Stage;
use neurofluid_train::stages::{Run, Start};

/// The tiny experiment's scene, generated into `tmp`: its root and the test view's camera at
/// frame 1.
fn tiny_scene(tmp: &Path, name: &str) -> (PathBuf, Camera) {
    let run = Run::prepare(tiny_experiment(tmp, name), Start::Resume, &[Stage::Warmup]).unwrap();
    let camera = run.scene.camera(Role::Test, "view_5", 1).unwrap();
    (run.scene.root().to_path_buf(), camera)
}

#[test]
fn nerf_and_nerfstudio_intrinsics_describe_the_same_camera() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let (root, before) = tiny_scene(tmp.path(), "cams");
    let path = transforms_path(&root, "view_5", "test");
    let original = TransformsFile::read(&path).unwrap();
    assert!(original.camera_angle_x.is_some() && original.intrinsics.fl_x.is_some());

    // nerfstudio's intrinsics alone
    let mut t = original.clone();
    t.camera_angle_x = None;
    t.write(&path).unwrap();
    let cam = Scene::open(&root)
        .unwrap()
        .camera(Role::Test, "view_5", 1)
        .unwrap();
    assert!(
        (cam.fx - before.fx).abs() < 1e-3 * before.fx,
        "{cam:?} vs {before:?}"
    );
    assert_eq!((cam.cx, cam.cy), (before.cx, before.cy));
    for p in [0u32, 17, 1023] {
        let (a, b) = (cam.rays(&[p]).dirs[0], before.rays(&[p]).dirs[0]);
        assert!(a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5));
    }

    // NeRF's alone
    let mut t = original.clone();
    t.intrinsics = Default::default();
    t.write(&path).unwrap();
    assert_eq!(
        Scene::open(&root)
            .unwrap()
            .camera(Role::Test, "view_5", 1)
            .unwrap(),
        before
    );

    // a frame's own intrinsics win over the file's
    let mut t = original.clone();
    t.frames[1].intrinsics.fl_y = Some(2.0 * before.fx);
    t.write(&path).unwrap();
    let scene = Scene::open(&root).unwrap();
    assert!((scene.camera(Role::Test, "view_5", 1).unwrap().fy - 2.0 * before.fx).abs() < 1e-3);
    assert_eq!(scene.camera(Role::Test, "view_5", 2).unwrap().fy, before.fy);

    // lens distortion and a size other than the images' are refused, naming the key
    let mut t = original.clone();
    t.intrinsics.k1 = Some(0.1);
    t.write(&path).unwrap();
    let err = Scene::open(&root).unwrap_err().to_string();
    assert!(
        err.contains("k1") && err.contains("transforms_test.json"),
        "{err}"
    );
    // (refused when the scene opens: the first image's header against `w`, `h`)
    let mut t = original.clone();
    t.intrinsics.w = Some(99);
    t.write(&path).unwrap();
    let err = Scene::open(&root).unwrap_err().to_string();
    assert!(err.contains("w, h") && err.contains("99"), "{err}");
    // neither convention: refused
    let mut t = original;
    t.camera_angle_x = None;
    t.intrinsics = Default::default();
    t.write(&path).unwrap();
    let err = Scene::open(&root).unwrap_err().to_string();
    assert!(
        err.contains("camera_angle_x") && err.contains("fl_x"),
        "{err}"
    );
}

/// A scene of particles only (no images: DLF rollouts and training) opens where its transforms
/// give the images' size, with the cameras it had; an image it lacks is named when loaded, and
/// without `w` and `h` the missing first image is named at once.
#[test]
fn a_scene_without_images_opens_where_the_transforms_give_their_size() {
    let _turn = seeded_turn();
    let tmp = tempfile::tempdir().unwrap();
    let (root, before) = tiny_scene(tmp.path(), "noimg");
    let particles = Scene::open(&root)
        .unwrap()
        .particles(Role::Test, 1)
        .unwrap();
    let pngs: Vec<_> = files_under(&root)
        .into_iter()
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    assert!(!pngs.is_empty());
    for p in &pngs {
        std::fs::remove_file(root.join(p)).unwrap();
    }
    let scene = Scene::open(&root).unwrap();
    assert_eq!(scene.camera(Role::Test, "view_5", 1).unwrap(), before);
    assert_eq!(scene.particles(Role::Test, 1).unwrap(), particles);
    let err = scene
        .image(Role::Test, "view_5", 1)
        .unwrap_err()
        .to_string();
    assert!(err.contains("view_5") && err.contains(".png"), "{err}");

    let path = transforms_path(&root, "view_5", "test");
    let mut t = TransformsFile::read(&path).unwrap();
    (t.intrinsics.w, t.intrinsics.h) = (None, None);
    t.write(&path).unwrap();
    let err = Scene::open(&root).unwrap_err().to_string();
    assert!(err.contains("view_5") && err.contains(".png"), "{err}");
}
