//! The fluid surface as an iso-surface of the normalised SPH density field
//! φ(x) = Σⱼ V₀ W(|x − xⱼ|) (cubic kernel, support 4r), splatted on a voxel grid and
//! interpolated trilinearly; the surface is φ = iso (≈ 0.5: half the rest density, as in
//! NeuroFluid's OpenVDB meshes). A coarse block grid of maxima lets rays skip empty space.

use glam::Vec3;
use rayon::prelude::*;

use crate::sph::kernel::CubicKernel;

/// Cells per block edge of the empty-space-skipping grid.
const BLOCK: usize = 8;

/// A scalar field on a regular grid (values at cell corners).
#[derive(Debug, Clone)]
pub struct DensityField {
    origin: Vec3,
    cell: f32,
    dims: [usize; 3],
    values: Vec<f32>,
    bdims: [usize; 3],
    block_max: Vec<f32>,
    /// The iso level of the surface.
    pub iso: f32,
}

impl DensityField {
    /// Splats particles at `pos` (volume `volume` each) with a cubic kernel of support `support`
    /// onto a grid of spacing `cell`. Deterministic: each z-slab is summed in particle order.
    pub fn build(pos: &[[f32; 3]], volume: f32, support: f32, cell: f32, iso: f32) -> Self {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for p in pos {
            lo = lo.min(Vec3::from(*p));
            hi = hi.max(Vec3::from(*p));
        }
        if pos.is_empty() {
            lo = Vec3::ZERO;
            hi = Vec3::ZERO;
        }
        let pad = Vec3::splat(support + 2.0 * cell);
        let origin = lo - pad;
        let ext = hi + pad - origin;
        let dims = [
            (ext.x / cell).ceil() as usize + 1,
            (ext.y / cell).ceil() as usize + 1,
            (ext.z / cell).ceil() as usize + 1,
        ];
        let kernel = CubicKernel::new(support as f64);
        let reach = (support / cell).ceil() as i64;
        let plane = dims[0] * dims[1];
        let mut values = vec![0.0f32; plane * dims[2]];
        // particles binned by the z index of their nearest grid plane
        let mut by_z: Vec<Vec<u32>> = vec![Vec::new(); dims[2]];
        for (i, p) in pos.iter().enumerate() {
            let kz = (((p[2] - origin.z) / cell).round() as usize).min(dims[2] - 1);
            by_z[kz].push(i as u32);
        }
        values
            .par_chunks_mut(plane)
            .enumerate()
            .for_each(|(k, slab)| {
                let z = origin.z + k as f32 * cell;
                let k0 = (k as i64 - reach).max(0) as usize;
                let k1 = ((k as i64 + reach) as usize).min(dims[2] - 1);
                for list in &by_z[k0..=k1] {
                    for &i in list {
                        let p = pos[i as usize];
                        let dz = z - p[2];
                        if dz.abs() >= support {
                            continue;
                        }
                        let ci = ((p[0] - origin.x) / cell).round() as i64;
                        let cj = ((p[1] - origin.y) / cell).round() as i64;
                        for j in (cj - reach).max(0)..=(cj + reach).min(dims[1] as i64 - 1) {
                            let dy = origin.y + j as f32 * cell - p[1];
                            for ii in (ci - reach).max(0)..=(ci + reach).min(dims[0] as i64 - 1) {
                                let dx = origin.x + ii as f32 * cell - p[0];
                                let r = (dx * dx + dy * dy + dz * dz).sqrt();
                                if r < support {
                                    slab[j as usize * dims[0] + ii as usize] +=
                                        volume * kernel.w(r as f64) as f32;
                                }
                            }
                        }
                    }
                }
            });
        let bdims = dims.map(|d| d.div_ceil(BLOCK));
        let mut block_max = vec![0.0f32; bdims[0] * bdims[1] * bdims[2]];
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let v = values[(k * dims[1] + j) * dims[0] + i];
                    // a cell corner belongs to the blocks on both sides of a block border
                    for bk in block_span(k, bdims[2]) {
                        for bj in block_span(j, bdims[1]) {
                            for bi in block_span(i, bdims[0]) {
                                let b = &mut block_max[(bk * bdims[1] + bj) * bdims[0] + bi];
                                *b = b.max(v);
                            }
                        }
                    }
                }
            }
        }
        Self {
            origin,
            cell,
            dims,
            values,
            bdims,
            block_max,
            iso,
        }
    }

    /// Lower and upper corner of the grid.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let ext = Vec3::new(
            (self.dims[0] - 1) as f32,
            (self.dims[1] - 1) as f32,
            (self.dims[2] - 1) as f32,
        ) * self.cell;
        (self.origin, self.origin + ext)
    }

    fn at(&self, i: usize, j: usize, k: usize) -> f32 {
        self.values[(k * self.dims[1] + j) * self.dims[0] + i]
    }

    /// Trilinearly interpolated φ at `p` (0 outside the grid).
    pub fn sample(&self, p: Vec3) -> f32 {
        let q = (p - self.origin) / self.cell;
        if q.min_element() < 0.0 {
            return 0.0;
        }
        let (i, j, k) = (q.x as usize, q.y as usize, q.z as usize);
        if i + 1 >= self.dims[0] || j + 1 >= self.dims[1] || k + 1 >= self.dims[2] {
            return 0.0;
        }
        let f = q - Vec3::new(i as f32, j as f32, k as f32);
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let c00 = lerp(self.at(i, j, k), self.at(i + 1, j, k), f.x);
        let c10 = lerp(self.at(i, j + 1, k), self.at(i + 1, j + 1, k), f.x);
        let c01 = lerp(self.at(i, j, k + 1), self.at(i + 1, j, k + 1), f.x);
        let c11 = lerp(self.at(i, j + 1, k + 1), self.at(i + 1, j + 1, k + 1), f.x);
        lerp(lerp(c00, c10, f.y), lerp(c01, c11, f.y), f.z)
    }

    /// ∇φ at `p` by central differences of the interpolated field.
    pub fn gradient(&self, p: Vec3) -> Vec3 {
        let e = 0.5 * self.cell;
        Vec3::new(
            self.sample(p + Vec3::X * e) - self.sample(p - Vec3::X * e),
            self.sample(p + Vec3::Y * e) - self.sample(p - Vec3::Y * e),
            self.sample(p + Vec3::Z * e) - self.sample(p - Vec3::Z * e),
        ) / (2.0 * e)
    }

    /// Outward unit surface normal at `p` (−∇φ normalised).
    pub fn normal(&self, p: Vec3) -> Vec3 {
        (-self.gradient(p)).normalize_or(Vec3::Y)
    }

    /// If the block containing `p` holds no value above the iso level, the ray parameter at
    /// which the ray `o + t·d` leaves that block; otherwise `None`.
    pub fn skip(&self, p: Vec3, o: Vec3, d: Vec3) -> Option<f32> {
        let q = (p - self.origin) / (self.cell * BLOCK as f32);
        if q.min_element() < 0.0 {
            return None;
        }
        let b = [q.x as usize, q.y as usize, q.z as usize];
        if (0..3).any(|a| b[a] >= self.bdims[a]) {
            return None;
        }
        if self.block_max[(b[2] * self.bdims[1] + b[1]) * self.bdims[0] + b[0]] >= self.iso {
            return None;
        }
        let size = self.cell * BLOCK as f32;
        let blo = self.origin + Vec3::new(b[0] as f32, b[1] as f32, b[2] as f32) * size;
        let bhi = blo + Vec3::splat(size);
        let mut t_exit = f32::INFINITY;
        for a in 0..3 {
            if d[a].abs() > 1e-12 {
                let t = if d[a] > 0.0 {
                    (bhi[a] - o[a]) / d[a]
                } else {
                    (blo[a] - o[a]) / d[a]
                };
                t_exit = t_exit.min(t);
            }
        }
        Some(t_exit)
    }
}

fn block_span(i: usize, nblocks: usize) -> impl Iterator<Item = usize> {
    let b = i / BLOCK;
    let first = if i.is_multiple_of(BLOCK) && b > 0 {
        b - 1
    } else {
        b
    };
    (first..=b).filter(move |&x| x < nblocks)
}

impl DensityField {
    /// Grid spacing.
    pub fn cell_size(&self) -> f32 {
        self.cell
    }
}
