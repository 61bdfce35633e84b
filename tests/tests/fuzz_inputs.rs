//! Property tests for every reader of user files: a mutated or random experiment TOML, `--set`
//! override, JSON file, PNG, `.npz`, weights file or DLF record, and hostile containers (nested
//! and memo-doubling pickles, huge declared array shapes and vertex counts, compression bombs),
//! gives a value or an error that names the file, never a panic (proptest reports a panic as a failure and shrinks it to a
//! small input). The case counts are fixed so CI stays within seconds.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use neurofluid_core::scene::{
    BoxParticles, FrameEntry, Image, Particles, SceneManifest, TransformsFile, png_size,
    write_png_rgba,
};
use neurofluid_tests::{seeded_turn, workspace_root};
use neurofluid_train::config::Experiment;
use proptest::prelude::*;

/// Ways to damage a valid file: cut it, flip bytes (anywhere, near its start, near its end),
/// splice in garbage.
fn mutated(seed: Vec<u8>) -> impl Strategy<Value = Vec<u8>> {
    let n = seed.len().max(1);
    let head = n.min(4096);
    let s1 = seed.clone();
    let s2 = seed.clone();
    let s3 = seed.clone();
    let s4 = seed.clone();
    prop_oneof![
        (0..n).prop_map(move |cut| s1[..cut.min(s1.len())].to_vec()),
        prop::collection::vec((0..n, any::<u8>()), 1..8).prop_map(move |flips| {
            let mut b = s2.clone();
            for (i, v) in flips {
                if let Some(x) = b.get_mut(i) {
                    *x = v;
                }
            }
            b
        }),
        prop::collection::vec((0..head, any::<u8>()), 1..8).prop_map(move |flips| {
            let mut b = s3.clone();
            for (i, v) in flips {
                if let Some(x) = b.get_mut(i) {
                    *x = v;
                }
            }
            b
        }),
        prop::collection::vec((0..head, any::<u8>()), 1..8).prop_map(move |flips| {
            let mut b = s4.clone();
            let len = b.len();
            for (i, v) in flips {
                if let Some(x) = b.get_mut(len.saturating_sub(1 + i)) {
                    *x = v;
                }
            }
            b
        }),
        (0..n, prop::collection::vec(any::<u8>(), 1..64)).prop_map(move |(at, junk)| {
            let mut b = seed.clone();
            let at = at.min(b.len());
            b.splice(at..at, junk);
            b
        }),
    ]
}

/// A file holding `bytes`, named `name` in a fresh folder.
fn file_with(name: &str, bytes: &[u8]) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    (dir, path)
}

/// `cases` cases from a fixed seed: CI explores the same inputs on every run.
fn fixed(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x5eed_f1d0),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

/// An error must name the file it is about.
fn names_file<T, E: std::fmt::Display>(r: Result<T, E>, path: &Path) -> Result<(), TestCaseError> {
    if let Err(e) = r {
        let msg = format!("{e:#}");
        let name = path.file_name().unwrap().to_string_lossy();
        prop_assert!(
            msg.contains(name.as_ref()),
            "error without the file name: {msg}"
        );
    }
    Ok(())
}

/// Seed files, made once.
struct Seeds {
    _dir: tempfile::TempDir,
    manifest: Vec<u8>,
    transforms: Vec<u8>,
    state: Vec<u8>,
    metrics: Vec<u8>,
    png: Vec<u8>,
    particles: Vec<u8>,
    boundary: Vec<u8>,
    dlf_bpk: Vec<u8>,
    physnerf: Vec<u8>,
    record: Vec<u8>,
}

