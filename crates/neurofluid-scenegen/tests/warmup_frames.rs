//! The warm-up views at every training frame: generated directly (`warmup_every_frame`) or added
//! to a generated scene afterwards (`render_warmup_frames`), tiny sizes.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use neurofluid_core::scene::{MANIFEST_FILE, Particles, Role, Scene, transforms_path};
use neurofluid_scenegen::{Preset, Scale, SceneConfig, SceneKind, generate, render_warmup_frames};

const TRAIN_FRAMES: usize = 4;

use crate::common;
use common::contents;

fn tmp(name: &str) -> PathBuf {
    common::tmp("warmup", name)
}

fn tiny(seed: u64, every_frame: bool) -> Preset {
    common::tiny(seed, TRAIN_FRAMES, |c| {
        c.warmup_every_frame = Some(every_frame)
    })
}

/// Modification times of every file under `root`.
fn mtimes(root: &Path) -> BTreeMap<PathBuf, std::time::SystemTime> {
    contents(root)
        .into_keys()
        .map(|f| {
            let t = std::fs::metadata(root.join(&f))
                .unwrap()
                .modified()
                .unwrap();
            (f, t)
        })
        .collect()
}

fn assert_same_files(a: &Path, b: &Path) {
    let (fa, fb) = (contents(a), contents(b));
    assert_eq!(
        fa.keys().collect::<Vec<_>>(),
        fb.keys().collect::<Vec<_>>(),
        "different file sets"
    );
    for (f, bytes) in &fa {
        assert!(bytes == &fb[f], "{f:?} differs");
    }
}

