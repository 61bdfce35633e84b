//! Fluid surfaces from particles: splashsurf's marching cubes over an SPH density of the
//! particles (`splashsurf_lib`), written as OBJ or PLY so a rollout opens in Blender or
//! ParaView.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;
use splashsurf_lib::nalgebra::Vector3;

/// How the surface is reconstructed, in multiples of the particle radius (splashsurf's own
/// relative settings).
#[derive(Debug, Clone, Copy, PartialEq, clap::Args)]
pub struct SurfaceSettings {
    /// Kernel smoothing length (× particle radius; the compact support is twice this).
    #[arg(long, default_value_t = 2.0)]
    pub smoothing_length: f64,
    /// Edge length of the marching-cubes grid (× particle radius).
    #[arg(long, default_value_t = 0.5)]
    pub cube_size: f64,
    /// Density threshold of the surface (× rest density).
    #[arg(long, default_value_t = 0.6)]
    pub threshold: f64,
}

impl Default for SurfaceSettings {
    fn default() -> Self {
        Self {
            smoothing_length: 2.0,
            cube_size: 0.5,
            threshold: 0.6,
        }
    }
}

impl SurfaceSettings {
    /// Every setting finite and > 0 (the command line takes any float).
    pub fn check(&self) -> anyhow::Result<()> {
        for (flag, v) in [
            ("--smoothing-length", self.smoothing_length),
            ("--cube-size", self.cube_size),
            ("--threshold", self.threshold),
        ] {
            anyhow::ensure!(
                v.is_finite() && v > 0.0,
                "{flag} must be a finite number > 0, got {v}"
            );
        }
        Ok(())
    }

    /// The marching-cubes grid over `particles` (their bounds grown by the kernel's support)
    /// stays within [`neurofluid_core::limits::max_decoded_bytes`] at 16 bytes a grid point,
    /// so a tiny `--cube-size` is an error rather than an allocation that aborts.
    fn check_grid(&self, particles: &[[f32; 3]], radius: f64) -> anyhow::Result<()> {
        let cube = self.cube_size * radius;
        let margin = 2.0 * self.smoothing_length * radius;
        let points: f64 = (0..3)
            .map(|a| {
                let (lo, hi) = particles.iter().fold((f64::MAX, f64::MIN), |(lo, hi), p| {
                    (lo.min(p[a] as f64), hi.max(p[a] as f64))
                });
                ((hi - lo + 2.0 * margin) / cube).ceil() + 1.0
            })
            .product();
        let limit = neurofluid_core::limits::max_decoded_bytes() as f64 / 16.0;
        anyhow::ensure!(
            points <= limit,
            "--cube-size {} (× radius {radius}) makes a grid of {points:.3e} points over the \
             particles, over the limit of {limit:.3e} ({}; raise --cube-size)",
            self.cube_size,
            neurofluid_core::limits::MAX_FILE_MB_ENV
        );
        Ok(())
    }
}

/// A triangle mesh.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub vertices: Vec<[f32; 3]>,
    /// Triangles as vertex indices, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
}