fn seeds() -> &'static Seeds {
    static SEEDS: OnceLock<Seeds> = OnceLock::new();
    SEEDS.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let p = |n: &str| dir.path().join(n);
        let read = |path: PathBuf| std::fs::read(path).unwrap();

        SceneManifest::released("watercube")
            .write(&p("scene.json"))
            .unwrap();
        let transforms = TransformsFile {
            camera_angle_x: Some(0.69),
            intrinsics: neurofluid_core::scene::Intrinsics {
                fl_x: Some(30.0),
                cx: Some(16.5),
                ..Default::default()
            },
            bounding_box: Some("box.pt".into()),
            frames: vec![FrameEntry {
                file_path: "train/0000".into(),
                transform_matrix: [
                    [1.0, 0.0, 0.0, 0.0],
                    [0.0, 1.0, 0.0, 0.0],
                    [0.0, 0.0, 1.0, 4.0],
                    [0.0, 0.0, 0.0, 1.0],
                ],
                particle_path: Some("particles/0000.npz".into()),
                intrinsics: neurofluid_core::scene::Intrinsics {
                    fl_y: Some(31.0),
                    ..Default::default()
                },
            }],
        };
        transforms.write(&p("transforms_train.json")).unwrap();
        let state = serde_json::json!({
            "stage": "warmup", "step": 4, "rng": 12345u64,
            "settings_digest": "abc", "settings": {"seed": "10"}
        });
        std::fs::write(p("state.json"), state.to_string()).unwrap();
        {
            let mut log = neurofluid_outputs::metrics_log::MetricsLog::open(dir.path()).unwrap();
            for s in 1..4 {
                let mut r = neurofluid_outputs::metrics_log::MetricsRow::new("warmup", s, 0.1, 1.0);
                r.set("psnr", 20.0);
                log.append(&r).unwrap();
            }
        }
        write_png_rgba(&p("img.png"), 8, 6, &[200u8; 8 * 6 * 4]).unwrap();
        let pts: Vec<[f32; 3]> = (0..10).map(|i| [i as f32, 0.5, -1.0]).collect();
        Particles {
            pos: pts.clone(),
            vel: pts.clone(),
        }
        .write(&p("particles.npz"))
        .unwrap();
        BoxParticles {
            points: pts.clone(),
            normals: pts,
        }
        .write(&p("box.npz"))
        .unwrap();

        // PhysNeRF's layers draw their initial weights from the backend's RNG when saved
        let _turn = seeded_turn();
        let device = neurofluid_core::device::cpu();
        let weights = workspace_root().join("assets/dlf_pretrained/pretrained_model_weights.pt");
        let net = neurofluid_dlf::load_dlf(&weights, Default::default(), &device).unwrap();
        neurofluid_dlf::save_checkpoint(&net, &p("dlf.bpk")).unwrap();
        let cfg = neurofluid_physnerf::PhysNerfConfig {
            depth: 2,
            width: 4,
            skip: 1,
            ..Default::default()
        };
        neurofluid_physnerf::PhysNerf::new(cfg, &device)
            .unwrap()
            .save(p("physnerf.safetensors"))
            .unwrap();
        let frame = neurofluid_dlf::records::RecordFrame {
            pos: vec![[0.0, 1.0, 0.0]; 3],
            vel: vec![[0.0; 3]; 3],
            box_points: Some(vec![[0.0; 3]; 2]),
            box_normals: Some(vec![[0.0, 1.0, 0.0]; 2]),
            ..Default::default()
        };
        neurofluid_dlf::records::write_record(&p("rec.msgpack.zst"), &[frame.clone(), frame])
            .unwrap();

        Seeds {
            manifest: read(p("scene.json")),
            transforms: read(p("transforms_train.json")),
            state: read(p("state.json")),
            metrics: read(p("metrics.jsonl")),
            png: read(p("img.png")),
            particles: read(p("particles.npz")),
            boundary: read(p("box.npz")),
            dlf_bpk: read(p("dlf.bpk")),
            physnerf: read(p("physnerf.safetensors")),
            record: read(p("rec.msgpack.zst")),
            _dir: dir,
        }
    })
}

fn tiny_ci_toml() -> String {
    std::fs::read_to_string(workspace_root().join("experiments/tiny-ci.toml")).unwrap()
}

fn experiment_from(text: &str) -> Result<(), TestCaseError> {
    let origin = Path::new("fuzz.toml");
    match Experiment::from_toml_str(text, origin) {
        Ok(e) => names_file(e.validate(origin), origin),
        Err(e) => names_file(Err::<(), _>(e), origin),
    }
}