#[test]
fn flag_on_equals_flag_off_then_extended_byte_for_byte() {
    let (a, b) = (tmp("eq_on"), tmp("eq_off"));
    let on = generate(&tiny(3, true), &a, false).unwrap();
    let off = generate(&tiny(3, false), &b, false).unwrap();
    // 4 warm-up views at every training frame + the test view at its frames, vs view_1 only
    assert_eq!(on.images, 4 * TRAIN_FRAMES + 2);
    assert_eq!(off.images, 4 + (TRAIN_FRAMES - 1) + 2);
    // the preset's flag does not matter to the extension
    for p in [tiny(3, false), tiny(3, true)] {
        let c = tmp(&format!("eq_ext_{}", p.warmup_every_frame));
        std::fs::create_dir_all(&c).unwrap();
        for (f, bytes) in contents(&b) {
            std::fs::create_dir_all(c.join(&f).parent().unwrap()).unwrap();
            std::fs::write(c.join(&f), bytes).unwrap();
        }
        let r = render_warmup_frames(&p, &c, false).unwrap();
        assert_eq!(r.images, 3 * (TRAIN_FRAMES - 1));
        assert_eq!(r.frames, TRAIN_FRAMES - 1);
        assert_eq!(
            r.transforms, 3,
            "view_2..view_4 gain frames, view_1 had them"
        );
        assert!(r.manifest);
        // every file: images, particles, transforms, box and manifest
        assert_same_files(&a, &c);
        let _ = std::fs::remove_dir_all(c);
    }
    for d in [a, b] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn extended_scene_opens_with_every_warmup_view_at_every_frame() {
    let d = tmp("open");
    generate(&tiny(5, false), &d, false).unwrap();
    assert_eq!(Scene::open(&d).unwrap().frames(Role::Warmup), 0..1);
    render_warmup_frames(&tiny(5, false), &d, false).unwrap();
    let scene = Scene::open(&d).unwrap();
    assert_eq!(scene.frames(Role::Warmup), 0..TRAIN_FRAMES);
    assert_eq!(scene.frames(Role::Train), 0..TRAIN_FRAMES);
    let views = scene.views(Role::Warmup).to_vec();
    assert_eq!(views, ["view_1", "view_2", "view_3", "view_4"]);
    for t in scene.frames(Role::Warmup) {
        let truth = scene.particles(Role::Train, t).unwrap();
        let mut images = Vec::new();
        for v in &views {
            let split = scene.view_split(Role::Warmup, v).unwrap();
            assert!(split.image_path(t).unwrap().is_file(), "{v} frame {t}");
            // every view stores the frame's particles, the same as the training view's
            let particles = Particles::read(&split.particle_path(t).unwrap()).unwrap();
            assert_eq!(particles, truth, "{v} frame {t}");
            let img = scene.image(Role::Warmup, v, t).unwrap();
            assert_eq!((img.width, img.height), (24, 24));
            assert!(
                img.alpha.iter().any(|&a| a > 0.5),
                "{v} frame {t}: no fluid"
            );
            images.push((v, img.rgb));
        }
        // four cameras, four different pictures of the same particles
        for (i, (vi, a)) in images.iter().enumerate() {
            for (vj, b) in &images[i + 1..] {
                assert_ne!(a, b, "{vi} and {vj} at frame {t}");
            }
        }
    }
    // the particles move: the extra frames are not copies of frame 0
    assert_ne!(
        scene.particles(Role::Warmup, 0).unwrap(),
        scene.particles(Role::Warmup, TRAIN_FRAMES - 1).unwrap()
    );
    let _ = std::fs::remove_dir_all(d);
}

#[test]
fn extending_twice_changes_nothing_and_an_interrupted_run_finishes() {
    let (d, on) = (tmp("idem"), tmp("idem_on"));
    let p = tiny(9, false);
    generate(&p, &d, false).unwrap();
    assert_eq!(render_warmup_frames(&p, &d, false).unwrap().images, 9);
    let before = contents(&d);
    let times = mtimes(&d);
    let again = render_warmup_frames(&p, &d, false).unwrap();
    assert_eq!(
        (again.images, again.frames, again.transforms, again.manifest),
        (0, 0, 0, false)
    );
    assert!(contents(&d) == before, "a second run changed files");
    assert_eq!(mtimes(&d), times, "a second run rewrote files");

    // a scene generated with the flag is complete already
    generate(&tiny(9, true), &on, false).unwrap();
    let times = mtimes(&on);
    assert_eq!(render_warmup_frames(&p, &on, false).unwrap().images, 0);
    assert_eq!(mtimes(&on), times);

    // an interrupted run: frame 1's renders written, the transforms and the manifest not yet
    let half = tmp("idem_half");
    generate(&p, &half, false).unwrap();
    assert!(contents(&half) != before);
    for v in ["view_2", "view_3", "view_4"] {
        for f in ["train/0001.png", "train/particles/0001.npz"] {
            let (src, dst) = (d.join(v).join(f), half.join(v).join(f));
            std::fs::create_dir_all(dst.parent().unwrap()).unwrap();
            std::fs::copy(src, dst).unwrap();
        }
    }
    assert_eq!(Scene::open(&half).unwrap().frames(Role::Warmup), 0..1);
    let r = render_warmup_frames(&p, &half, false).unwrap();
    assert_eq!((r.images, r.frames, r.manifest), (6, 2, true));
    assert!(contents(&half) == before);

    // a lost file of a finished scene is rendered again
    std::fs::remove_file(d.join("view_3/train/0002.png")).unwrap();
    let r = render_warmup_frames(&p, &d, false).unwrap();
    assert_eq!((r.images, r.transforms, r.manifest), (1, 0, false));
    assert!(contents(&d) == before);
    for dir in [d, on, half] {
        let _ = std::fs::remove_dir_all(dir);
    }
}

#[test]
fn folders_that_are_not_a_generated_scene_of_the_preset_are_refused() {
    let d = tmp("refuse");
    let p = tiny(11, false);
    let err = |dir: &Path, p: &Preset| render_warmup_frames(p, dir, false).unwrap_err().to_string();

    // no scene at all
    let empty = tmp("refuse_empty");
    std::fs::create_dir_all(&empty).unwrap();
    let e = err(&empty, &p);
    assert!(
        e.contains(MANIFEST_FILE) && e.contains("not a generated scene"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(empty);

    generate(&p, &d, false).unwrap();
    let untouched = contents(&d);
    // another preset: another seed, other sizes
    let mut other = tiny(12, false);
    let e = err(&d, &other);
    assert!(
        e.contains(MANIFEST_FILE) && e.contains("generator.seed") && e.contains("not a scene"),
        "{e}"
    );
    other = tiny(11, false);
    other.image_size = 32;
    other.train_frames = 5;
    let e = err(&d, &other);
    assert!(
        e.contains("generator.image_size") && e.contains("generator.train_frames"),
        "{e}"
    );
    other = tiny(11, false);
    other.name = "watercube".into();
    let e = err(&d, &other);
    assert!(e.contains("generator.name"), "{e}");
    assert!(contents(&d) == untouched, "a refused run wrote files");

    // a manifest without the generator's settings (a converted or hand-made scene)
    let mpath = d.join(MANIFEST_FILE);
    let mut m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&mpath).unwrap()).unwrap();
    m.as_object_mut().unwrap().remove("generator");
    std::fs::write(&mpath, serde_json::to_string_pretty(&m).unwrap()).unwrap();
    let e = err(&d, &p);
    assert!(
        e.contains(MANIFEST_FILE) && e.contains("no `generator` settings"),
        "{e}"
    );
    std::fs::write(&mpath, &untouched[Path::new(MANIFEST_FILE)]).unwrap();

    // a warm-up view whose camera is not the preset's
    let tpath = transforms_path(&d, "view_3", "train");
    let text = std::fs::read_to_string(&tpath).unwrap();
    let mut t: serde_json::Value = serde_json::from_str(&text).unwrap();
    t["frames"][0]["transform_matrix"][0][3] = serde_json::json!(9.0);
    std::fs::write(&tpath, serde_json::to_string_pretty(&t).unwrap()).unwrap();
    let e = err(&d, &p);
    assert!(
        e.contains("view_3") && e.contains("transforms_train.json") && e.contains("frames[0]"),
        "{e}"
    );
    std::fs::write(&tpath, text).unwrap();

    // the training view's particles of a frame are missing
    let gone = d.join("view_1/train/particles/0002.npz");
    std::fs::remove_file(&gone).unwrap();
    let e = err(&d, &p);
    assert!(
        e.contains("view_1/train/particles/0002.npz") && e.contains("missing"),
        "{e}"
    );
    assert!(
        !d.join("view_2/train/0001.png").exists(),
        "refused before rendering"
    );
    let _ = std::fs::remove_dir_all(d);
}

/// The quick watercube scene (`data/watercube_quick`, generated with the warm-up views at every
/// frame) copied, stripped to what `generate` writes without them, and extended again: prints
/// the time of the extension and checks that it gives back the scene's files byte for byte.
/// `cargo test -p neurofluid-scenegen --test scenegen_tests warmup_frames:: -- --ignored --nocapture`
#[test]
#[ignore = "needs data/watercube_quick; renders 147 images of 100×100"]
fn extend_a_copy_of_the_quick_watercube() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/watercube_quick");
    if !src.join(MANIFEST_FILE).is_file() {
        eprintln!("{} not generated: skipped", src.display());
        return;
    }
    let d = tmp("watercube_quick");
    let original = contents(&src);
    for (f, bytes) in &original {
        std::fs::create_dir_all(d.join(f).parent().unwrap()).unwrap();
        std::fs::write(d.join(f), bytes).unwrap();
    }
    let p = Preset::resolve(&SceneConfig::new(SceneKind::WaterCube, Scale::Quick));
    let t = std::time::Instant::now();
    let r = render_warmup_frames(&p, &d, false).unwrap();
    assert_eq!(
        r.images, 0,
        "the scene has the warm-up views at every frame already"
    );
    eprintln!(
        "complete scene: 0 images in {:.3} s",
        t.elapsed().as_secs_f64()
    );

    // what `generate` writes without the flag: view_2..view_4 at frame 0 only
    let frames = p.train_frames;
    for v in ["view_2", "view_3", "view_4"] {
        for t in 1..frames {
            let dir = d.join(v).join("train");
            std::fs::remove_file(dir.join(format!("{t:04}.png"))).unwrap();
            std::fs::remove_file(dir.join(format!("particles/{t:04}.npz"))).unwrap();
        }
        let path = transforms_path(&d, v, "train");
        let mut tf = neurofluid_core::scene::TransformsFile::read(&path).unwrap();
        tf.frames.truncate(1);
        tf.write(&path).unwrap();
    }
    let mpath = d.join(MANIFEST_FILE);
    let mut m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&mpath).unwrap()).unwrap();
    m["warmup"]["frames"]["end"] = serde_json::json!(1);
    m["generator"]
        .as_object_mut()
        .unwrap()
        .remove("warmup_every_frame");
    let m: neurofluid_core::scene::SceneManifest = serde_json::from_value(m).unwrap();
    m.write(&mpath).unwrap();
    assert_eq!(Scene::open(&d).unwrap().frames(Role::Warmup), 0..1);

    let t = std::time::Instant::now();
    let r = render_warmup_frames(&p, &d, false).unwrap();
    let secs = t.elapsed().as_secs_f64();
    eprintln!(
        "extended: {} images at {} frames in {secs:.1} s (render {:.1} s, read/write {:.1} s, \
         {} threads)",
        r.images,
        r.frames,
        r.render_s,
        r.write_s,
        rayon::current_num_threads()
    );
    assert_eq!(r.images, 3 * (frames - 1));
    let now = contents(&d);
    assert_eq!(now.len(), original.len());
    for (f, bytes) in &original {
        assert!(&now[f] == bytes, "{f:?} differs from data/watercube_quick");
    }
    let _ = std::fs::remove_dir_all(d);
}
