//! Box wall particles at DLF's wall density (~968 points/m², spec dlf.md §6.3): the surface
//! points of a lattice whose spacing is as close as possible to [`WALL_SPACING`] on each axis,
//! so every point is unique (shared edges and corners appear once), with unit normals pointing
//! into the box (the normalised sum of the inward normals of the faces a point lies on).

use neurofluid_core::scene::BoxParticles;

/// Target wall spacing: 1/√968 m ≈ 0.03214 m, DLF's Poisson-disk density.
pub const WALL_SPACING: f64 = 0.032_14;

/// Samples the surface of the box `[lo, hi]` at about `spacing` with inward unit normals.
pub fn box_walls(lo: [f64; 3], hi: [f64; 3], spacing: f64) -> BoxParticles {
    let n: [usize; 3] =
        std::array::from_fn(|a| (((hi[a] - lo[a]) / spacing).round() as usize).max(1) + 1);
    let step: [f64; 3] = std::array::from_fn(|a| (hi[a] - lo[a]) / (n[a] - 1) as f64);
    let mut points = Vec::new();
    let mut normals = Vec::new();
    for k in 0..n[2] {
        for j in 0..n[1] {
            for i in 0..n[0] {
                let idx = [i, j, k];
                let mut normal = [0.0f64; 3];
                let mut on_surface = false;
                for a in 0..3 {
                    if idx[a] == 0 {
                        normal[a] += 1.0;
                        on_surface = true;
                    } else if idx[a] == n[a] - 1 {
                        normal[a] -= 1.0;
                        on_surface = true;
                    }
                }
                if !on_surface {
                    continue;
                }
                let len = normal.iter().map(|v| v * v).sum::<f64>().sqrt();
                let p: [f32; 3] = std::array::from_fn(|a| {
                    if idx[a] == n[a] - 1 {
                        hi[a] as f32
                    } else {
                        (lo[a] + idx[a] as f64 * step[a]) as f32
                    }
                });
                points.push(p);
                normals.push(std::array::from_fn(|a| (normal[a] / len) as f32));
            }
        }
    }
    BoxParticles { points, normals }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    #[test]
    fn density_uniqueness_and_inward_normals() {
        let (lo, hi) = ([-1.0, -1.0, -1.0], [1.0, 2.455, 1.0]);
        let b = box_walls(lo, hi, WALL_SPACING);
        let area = 2.0 * (2.0 * 2.0 + 2.0 * 3.455 + 2.0 * 3.455);
        let density = b.len() as f64 / area;
        assert!((density - 968.0).abs() < 30.0, "{density} points/m²");
        // the released watercube box (same size, z-up) has 34,489 points
        assert!(
            (b.len() as f64 - 34_489.0).abs() / 34_489.0 < 0.02,
            "{}",
            b.len()
        );
        let unique: HashSet<[u32; 3]> = b.points.iter().map(|p| p.map(f32::to_bits)).collect();
        assert_eq!(unique.len(), b.len(), "duplicate wall points");
        let centre = [0.0f32, 0.7275, 0.0];
        for (p, nrm) in b.points.iter().zip(&b.normals) {
            let len = nrm.iter().map(|v| v * v).sum::<f32>().sqrt();
            assert!((len - 1.0).abs() < 1e-6);
            // on the surface
            let on = (0..3).any(|a| p[a] == lo[a] as f32 || p[a] == hi[a] as f32);
            assert!(on, "{p:?} not on the box surface");
            // points inwards: towards the centre
            let to_c: f32 = (0..3).map(|a| (centre[a] - p[a]) * nrm[a]).sum();
            assert!(to_c > 0.0, "{p:?} normal {nrm:?} points outwards");
        }
    }
}