proptest! {
    #![proptest_config(fixed(256))]

    #[test]
    fn experiment_toml_mutated(bytes in mutated(tiny_ci_toml().into_bytes())) {
        experiment_from(&String::from_utf8_lossy(&bytes))?;
    }

    #[test]
    fn experiment_toml_random(text in "[\\[\\]a-z_.=\"0-9 \\n-]{0,200}") {
        experiment_from(&text)?;
    }

    #[test]
    fn overrides_random(spec in "[a-z_.]{0,30}=?[\\[\\]{}a-z0-9.\"=, -]{0,30}") {
        let mut e = Experiment::from_toml_str(&tiny_ci_toml(), Path::new("tiny-ci.toml")).unwrap();
        if e.apply_override(&spec).is_ok() {
            let _ = e.validate(Path::new("tiny-ci.toml"));
        }
    }

    #[test]
    fn json_files_mutated(
        manifest in mutated(seeds().manifest.clone()),
        transforms in mutated(seeds().transforms.clone()),
        state in mutated(seeds().state.clone()),
        metrics in mutated(seeds().metrics.clone()),
    ) {
        let (_d, p) = file_with("scene.json", &manifest);
        match SceneManifest::read(&p) {
            Ok(m) => names_file(m.validate(&p), &p)?,
            Err(e) => names_file(Err::<(), _>(e), &p)?,
        }
        let (_d, p) = file_with("transforms_train.json", &transforms);
        names_file(TransformsFile::read(&p), &p)?;
        let (d, p) = file_with("state.json", &state);
        names_file(neurofluid_train::trainer::checkpoint::load_state::<
            neurofluid_train::trainer::checkpoint::CheckpointState,
        >(d.path()), &p)?;
        let (_d, p) = file_with("metrics.jsonl", &metrics);
        names_file(neurofluid_outputs::metrics_log::read_jsonl(&p), &p)?;
    }

    #[test]
    fn joblib_box_mutated(
        pt in mutated(std::fs::read(workspace_root().join("tests/data/box/box_joblib-1.6.pt")).unwrap()),
    ) {
        let (_d, p) = file_with("box.pt", &pt);
        names_file(BoxParticles::read(&p), &p)?;
    }

    #[test]
    fn images_and_arrays_mutated(
        png in mutated(seeds().png.clone()),
        particles in mutated(seeds().particles.clone()),
        boundary in mutated(seeds().boundary.clone()),
    ) {
        let (_d, p) = file_with("img.png", &png);
        names_file(png_size(&p), &p)?;
        names_file(Image::read(&p), &p)?;
        let (_d, p) = file_with("particles.npz", &particles);
        names_file(Particles::read(&p), &p)?;
        let (_d, p) = file_with("box.npz", &boundary);
        names_file(BoxParticles::read(&p), &p)?;
    }
}

proptest! {
    #![proptest_config(fixed(48))]

    #[test]
    fn weights_and_records_mutated(
        bpk in mutated(seeds().dlf_bpk.clone()),
        physnerf in mutated(seeds().physnerf.clone()),
        record in mutated(seeds().record.clone()),
    ) {
        // (loading draws no random number: `loading_draws`)
        let device = neurofluid_core::device::cpu();
        let (_d, p) = file_with("dlf.bpk", &bpk);
        names_file(neurofluid_dlf::load_dlf(&p, Default::default(), &device), &p)?;
        let (_d, p) = file_with("physnerf.safetensors", &physnerf);
        names_file(
            neurofluid_physnerf::PhysNerf::load(&p, &device, burn::tensor::DType::F32),
            &p,
        )?;
        let (_d, p) = file_with("rec.msgpack.zst", &record);
        names_file(neurofluid_dlf::records::read_record(&p), &p)?;
    }
}

/// The DLF weights as published (`.pt`, a zip of pickles; `.safetensors`): 2.7 MB each, so fewer
/// cases, with the damage concentrated where the structure is (the start and the zip directory
/// at the end) by [`mutated`]'s head and tail flips.
fn published_weights() -> &'static (Vec<u8>, Vec<u8>) {
    static W: OnceLock<(Vec<u8>, Vec<u8>)> = OnceLock::new();
    W.get_or_init(|| {
        let dir = workspace_root().join("assets/dlf_pretrained");
        (
            std::fs::read(dir.join("pretrained_model_weights.pt")).unwrap(),
            std::fs::read(dir.join("pretrained_model_weights.safetensors")).unwrap(),
        )
    })
}

proptest! {
    #![proptest_config(fixed(24))]

    #[test]
    fn published_dlf_weights_mutated(
        pt in mutated(published_weights().0.clone()),
        st in mutated(published_weights().1.clone()),
    ) {
        let device = neurofluid_core::device::cpu();
        let (_d, p) = file_with("w.pt", &pt);
        names_file(neurofluid_dlf::load_dlf(&p, Default::default(), &device), &p)?;
        let (_d, p) = file_with("w.safetensors", &st);
        names_file(neurofluid_dlf::load_dlf(&p, Default::default(), &device), &p)?;
    }
}

