//! Per-frame fluid particles (`pos`, `vel`) and the static box particles (`box`, `box_normals`).

use std::path::Path;

use crate::npz::{NpzReader, NpzWriter};

use super::error::{Result, SceneError};

/// Fluid particles of one frame, float32.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Particles {
    /// Positions, one row per particle.
    pub pos: Vec<[f32; 3]>,
    /// Velocities, one row per particle.
    pub vel: Vec<[f32; 3]>,
}

impl Particles {
    /// Number of particles.
    pub fn len(&self) -> usize {
        self.pos.len()
    }

    /// True when there is no particle.
    pub fn is_empty(&self) -> bool {
        self.pos.is_empty()
    }

    /// Reads a `.npz` holding `pos` and `vel` (float32 or float64, shape N×3).
    pub fn read(path: &Path) -> Result<Self> {
        let mut r = open(path)?;
        let pos = rows3(path, &mut r, "pos")?;
        let vel = rows3(path, &mut r, "vel")?;
        if pos.len() != vel.len() {
            return Err(SceneError::field(
                path,
                "vel",
                format!("{} rows like `pos`, got {}", pos.len(), vel.len()),
            ));
        }
        Ok(Self { pos, vel })
    }

    /// Writes `pos` and `vel` as float32 N×3 arrays, atomically.
    pub fn write(&self, path: &Path) -> Result<()> {
        let mut w = NpzWriter::new();
        w.add_f32("pos", &[self.pos.len(), 3], self.pos.as_flattened());
        w.add_f32("vel", &[self.vel.len(), 3], self.vel.as_flattened());
        finish(w, path)
    }
}

/// The static box: wall particles on the box surface with unit normals pointing into the box.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BoxParticles {
    /// Wall particle positions.
    pub points: Vec<[f32; 3]>,
    /// Unit normals pointing from the wall into the fluid region.
    pub normals: Vec<[f32; 3]>,
}

impl BoxParticles {
    /// Number of wall particles.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True when there is no wall particle.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Bounding box of the wall particles (`None` when empty).
    pub fn bounds(&self) -> Option<([f32; 3], [f32; 3])> {
        let first = *self.points.first()?;
        Some(
            self.points
                .iter()
                .fold((first, first), |(mut lo, mut hi), p| {
                    for a in 0..3 {
                        lo[a] = lo[a].min(p[a]);
                        hi[a] = hi[a].max(p[a]);
                    }
                    (lo, hi)
                }),
        )
    }

    /// Reads the box: `box.npz` (`box`, `box_normals`), or the released scenes' `box.pt` (a
    /// joblib or plain pickle of the same dict; its `box.npz` sibling is used when present).
    pub fn read(path: &Path) -> Result<Self> {
        if path.extension().is_some_and(|e| e == "pt") {
            let npz = path.with_extension("npz");
            if npz.is_file() {
                return Self::read(&npz);
            }
            let bytes = crate::input_file::read(path).map_err(|e| SceneError::io(path, e))?;
            let arrays = super::unpickle::pickled_arrays(&bytes)
                .map_err(|message| SceneError::field(path, "box", message))?;
            let rows = |key: &str| -> Result<Vec<[f32; 3]>> {
                let a = arrays.get(key).ok_or_else(|| {
                    SceneError::field(path, key, "an (N, 3) float array in the pickled dict")
                })?;
                if a.shape.len() != 2 || a.shape[1] != 3 {
                    return Err(SceneError::field(
                        path,
                        key,
                        format!("shape (N, 3), found {:?}", a.shape),
                    ));
                }
                Ok(a.data
                    .chunks_exact(3)
                    .map(|c| [c[0] as f32, c[1] as f32, c[2] as f32])
                    .collect())
            };
            return Self::checked(path, rows("box")?, rows("box_normals")?);
        }
        let mut r = open(path)?;
        let points = rows3(path, &mut r, "box")?;
        let normals = rows3(path, &mut r, "box_normals")?;
        Self::checked(path, points, normals)
    }

    /// A box read from `path`: non-empty, one finite normal per point.
    fn checked(path: &Path, points: Vec<[f32; 3]>, normals: Vec<[f32; 3]>) -> Result<Self> {
        if points.is_empty() {
            return Err(SceneError::field(
                path,
                "box",
                "at least one box particle (the walls DLF collides with), found none",
            ));
        }
        if points.len() != normals.len() {
            return Err(SceneError::field(
                path,
                "box_normals",
                format!("{} rows like `box`, got {}", points.len(), normals.len()),
            ));
        }
        for (key, rows) in [("box", &points), ("box_normals", &normals)] {
            if let Some(i) = rows.iter().position(|r| !r.iter().all(|v| v.is_finite())) {
                return Err(SceneError::field(
                    path,
                    format!("{key}[{i}]"),
                    "finite numbers",
                ));
            }
        }
        Ok(Self { points, normals })
    }

    /// Writes the box as a plain Python pickle (`box.pt`, loadable by `joblib.load` and
    /// `pickle.load`), atomically.
    pub fn write_pickle(&self, path: &Path) -> Result<()> {
        crate::atomic::write_bytes(path, &super::pickle::box_pickle(self))
            .map_err(|e| SceneError::io(path, e))
    }

    /// Writes `box` and `box_normals` as float32 N×3 arrays, atomically.
    pub fn write(&self, path: &Path) -> Result<()> {
        let mut w = NpzWriter::new();
        w.add_f32("box", &[self.points.len(), 3], self.points.as_flattened());
        w.add_f32(
            "box_normals",
            &[self.normals.len(), 3],
            self.normals.as_flattened(),
        );
        finish(w, path)
    }
}

fn open(path: &Path) -> Result<NpzReader> {
    if path.symlink_metadata().is_err() {
        return Err(SceneError::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        ));
    }
    NpzReader::open(path).map_err(|e| SceneError::Npz {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

fn finish(w: NpzWriter, path: &Path) -> Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| SceneError::io(parent, e))?;
    }
    w.write(path).map_err(|e| SceneError::Npz {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

fn rows3(path: &Path, r: &mut NpzReader, name: &str) -> Result<Vec<[f32; 3]>> {
    let a = r.f32(name).map_err(|e| SceneError::Npz {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    if a.shape.len() != 2 || a.shape[1] != 3 {
        return Err(SceneError::field(
            path,
            name,
            format!("shape (N, 3), got {:?}", a.shape),
        ));
    }
    if a.data.iter().any(|v| !v.is_finite()) {
        return Err(SceneError::field(path, name, "finite values"));
    }
    Ok(a.data.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}
