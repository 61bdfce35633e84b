//! The built-in scenes' validation views (`validation_views`): on the warm-up ring where the
//! test view sits, at the warm-up midpoints no test view takes, over the test frames; every other
//! file of the scene as it is without them. Tiny sizes.

use std::path::{Path, PathBuf};

use neurofluid_core::scene::{MANIFEST_FILE, Role, Scene};
use neurofluid_scenegen::generate::{validation_azimuths, validation_views, views};
use neurofluid_scenegen::{Preset, Scale, SceneConfig, SceneKind, generate};

use crate::common;
use common::contents;

fn tmp(name: &str) -> PathBuf {
    common::tmp("validation", name)
}

fn tiny(validation: bool) -> Preset {
    common::tiny(4, 3, |c| c.validation_views = Some(validation))
}

#[test]
fn the_midpoints_left_by_the_test_views() {
    assert_eq!(validation_azimuths(1), vec![165.0, 255.0, 345.0]);
    // two test views: 75° and 255°
    assert_eq!(validation_azimuths(2), vec![165.0, 345.0]);
    // four take every midpoint
    assert!(validation_azimuths(4).is_empty());
    let mut cfg = SceneConfig::new(SceneKind::WaterCube, Scale::Quick);
    cfg.test_views = Some(4);
    cfg.validation_views = Some(true);
    let err = cfg.validate(Path::new("x.toml")).unwrap_err().to_string();
    assert!(err.contains("scene.validation_views"), "{err}");
}

/// A validation view is the test view turned about the vertical axis through the ring's target
/// by the difference of their azimuths: same distance, elevation and intrinsics.
#[test]
fn validation_cameras_are_the_test_camera_turned_about_the_target() {
    let p = tiny(true);
    let (warm, test) = views(&p);
    let val = validation_views(&p);
    assert_eq!(
        val.iter().map(|v| v.name.as_str()).collect::<Vec<_>>(),
        ["view_6", "view_7", "view_8"]
    );
    let t = &test[0];
    let c2w = |m: [[f32; 4]; 4]| {
        (
            glam::Vec3::new(m[0][3], m[1][3], m[2][3]),
            glam::Mat3::from_cols(
                glam::Vec3::new(m[0][0], m[1][0], m[2][0]),
                glam::Vec3::new(m[0][1], m[1][1], m[2][1]),
                glam::Vec3::new(m[0][2], m[1][2], m[2][2]),
            ),
        )
    };
    // a point on the vertical axis through the ring's target: the midpoint of view_1's and
    // view_3's centres, which face each other across it
    let (e1, _) = c2w(warm[0].camera.c2w);
    let (e3, _) = c2w(warm[2].camera.c2w);
    let target = 0.5 * (e1 + e3);
    let (et, rt) = c2w(t.camera.c2w);
    for v in &val {
        let turn = glam::Mat3::from_rotation_y((v.azimuth_deg - t.azimuth_deg).to_radians());
        let (ev, rv) = c2w(v.camera.c2w);
        let want_eye = target + turn * (et - target);
        assert!(
            (ev - want_eye).length() < 1e-4,
            "{}: eye {ev} vs {want_eye}",
            v.name
        );
        for a in 0..3 {
            assert!(
                (rv.col(a) - turn * rt.col(a)).length() < 1e-5,
                "{} axis {a}",
                v.name
            );
        }
        assert_eq!(v.camera.fx, t.camera.fx);
        assert_eq!((v.camera.width, v.camera.height), (24, 24));
    }
    assert!(validation_views(&tiny(false)).is_empty());
}

#[test]
fn validation_views_are_added_and_every_other_file_is_the_same() {
    let (a, b) = (tmp("with"), tmp("without"));
    let with = generate(&tiny(true), &a, false).unwrap();
    let without = generate(&tiny(false), &b, false).unwrap();
    assert_eq!(with.images, without.images + 3 * 2);
    let (fa, fb) = (contents(&a), contents(&b));
    for (f, bytes) in &fb {
        if f == Path::new(MANIFEST_FILE) {
            continue;
        }
        assert!(fa.get(f) == Some(bytes), "{f:?} differs");
    }
    let added: Vec<&PathBuf> = fa.keys().filter(|f| !fb.contains_key(*f)).collect();
    assert!(!added.is_empty());
    for f in &added {
        assert!(
            ["view_6", "view_7", "view_8"]
                .iter()
                .any(|v| f.starts_with(v)),
            "{f:?}"
        );
    }
    // the manifests differ in the validation set and the generator's flag alone
    let json = |d: &Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(d.join(MANIFEST_FILE)).unwrap()).unwrap()
    };
    let (mut ja, jb) = (json(&a), json(&b));
    assert_eq!(ja["generator"]["validation_views"], true);
    ja["generator"]
        .as_object_mut()
        .unwrap()
        .remove("validation_views");
    ja.as_object_mut().unwrap().remove("validation");
    assert_eq!(ja, jb);
    // and the scene reads them: the test frames, images of the sphere, the test view's look
    let scene = Scene::open(&a).unwrap();
    assert_eq!(scene.frames(Role::Validation), scene.frames(Role::Test));
    assert_eq!(scene.views(Role::Validation).len(), 3);
    for v in scene.views(Role::Validation) {
        let img = scene.image(Role::Validation, v, 1).unwrap();
        let covered = img.alpha.iter().filter(|&&a| a > 0.5).count();
        assert!(covered > 10, "{v}: {covered} fluid pixels");
    }
    assert!(Scene::open(&b).unwrap().views(Role::Validation).is_empty());
    for d in [a, b] {
        let _ = std::fs::remove_dir_all(d);
    }
}

/// The warm-up views at every frame are added to a scene with validation views by a preset
/// without the flag (it is a free setting): the scene keeps them, and comes out as `generate`
/// writes it with both.
#[test]
fn a_scene_keeps_its_validation_views_when_its_warm_up_views_are_extended() {
    let (a, b) = (tmp("ext_both"), tmp("ext_val"));
    let both = Preset {
        warmup_every_frame: true,
        ..tiny(true)
    };
    generate(&both, &a, false).unwrap();
    generate(&tiny(true), &b, false).unwrap();
    let r = neurofluid_scenegen::render_warmup_frames(&tiny(false), &b, false).unwrap();
    assert!(r.manifest && r.images > 0);
    assert_eq!(contents(&a), contents(&b));
    for d in [a, b] {
        let _ = std::fs::remove_dir_all(d);
    }
}
