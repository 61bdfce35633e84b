//! `neurofluid-train mesh` turns a folder of particle files into one closed surface each.

use std::process::Command;

use neurofluid_core::scene::Particles;
use neurofluid_train::mesh::Mesh;

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
