//! Physical and reproducibility checks of the built-in scene generator (small sizes).

use std::path::PathBuf;

use neurofluid_core::scene::{BoxParticles, Particles, Role, Scene, UpAxis};
use neurofluid_scenegen::shapes::Shape;
use neurofluid_scenegen::{Preset, Scale, SceneConfig, SceneKind, generate, simulate};
use neurofluid_tests::{files_under, small_preset};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("nf_scene_{name}_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn mean_speed(f: &Particles) -> f64 {
    f.vel
        .iter()
        .map(|v| (v.iter().map(|c| (*c as f64).powi(2)).sum::<f64>()).sqrt())
        .sum::<f64>()
        / f.len() as f64
}

#[test]
fn count_constant_particles_inside_and_energy_decays() {
    let p = small_preset(
        SceneKind::WaterCube,
        Shape::Cube {
            center: [-0.1, -0.1, 0.0],
            size: 0.35,
        },
    );
    let sim = simulate(&p, 120, false);
    let n = sim.frames[0].len();
    assert!(n > 300, "{n}");
    let r = p.radius as f32;
    for (t, f) in sim.frames.iter().enumerate() {
        assert_eq!(f.len(), n, "frame {t}");
        for x in &f.pos {
            for a in 0..3 {
                assert!(
                    x[a] >= p.box_lo[a] as f32 + 0.99 * r && x[a] <= p.box_hi[a] as f32 - 0.99 * r,
                    "frame {t}: {x:?} outside the box"
                );
            }
        }
    }
    // containment comes from the boundary particles, not from the clamping safety net
    let clamps: usize = sim.stats.iter().map(|s| s.clamped).sum();
    let particle_steps: usize = sim.stats.iter().map(|s| s.substeps).sum::<usize>() * n;
    assert!(
        (clamps as f64) < 1e-3 * particle_steps as f64,
        "{clamps} clamps in {particle_steps} particle-steps"
    );
    // the density solve keeps the fluid near-incompressible
    let last = sim.stats.last().unwrap();
    assert!(last.density_error < 0.01, "{}", last.density_error);
    // energy: rises during the fall, then decays as the fluid settles
    let ke = &sim.kinetic_energy;
    let (peak_t, peak) =
        ke.iter().enumerate().fold(
            (0, 0.0f64),
            |acc, (t, &e)| if e > acc.1 { (t, e) } else { acc },
        );
    assert!(peak > 0.0 && peak_t < 60, "peak at {peak_t}");
    let tail = ke[100..].iter().sum::<f64>() / 20.0;
    assert!(tail < 0.15 * peak, "tail {tail} vs peak {peak}");
    let mid = ke[70..90].iter().sum::<f64>() / 20.0;
    assert!(tail < mid, "energy still growing: {mid} → {tail}");
}

#[test]
fn honey_moves_measurably_slower_than_water() {
    let cone = Shape::Cone {
        base: [0.0, -0.38, 0.0],
        radius: 0.3,
        height: 0.55,
    };
    let water = small_preset(SceneKind::WaterCube, cone);
    let honey = small_preset(SceneKind::HoneyCone, cone);
    assert!(honey.viscosity > 5.0 * water.viscosity);
    let frames = 30;
    let sw = simulate(&water, frames, false);
    let sh = simulate(&honey, frames, false);
    assert_eq!(sw.frames[0].pos, sh.frames[0].pos, "same initial particles");
    let vw: f64 = sw.frames.iter().map(mean_speed).sum();
    let vh: f64 = sh.frames.iter().map(mean_speed).sum();
    assert!(vh < 0.6 * vw, "honey mean speed {vh} vs water {vw}");
    // and its particles travel less far from where they started
    let travelled = |sim: &neurofluid_scenegen::Simulation, t: usize| {
        sim.frames[t]
            .pos
            .iter()
            .zip(&sim.frames[0].pos)
            .map(|(x, x0)| {
                (0..3)
                    .map(|a| ((x[a] - x0[a]) as f64).powi(2))
                    .sum::<f64>()
                    .sqrt()
            })
            .sum::<f64>()
            / sim.frames[0].len() as f64
    };
    let (dw, dh) = (travelled(&sw, 15), travelled(&sh, 15));
    assert!(
        dh < 0.6 * dw,
        "mean displacement after 15 frames: honey {dh}, water {dw}"
    );
}

