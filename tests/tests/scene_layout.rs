//! The scene loader on a tiny fixture written in NeuroFluid's released layout (z up, no
//! manifest, joblib `box.pt`), and its errors on missing files and fields.

use std::path::{Path, PathBuf};

use neurofluid_core::scene::{
    BoxParticles, FrameEntry, MANIFEST_FILE, Particles, Role, Scene, SceneError, SceneManifest,
    TransformsFile, UpAxis, ViewSet, transforms_path, write_png_rgba,
};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("nf_layout_{name}_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn c2w(k: usize) -> [[f32; 4]; 4] {
    // camera on a ring around the z axis, with the uniform scale the released cameras carry
    let a = k as f32;
    let (s, c) = a.sin_cos();
    let sc = 0.4155;
    [
        [c * sc, 0.0, s * sc, 10.0 * s],
        [s * sc, 0.0, -c * sc, -10.0 * c],
        [0.0, sc, 0.0, 3.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

fn particles(t: usize) -> Particles {
    Particles {
        pos: (0..5)
            .map(|i| [i as f32 * 0.1, 0.0, 1.0 - t as f32 * 0.01])
            .collect(),
        vel: (0..5).map(|i| [0.0, i as f32, -(t as f32)]).collect(),
    }
}

/// view_1…view_4 `train` (view_1 with 50 frames, the others 1), view_5 `test` with 60 frames.
fn write_released(root: &Path) {
    // 2×2 RGBA: transparent, opaque red, half-transparent green, opaque white
    let rgba = [
        0, 0, 0, 0, 255, 0, 0, 255, 0, 255, 0, 128, 255, 255, 255, 255,
    ];
    for (view, split, n) in [
        ("view_1", "train", 50),
        ("view_2", "train", 1),
        ("view_3", "train", 1),
        ("view_4", "train", 1),
        ("view_5", "test", 60),
    ] {
        let k: usize = view[5..].parse().unwrap();
        let mut frames = Vec::new();
        for t in 0..n {
            write_png_rgba(
                &root.join(view).join(split).join(format!("{t:04}.png")),
                2,
                2,
                &rgba,
            )
            .unwrap();
            particles(t)
                .write(
                    &root
                        .join(view)
                        .join(split)
                        .join(format!("particles/{t:04}.npz")),
                )
                .unwrap();
            frames.push(FrameEntry {
                file_path: format!("./{split}/{t:04}"),
                transform_matrix: c2w(k),
                particle_path: Some(format!("particles/{t:04}.npz")),
                intrinsics: Default::default(),
            });
        }
        TransformsFile {
            camera_angle_x: Some(0.3235),
            intrinsics: Default::default(),
            bounding_box: Some("box.pt".into()),
            frames,
        }
        .write(&transforms_path(root, view, split))
        .unwrap();
    }
}

/// A test view whose camera is a training view's is not a novel view: the scene is refused
/// with the field and the training view named (issue 72: it was scored as a novel view).
#[test]
fn a_test_view_with_a_training_camera_is_refused() {
    let root = released_scene("seen_test_view");
    Scene::open(&root).unwrap();
    let path = transforms_path(&root, "view_5", "test");
    let mut t = TransformsFile::read(&path).unwrap();
    for f in &mut t.frames {
        f.transform_matrix = c2w(1);
    }
    t.write(&path).unwrap();
    let err = Scene::open(&root).unwrap_err().to_string();
    assert!(
        err.contains("transforms_test.json") && err.contains("view_1") && err.contains("novel"),
        "{err}"
    );
}

/// The released-layout fixture with the released box, in a fresh folder `name`.
fn released_scene(name: &str) -> PathBuf {
    let root = tmp(name);
    write_released(&root);
    std::fs::copy(
        neurofluid_tests::workspace_root().join("tests/data/box/box_joblib-1.1.pt"),
        root.join("box.pt"),
    )
    .unwrap();
    root
}

#[test]
fn released_layout_loads_with_defaults() {
    let root = released_scene("watercube");
    let scene = Scene::open(&root).unwrap();
    assert!(!scene.has_manifest_file());
    assert_eq!(
        scene.manifest(),
        &SceneManifest::released(scene.manifest().name.as_str())
    );
    assert_eq!(scene.up_axis(), UpAxis::Z);
    assert_eq!(scene.up_axis().gravity(), [0.0, 0.0, -9.81]);
    assert_eq!(
        scene.views(Role::Warmup),
        ["view_1", "view_2", "view_3", "view_4"]
    );
    assert_eq!(scene.views(Role::Train), ["view_1"]);
    assert_eq!(scene.views(Role::Test), ["view_5"]);
    assert_eq!(scene.frames(Role::Train), 0..50);
    assert_eq!(scene.frames(Role::Test), 0..60);
    // particles by frame, from the role's first view
    assert_eq!(scene.particles(Role::Train, 7).unwrap(), particles(7));
    assert_eq!(scene.particles(Role::Test, 59).unwrap(), particles(59));
    assert_eq!(scene.particle_sequence(Role::Train).unwrap().len(), 50);
    // camera: focal from camera_angle_x, transform as written
    let cam = scene.camera(Role::Test, "view_5", 3).unwrap();
    assert_eq!(cam.c2w, c2w(5));
    assert!((cam.fx - 1.0 / (0.5f32 * 0.3235).tan()).abs() < 1e-5);
    assert_eq!((cam.fx, cam.cx, cam.cy), (cam.fy, 1.0, 1.0));
    // images composited on white: c·a + (1 − a)
    let img = scene.image(Role::Warmup, "view_2", 0).unwrap();
    assert_eq!((img.width, img.height), (2, 2));
    let a = 128.0 / 255.0;
    let expect = [
        1.0,
        1.0,
        1.0,
        1.0,
        0.0,
        0.0,
        1.0 - a,
        1.0,
        1.0 - a,
        1.0,
        1.0,
        1.0,
    ];
    for (x, e) in img.rgb.iter().zip(expect) {
        assert!((x - e).abs() < 1e-6, "{:?}", img.rgb);
    }
    assert_eq!(img.alpha[0], 0.0);
    // the released joblib box.pt is read directly
    assert_eq!(scene.boundary().unwrap().points.len(), 5);
    // a box.npz next to it is preferred
    let walls = BoxParticles {
        points: vec![[-1.0, -1.0, -1.0], [1.0, 1.0, 2.455]],
        normals: vec![[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]],
    };
    walls.write(&root.join("box.npz")).unwrap();
    assert_eq!(scene.boundary().unwrap(), walls);
    // an unknown view is an error naming the scene's views
    assert!(matches!(
        scene.camera(Role::Test, "view_9", 0),
        Err(SceneError::Lookup(_))
    ));
    let _ = std::fs::remove_dir_all(root);
}

#[test]
fn released_honeycone_trains_on_frames_15_to_64() {
    let m = SceneManifest::released("honeycone");
    assert_eq!(m.train.frames.range(), 15..65);
    assert_eq!(
        SceneManifest::released("watersphere").train.frames.range(),
        0..50
    );
}

#[test]
fn missing_files_and_fields_name_the_path_and_field() {
    let root = tmp("broken");
    write_released(&root);
    // too few frames for the default train range
    let json = transforms_path(&root, "view_1", "train");
    let mut t = TransformsFile::read(&json).unwrap();
    t.frames.truncate(10);
    t.write(&json).unwrap();
    let err = Scene::open(&root).unwrap_err().to_string();
    assert!(
        err.contains("transforms_train.json") && err.contains("frames"),
        "{err}"
    );
    write_released(&root);

    // a frame without transform_matrix
    let text = std::fs::read_to_string(&json).unwrap();
    let mut v: serde_json_value::Value = serde_json_value::from_str(&text);
    v.remove_first("transform_matrix");
    std::fs::write(&json, v.0).unwrap();
    let err = Scene::open(&root).unwrap_err().to_string();
    assert!(
        err.contains("view_1") && err.contains("transform_matrix"),
        "{err}"
    );
    write_released(&root);

    // a missing image
    std::fs::remove_file(root.join("view_5/test/0000.png")).unwrap();
    let err = Scene::open(&root).unwrap_err().to_string();
    assert!(err.contains("view_5") && err.contains("0000.png"), "{err}");
    write_released(&root);

    // a missing particle file, and an array missing from one
    let scene = Scene::open(&root).unwrap();
    std::fs::remove_file(root.join("view_1/train/particles/0003.npz")).unwrap();
    let err = scene.particles(Role::Train, 3).unwrap_err().to_string();
    assert!(err.contains("particles/0003.npz"), "{err}");
    BoxParticles::default()
        .write(&root.join("view_1/train/particles/0004.npz"))
        .unwrap();
    let err = scene.particles(Role::Train, 4).unwrap_err().to_string();
    assert!(err.contains("0004.npz") && err.contains("pos"), "{err}");

    // a bad manifest field
    std::fs::write(root.join("scene.json"), "{\"name\": \"x\"}").unwrap();
    let err = Scene::open(&root).unwrap_err().to_string();
    assert!(
        err.contains("scene.json") && err.contains("up_axis"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(root);
}

#[test]
fn validation_views_load_apart_from_the_other_roles() {
    let root = tmp("validation");
    write_released(&root);
    let manifest = root.join(MANIFEST_FILE);
    let mut m = SceneManifest::released("watercube");
    m.box_file = "box.npz".into();
    BoxParticles {
        points: vec![[0.0; 3]],
        normals: vec![[0.0, 0.0, 1.0]],
    }
    .write(&root.join("box.npz"))
    .unwrap();
    m.write(&manifest).unwrap();
    // none declared: the role has no views
    let scene = Scene::open(&root).unwrap();
    assert!(scene.views(Role::Validation).is_empty());
    assert!(scene.frames(Role::Validation).is_empty());

    // view_6, a copy of the test view under another name, declared as the validation view
    neurofluid_tests::copy_dir(&root.join("view_5"), &root.join("view_6"));
    m.validation = Some(ViewSet {
        views: vec!["view_6".into()],
        ..m.test.clone()
    });
    m.write(&manifest).unwrap();
    let scene = Scene::open(&root).unwrap();
    assert_eq!(scene.views(Role::Validation), ["view_6"]);
    assert_eq!(scene.views(Role::Test), ["view_5"]);
    assert_eq!(scene.frames(Role::Validation), scene.frames(Role::Test));
    assert_eq!(
        scene.camera(Role::Validation, "view_6", 3).unwrap(),
        scene.camera(Role::Test, "view_5", 3).unwrap()
    );
    assert_eq!(
        scene.image(Role::Validation, "view_6", 59).unwrap().rgb,
        scene.image(Role::Test, "view_5", 59).unwrap().rgb
    );

    // validation views on other frames than the test's, or shared with another role, or
    // missing, are refused naming the field or the view
    let refused = |validation: ViewSet| {
        let mut bad = m.clone();
        bad.validation = Some(validation);
        bad.write(&manifest).unwrap();
        Scene::open(&root).unwrap_err().to_string()
    };
    let mut frames = m.validation.clone().unwrap();
    frames.frames.end = 50;
    let err = refused(frames);
    assert!(
        err.contains("scene.json") && err.contains("validation.frames"),
        "{err}"
    );
    let mut shared = m.validation.clone().unwrap();
    shared.views.push("view_2".into());
    let err = refused(shared);
    assert!(
        err.contains("validation.views") && err.contains("view_2"),
        "{err}"
    );
    let mut missing = m.validation.clone().unwrap();
    missing.views = vec!["view_7".into()];
    let err = refused(missing);
    assert!(err.contains("view_7"), "{err}");
    let _ = std::fs::remove_dir_all(root);
}

/// Minimal text surgery on JSON without a JSON dependency in this test crate.
mod serde_json_value {
    pub struct Value(pub String);
    pub fn from_str(s: &str) -> Value {
        Value(s.to_string())
    }
    impl Value {
        /// Renames the first occurrence of the key so the field is missing.
        pub fn remove_first(&mut self, key: &str) {
            self.0 = self
                .0
                .replacen(&format!("\"{key}\""), "\"renamed_away\"", 1);
        }
    }
}

/// `np.savez(pos=[[0.1, 1/3, -2.5], [1e-3, 7.25, 0]], vel=[[-1, 0.5, 2/3], [3, -0.125, 9.5]])`
/// with float64 arrays, as numpy 2.4 wrote it (the released data stores float64 particles).
const F64_NPZ_HEX: &[&str] = &[
    "504b03042d00000000000000210039196e9dffffffffffffffff07001400706f732e6e707901001000b0000000000000",
    "00b000000000000000934e554d5059010076007b276465736372273a20273c6638272c2027666f727472616e5f6f7264",
    "6572273a2046616c73652c20277368617065273a2028322c2033292c207d202020202020202020202020202020202020",
    "202020202020202020202020202020202020202020202020202020202020202020202020202020200a9a9999999999b9",
    "3f555555555555d53f00000000000004c0fca9f1d24d62503f0000000000001d400000000000000000504b03042d0000",
    "0000000000210067819832ffffffffffffffff0700140076656c2e6e707901001000b000000000000000b00000000000",
    "0000934e554d5059010076007b276465736372273a20273c6638272c2027666f727472616e5f6f72646572273a204661",
    "6c73652c20277368617065273a2028322c2033292c207d20202020202020202020202020202020202020202020202020",
    "2020202020202020202020202020202020202020202020202020202020202020200a000000000000f0bf000000000000",
    "e03f555555555555e53f0000000000000840000000000000c0bf0000000000002340504b01022d032d00000000000000",
    "210039196e9db0000000b0000000070000000000000000000000800100000000706f732e6e7079504b01022d032d0000",
    "0000000000210067819832b0000000b00000000700000000000000000000008001e900000076656c2e6e7079504b0506",
    "00000000020002006a000000d20100000000",
];

#[test]
fn float64_particles_written_by_numpy_read_as_f32() {
    let hex: String = F64_NPZ_HEX.concat();
    let bytes: Vec<u8> = (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
        .collect();
    let dir = tmp("f64");
    let path = dir.join("0000.npz");
    std::fs::write(&path, bytes).unwrap();
    let p = Particles::read(&path).unwrap();
    assert_eq!(
        p.pos,
        vec![
            [0.1f64 as f32, (1.0f64 / 3.0) as f32, -2.5],
            [1e-3f64 as f32, 7.25, 0.0]
        ]
    );
    assert_eq!(
        p.vel,
        vec![[-1.0, 0.5, (2.0f64 / 3.0) as f32], [3.0, -0.125, 9.5]]
    );
    let _ = std::fs::remove_dir_all(dir);
}