/// The surface of the fluid the particles of radius `radius` sample.
pub fn reconstruct(
    particles: &[[f32; 3]],
    radius: f32,
    settings: &SurfaceSettings,
) -> anyhow::Result<Mesh> {
    anyhow::ensure!(
        radius.is_finite() && radius > 0.0,
        "the particle radius must be > 0, got {radius}"
    );
    settings.check()?;
    anyhow::ensure!(
        particles.iter().flatten().all(|v| v.is_finite()),
        "particle positions must be finite"
    );
    if particles.is_empty() {
        return Ok(Mesh::default());
    }
    let r = radius as f64;
    settings.check_grid(particles, r)?;
    let params = splashsurf_lib::Parameters {
        particle_radius: r,
        rest_density: 1000.0,
        compact_support_radius: 2.0 * settings.smoothing_length * r,
        cube_size: settings.cube_size * r,
        iso_surface_threshold: settings.threshold,
        particle_aabb: None,
        enable_multi_threading: true,
        enable_simd: true,
        spatial_decomposition: splashsurf_lib::SpatialDecomposition::None,
        global_neighborhood_list: false,
    };
    let pts: Vec<Vector3<f64>> = particles
        .iter()
        .map(|p| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        .collect();
    let surface = splashsurf_lib::reconstruct_surface::<i64, f64>(&pts, &params)
        .map_err(|e| anyhow::anyhow!("surface reconstruction: {e}"))?;
    let mesh = &surface.mesh;
    Ok(Mesh {
        vertices: mesh
            .vertices
            .iter()
            .map(|v| [v.x as f32, v.y as f32, v.z as f32])
            .collect(),
        triangles: mesh
            .triangles
            .iter()
            .map(|t| [t[0] as u32, t[1] as u32, t[2] as u32])
            .collect(),
    })
}

impl Mesh {
    /// The enclosed volume (divergence theorem; positive for outward-facing triangles).
    pub fn volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertices[i as usize].map(f64::from));
                (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                    + a[2] * (b[0] * c[1] - b[1] * c[0]))
                    / 6.0
            })
            .sum()
    }

    /// The edges not shared by exactly two triangles running through them in opposite
    /// directions, and the number of all edges.
    pub fn open_edges(&self) -> (usize, usize) {
        // per undirected edge: (uses, uses in one direction − uses in the other)
        let mut edges: HashMap<(u32, u32), (u32, i32)> =
            HashMap::with_capacity(self.triangles.len() * 2);
        for t in &self.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let e = edges.entry((a.min(b), a.max(b))).or_default();
                e.0 += 1;
                e.1 += if a < b { 1 } else { -1 };
            }
        }
        let open = edges.values().filter(|&&e| e != (2, 0)).count();
        (open, edges.len())
    }

    /// Whether every edge is shared by exactly two triangles, in opposite directions (a closed,
    /// consistently oriented surface).
    pub fn is_closed(&self) -> bool {
        !self.triangles.is_empty() && self.open_edges().0 == 0
    }

    /// Writes the mesh as OBJ (`.obj`) or binary PLY (`.ply`), by the extension, atomically.
    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
        let bytes = match ext {
            "obj" => self.obj().into_bytes(),
            "ply" => self.ply(),
            _ => anyhow::bail!("{}: expected a .obj or .ply file name", path.display()),
        };
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        neurofluid_core::atomic::write_bytes(path, &bytes)
            .with_context(|| format!("writing {}", path.display()))
    }

    fn obj(&self) -> String {
        let mut s = String::from("# fluid surface written by neurofluid-train mesh\n");
        for v in &self.vertices {
            let _ = writeln!(s, "v {} {} {}", v[0], v[1], v[2]);
        }
        for t in &self.triangles {
            let _ = writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
        }
        s
    }

    fn ply(&self) -> Vec<u8> {
        let mut out = format!(
            "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\n\
             property float y\nproperty float z\nelement face {}\n\
             property list uchar uint vertex_indices\nend_header\n",
            self.vertices.len(),
            self.triangles.len()
        )
        .into_bytes();
        for v in &self.vertices {
            for c in v {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
        for t in &self.triangles {
            out.push(3);
            for i in t {
                out.extend_from_slice(&i.to_le_bytes());
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A block of particles on the 2r lattice: its surface is closed and encloses about the
    /// block's volume (n·(2r)³, each particle's cell).
    #[test]
    fn a_block_of_particles_gives_a_closed_surface_of_its_volume() {
        let r = 0.025f32;
        let n = 12;
        let mut pts = Vec::new();
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    pts.push([i as f32, j as f32, k as f32].map(|c| (c + 0.5) * 2.0 * r));
                }
            }
        }
        let mesh = reconstruct(&pts, r, &SurfaceSettings::default()).unwrap();
        assert!(mesh.is_closed(), "{} triangles", mesh.triangles.len());
        let want = (n as f64 * 2.0 * r as f64).powi(3);
        let got = mesh.volume();
        assert!(
            (got - want).abs() < 0.1 * want,
            "volume {got:.6} vs the block's {want:.6}"
        );
        // a mesh with a missing triangle is open
        let mut open = mesh.clone();
        open.triangles.pop();
        assert!(!open.is_closed());
    }

    #[test]
    fn meshes_write_as_obj_and_ply() {
        let mesh = Mesh {
            vertices: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
            ],
            triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        };
        assert!(mesh.is_closed());
        assert!((mesh.volume() - 1.0 / 6.0).abs() < 1e-12);
        let dir = tempfile::tempdir().unwrap();
        mesh.write(&dir.path().join("t.obj")).unwrap();
        let obj = std::fs::read_to_string(dir.path().join("t.obj")).unwrap();
        assert_eq!(obj.lines().filter(|l| l.starts_with("v ")).count(), 4);
        assert!(obj.contains("f 1 3 2"));
        mesh.write(&dir.path().join("t.ply")).unwrap();
        let ply = std::fs::read(dir.path().join("t.ply")).unwrap();
        let header_end = ply.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        assert_eq!(ply.len() - header_end, 4 * 12 + 4 * 13);
        assert!(mesh.write(&dir.path().join("t.stl")).is_err());
    }
}
