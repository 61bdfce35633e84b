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
    /// Every setting > 0 and at most [`MAX_RELATIVE_SETTING`] (the command line takes any
    /// float; a threshold of 10³⁰ rest densities finds no surface, a kernel of 10³⁰ radii one
    /// blob).
    pub fn check(&self) -> anyhow::Result<()> {
        for (flag, v) in [
            ("--smoothing-length", self.smoothing_length),
            ("--cube-size", self.cube_size),
            ("--threshold", self.threshold),
        ] {
            anyhow::ensure!(
                v > 0.0 && v <= MAX_RELATIVE_SETTING,
                "{flag} must be a number > 0 and ≤ {MAX_RELATIVE_SETTING}, got {v}"
            );
        }
        Ok(())
    }

    /// The neighbour pairs of `particles` within the kernel's support stay within
    /// [`neurofluid_core::limits::max_decoded_bytes`] at 8 bytes a pair, counted from above by
    /// a grid of cells as wide as the support (each particle against the 27 cells around its
    /// own), so particles piled on one another are an error rather than neighbour lists that
    /// exhaust memory (200 000 at one point would make 4·10¹⁰ pairs).
    fn check_neighbours(&self, particles: &[[f32; 3]], radius: f64) -> anyhow::Result<()> {
        let support = 2.0 * self.smoothing_length * radius;
        let cell_of = |p: &[f32; 3]| p.map(|v| (v as f64 / support).floor() as i64);
        let mut cells: HashMap<[i64; 3], u64> = HashMap::new();
        for p in particles {
            *cells.entry(cell_of(p)).or_default() += 1;
        }
        let mut pairs: u64 = 0;
        for (c, &n) in &cells {
            let mut around = 0;
            for d in 0..27_i64 {
                let offset = [d % 3 - 1, d / 3 % 3 - 1, d / 9 - 1];
                let key = [c[0] + offset[0], c[1] + offset[1], c[2] + offset[2]];
                around += cells.get(&key).copied().unwrap_or(0);
            }
            pairs = pairs.saturating_add(n.saturating_mul(around));
        }
        let limit = neurofluid_core::limits::max_decoded_bytes() / 8;
        let (cell, most) = cells.iter().max_by_key(|(_, n)| **n).expect("particles");
        anyhow::ensure!(
            pairs <= limit,
            "the particles make up to {pairs} neighbour pairs within the kernel's support \
             ({support} m), over the limit of {limit} ({}); the fullest cell holds {most} \
             particles near {:?}: particles piled on one another (a collapsed or damaged set)",
            neurofluid_core::limits::MAX_FILE_MB_ENV,
            cell.map(|i| i as f64 * support)
        );
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

/// The largest particle radius a surface is made for, in metres.
pub const MAX_RADIUS: f32 = 1e3;

/// The largest smoothing length, cube size or threshold (each relative to the radius or the
/// rest density).
pub const MAX_RELATIVE_SETTING: f64 = 10.0;

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
        radius > 0.0 && radius <= MAX_RADIUS,
        "the particle radius must be > 0 and ≤ {MAX_RADIUS} m, got {radius}"
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
    settings.check_neighbours(particles, r)?;
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

    /// Particles piled at one point, a radius of 10³⁰ m and a threshold of 10³⁰ are errors
    /// before splashsurf runs (issue 72: 200k coincident particles took 3.8 GB).
    #[test]
    fn piled_particles_and_absurd_settings_are_refused() {
        let settings = SurfaceSettings::default();
        let piled = vec![[0.1f32, 0.2, 0.3]; 20_000];
        let e = reconstruct(&piled, 0.025, &settings)
            .unwrap_err()
            .to_string();
        assert!(e.contains("neighbour pairs") && e.contains("20000"), "{e}");
        let one = [[0.0f32; 3]];
        let e = reconstruct(&one, 1e30, &settings).unwrap_err().to_string();
        assert!(e.contains("radius"), "{e}");
        let high = SurfaceSettings {
            threshold: 1e30,
            ..settings
        };
        let e = reconstruct(&one, 0.025, &high).unwrap_err().to_string();
        assert!(e.contains("--threshold"), "{e}");
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