fn tiny(seed: u64) -> Preset {
    let mut cfg = SceneConfig::new(SceneKind::WaterSphere, Scale::Quick);
    cfg.seed = seed;
    cfg.image_size = Some(24);
    cfg.samples_per_axis = Some(1);
    cfg.train_frames = Some(3);
    cfg.test_frames = Some(4);
    let mut p = small_preset(
        SceneKind::WaterSphere,
        Shape::Sphere {
            center: [0.0, 0.0, 0.0],
            radius: 0.2,
        },
    );
    let q = Preset::resolve(&cfg);
    p.image_size = q.image_size;
    p.samples_per_axis = q.samples_per_axis;
    p.train_frames = q.train_frames;
    p.test_frames = q.test_frames;
    p.seed = seed;
    p
}

#[test]
fn same_seed_gives_byte_identical_files_and_reads_back() {
    let (a, b, c) = (tmp("seed_a"), tmp("seed_b"), tmp("seed_c"));
    let p = tiny(7);
    let ra = generate::generate(&p, &a, false).unwrap();
    // the second run on a single thread: results must not depend on the thread count
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| generate::generate(&p, &b, false))
        .unwrap();
    let fa = files_under(&a);
    assert_eq!(fa, files_under(&b));
    // 4 warm-up + 2 more train frames + 4 test frames, each with an image and a particle file,
    // 5 transforms files, box.npz, box.pt and scene.json
    assert_eq!(ra.images, 4 + 2 + 4);
    assert_eq!(fa.len(), 2 * ra.images + 5 + 3, "{fa:?}");
    for f in &fa {
        assert_eq!(
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
            "{f:?} differs"
        );
    }
    // another seed moves the particles
    generate::generate(&tiny(8), &c, false).unwrap();
    let pa = Particles::read(&a.join("view_1/train/particles/0000.npz")).unwrap();
    let pc = Particles::read(&c.join("view_1/train/particles/0000.npz")).unwrap();
    assert_ne!(pa.pos, pc.pos);

    // read back: the loader returns exactly what was simulated and written
    let sim = simulate(&p, 4, false);
    let scene = Scene::open(&a).unwrap();
    assert_eq!(scene.up_axis(), UpAxis::Y);
    assert_eq!(scene.views(Role::Warmup).len(), 4);
    assert_eq!(scene.frames(Role::Train), 0..3);
    assert_eq!(scene.frames(Role::Test), 0..4);
    for t in 0..4 {
        assert_eq!(
            scene.particles(Role::Test, t).unwrap(),
            sim.frames[t],
            "test frame {t}"
        );
    }
    for t in 0..3 {
        assert_eq!(
            scene.particles(Role::Train, t).unwrap(),
            sim.frames[t],
            "train frame {t}"
        );
    }
    let walls: BoxParticles = scene.boundary().unwrap();
    assert_eq!(walls, sim.walls);
    let (lo, hi) = walls.bounds().unwrap();
    assert_eq!(
        (lo, hi),
        (p.box_lo.map(|v| v as f32), p.box_hi.map(|v| v as f32))
    );
    let m = scene.manifest();
    assert!(m.near > 0.0 && m.far > m.near);
    // every camera sees the box between near and far
    for v in scene.views(Role::Warmup) {
        let cam = scene.camera(Role::Warmup, v, 0).unwrap();
        assert_eq!((cam.width, cam.height), (24, 24));
        let o = cam.origin();
        for corner in 0..8 {
            let c = [
                if corner & 1 == 0 { lo[0] } else { hi[0] },
                if corner & 2 == 0 { lo[1] } else { hi[1] },
                if corner & 4 == 0 { lo[2] } else { hi[2] },
            ];
            let d = ((0..3).map(|a| (c[a] - o[a]).powi(2)).sum::<f32>()).sqrt();
            assert!(
                d > m.near && d < m.far,
                "corner at {d} outside [{}, {}]",
                m.near,
                m.far
            );
        }
    }
    // the fluid is visible: some covered pixels at frame 0, background pixels are white
    let img = scene.image(Role::Warmup, "view_1", 0).unwrap();
    let covered = img.alpha.iter().filter(|&&a| a > 0.5).count();
    assert!(covered > 5, "{covered} covered pixels");
    for (i, &a) in img.alpha.iter().enumerate() {
        if a == 0.0 {
            assert_eq!(&img.rgb[i * 3..i * 3 + 3], &[1.0, 1.0, 1.0]);
        }
    }
    for d in [a, b, c] {
        let _ = std::fs::remove_dir_all(d);
    }
}