/// Pickles made of structure only (containers, marks, memo puts and gets, small ints): nested,
/// self-referencing and memo-doubling ones among them. Each reads or fails with the file's
/// name, within the depth and value limits: no stack overflow, no runaway memory.
fn pickle_ops() -> impl Strategy<Value = Vec<u8>> {
    let op = prop_oneof![
        Just(vec![b'(']),
        Just(vec![b')']),
        Just(vec![b']']),
        Just(vec![b'}']),
        Just(vec![b't']),
        Just(vec![0x85]),
        Just(vec![0x86]),
        Just(vec![0x87]),
        Just(vec![b'a']),
        Just(vec![b'e']),
        Just(vec![b's']),
        Just(vec![b'u']),
        Just(vec![0x94]),
        Just(vec![b'N']),
        (0u8..6).prop_map(|i| vec![b'h', i]),
        any::<u8>().prop_map(|k| vec![b'K', k]),
    ];
    (prop::collection::vec(op, 0..600), 0usize..3).prop_map(|(ops, deep)| {
        let mut b = vec![0x80, 4];
        // some cases start from a deep or doubling prefix
        match deep {
            1 => b.extend(std::iter::repeat_n(0x85, 10_000)),
            2 => b.extend(std::iter::repeat_n([b']', 0x94, b'h', 0, b'h', 0, 0x86], 40).flatten()),
            _ => {}
        }
        b.extend(ops.concat());
        b.push(b'.');
        b
    })
}

/// An `.npy` header declaring `shape` over a few bytes of data, stored in an `.npz`.
fn npz_declaring(shape: &[u64], data: &[u8]) -> Vec<u8> {
    use std::io::Write;
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let header = format!(
        "{{'descr': '<f4', 'fortran_order': False, 'shape': ({},), }}\n",
        dims.join(", ")
    );
    let mut npy = b"\x93NUMPY\x01\x00".to_vec();
    npy.extend((header.len() as u16).to_le_bytes());
    npy.extend(header.as_bytes());
    npy.extend(data);
    let mut zip = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    zip.start_file("pos.npy", zip::write::SimpleFileOptions::default())
        .unwrap();
    zip.write_all(&npy).unwrap();
    zip.finish().unwrap().into_inner()
}

proptest! {
    #![proptest_config(fixed(256))]

    #[test]
    fn structural_pickles(pickle in pickle_ops()) {
        let (_d, p) = file_with("box.pt", &pickle);
        names_file(BoxParticles::read(&p), &p)?;
    }

    #[test]
    fn huge_declared_sizes(
        shape in prop::collection::vec(prop_oneof![0u64..8, 1u64 << 20..1u64 << 40, Just(u64::MAX / 3)], 1..4),
        data in prop::collection::vec(any::<u8>(), 0..64),
        vertices in prop_oneof![any::<u64>(), 0u64..64],
        floats in prop::collection::vec(any::<u8>(), 0..64),
        ascii in any::<bool>(),
    ) {
        let (_d, p) = file_with("particles.npz", &npz_declaring(&shape, &data));
        let read = neurofluid_core::npz::NpzReader::open(&p).and_then(|mut r| r.f32("pos"));
        if let Ok(a) = &read {
            prop_assert_eq!(a.len() as u64, shape.iter().product::<u64>());
        }
        names_file(read, &p)?;
        let format = if ascii { "ascii" } else { "binary_little_endian" };
        let mut ply = format!(
            "ply\nformat {format} 1.0\nelement vertex {vertices}\nproperty float x\n\
             property float y\nproperty float z\nend_header\n"
        )
        .into_bytes();
        ply.extend(floats);
        let (_d, p) = file_with("cloud.ply", &ply);
        names_file(neurofluid_outputs::formats::ply::read_ply(&p), &p)?;
    }
}

proptest! {
    #![proptest_config(fixed(32))]

    #[test]
    fn compressed_records_expanding(
        blocks in prop_oneof![1usize..600, 15_000usize..20_000],
        byte in any::<u8>(),
    ) {
        // a zstd frame of RLE blocks of 128 KiB each: 4 bytes on disk per block
        let mut z = vec![0x28, 0xb5, 0x2f, 0xfd, 0x00, 7 << 3];
        for i in 0..blocks {
            let header = u32::from(i + 1 == blocks) | (1 << 1) | (131_072 << 3);
            z.extend(&header.to_le_bytes()[..3]);
            z.push(byte);
        }
        let (_d, p) = file_with("rec.msgpack.zst", &z);
        let read = neurofluid_dlf::records::read_record(&p);
        if blocks >= 15_000 {
            // 2 GiB from 70 KB: over the ratio cap whatever the bytes
            prop_assert!(read.is_err());
        }
        names_file(read, &p)?;
    }
}
