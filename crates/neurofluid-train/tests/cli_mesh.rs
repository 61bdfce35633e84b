//! `neurofluid-train mesh` turns a folder of particle files into one closed surface each.

use std::process::Command;

use neurofluid_core::scene::Particles;
use neurofluid_outputs::geometry::mesh::Mesh;

#[test]
fn mesh_writes_one_surface_per_particle_file() {
    let tmp = tempfile::tempdir().unwrap();
    let input = tmp.path().join("particles");
    let r = 0.025f32;
    for (frame, n) in [(0, 6), (1, 8)] {
        let mut pos = Vec::new();
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    pos.push([i, j, k].map(|c| (c as f32 + 0.5) * 2.0 * r));
                }
            }
        }
        let vel = vec![[0.0; 3]; pos.len()];
        Particles { pos, vel }
            .write(&input.join(format!("{frame:04}.npz")))
            .unwrap();
    }
    let out = tmp.path().join("meshes");
    let run = Command::new(env!("CARGO_BIN_EXE_neurofluid-train"))
        .arg("mesh")
        .arg(&input)
        .arg("--output")
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let mut volumes = Vec::new();
    for frame in ["0000", "0001"] {
        let obj = std::fs::read_to_string(out.join(format!("{frame}.obj"))).unwrap();
        let numbers = |l: &str| -> Vec<f64> { l.split(' ').map(|x| x.parse().unwrap()).collect() };
        let mesh = Mesh {
            vertices: obj
                .lines()
                .filter_map(|l| l.strip_prefix("v "))
                .map(|l| {
                    let c = numbers(l);
                    [c[0] as f32, c[1] as f32, c[2] as f32]
                })
                .collect(),
            triangles: obj
                .lines()
                .filter_map(|l| l.strip_prefix("f "))
                .map(|l| {
                    let i = numbers(l);
                    [i[0] as u32 - 1, i[1] as u32 - 1, i[2] as u32 - 1]
                })
                .collect(),
        };
        assert!(mesh.is_closed(), "{frame}");
        volumes.push(mesh.volume());
    }
    // the larger block's surface encloses about (8/6)³ times the volume
    let ratio = volumes[1] / volumes[0];
    assert!((ratio - (8.0f64 / 6.0).powi(3)).abs() < 0.2, "{volumes:?}");
}

/// Settings and outputs are checked before any mesh is written: non-finite or tiny settings,
/// an output that would replace an input, two inputs with one stem; the file limit knob holds.
#[test]
fn mesh_refuses_what_it_cannot_do_before_writing() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let cube: Vec<[f32; 3]> = (0..27)
        .map(|i| [i % 3, (i / 3) % 3, i / 9].map(|c| c as f32 * 0.05))
        .collect();
    for dir in [&a, &b] {
        std::fs::create_dir_all(dir).unwrap();
        neurofluid_outputs::formats::ply::write_ply(
            &dir.join("0000.ply"),
            &cube,
            None,
            neurofluid_outputs::formats::ply::PlyFormat::BinaryLittleEndian,
        )
        .unwrap();
    }
    let before = std::fs::read(a.join("0000.ply")).unwrap();
    let out = tmp.path().join("out");
    let mesh = |args: &[&str], env: Option<(&str, &str)>| {
        let mut c = Command::new(env!("CARGO_BIN_EXE_neurofluid-train"));
        c.arg("mesh").args(args);
        if let Some((k, v)) = env {
            c.env(k, v);
        }
        let run = c.output().unwrap();
        assert!(!run.status.success(), "{args:?} succeeded");
        let err = String::from_utf8_lossy(&run.stderr).into_owned();
        assert!(!err.contains("panicked"), "{err}");
        err
    };
    let (a_s, b_s, out_s) = (
        a.to_str().unwrap(),
        b.to_str().unwrap(),
        out.to_str().unwrap(),
    );
    let err = mesh(&[a_s, "--output", out_s, "--smoothing-length", "inf"], None);
    assert!(err.contains("--smoothing-length"), "{err}");
    let err = mesh(&[a_s, "--output", out_s, "--cube-size", "1e-5"], None);
    assert!(
        err.contains("--cube-size") && err.contains("limit"),
        "{err}"
    );
    let err = mesh(&[a_s, "--output", a_s, "--format", "ply"], None);
    assert!(err.contains("would replace the input"), "{err}");
    assert_eq!(std::fs::read(a.join("0000.ply")).unwrap(), before);
    let err = mesh(&[a_s, b_s, "--output", out_s], None);
    assert!(err.contains("same stem"), "{err}");
    assert!(!out.exists(), "a mesh was written");
    // a particle file over the file limit, named with the limit's knob
    let big = tmp.path().join("big");
    Particles {
        pos: vec![[0.0; 3]; 100_000],
        vel: vec![[0.0; 3]; 100_000],
    }
    .write(&big.join("0000.npz"))
    .unwrap();
    let err = mesh(
        &[big.to_str().unwrap(), "--output", out_s],
        Some((neurofluid_core::limits::MAX_FILE_MB_ENV, "1")),
    );
    assert!(
        err.contains("0000.npz") && err.contains(neurofluid_core::limits::MAX_FILE_MB_ENV),
        "{err}"
    );
}
