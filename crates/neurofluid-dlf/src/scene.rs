//! Small synthetic DLF scenes (a fluid block in a closed box of wall particles), the same
//! construction as the reference harness's `make-case`/`bench` scenes, for tests and benchmarks.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Particle radius of the DLF data (m).
pub const PARTICLE_RADIUS: f32 = 0.025;

/// Wall spacing with DLF's wall density (1.9 points per π r², about 968/m²).
pub fn dlf_wall_spacing() -> f64 {
    (std::f64::consts::PI * (PARTICLE_RADIUS as f64).powi(2) / 1.9).sqrt()
}

/// A scene: fluid particles and static wall particles with inward normals.
#[derive(Debug, Clone, PartialEq)]
pub struct BoxScene {
    /// Fluid positions.
    pub pos: Vec<[f32; 3]>,
    /// Fluid velocities.
    pub vel: Vec<[f32; 3]>,
    /// Wall particles.
    pub box_points: Vec<[f32; 3]>,
    /// Unit wall normals pointing into the box.
    pub box_normals: Vec<[f32; 3]>,
    /// Box lower corner.
    pub box_lo: [f32; 3],
    /// Box upper corner.
    pub box_hi: [f32; 3],
}

/// Wall particles of the closed box [lo, hi], each face sampled at the cell centres of a grid of
/// about `spacing`, normals pointing into the box.
pub fn box_walls(lo: [f64; 3], hi: [f64; 3], spacing: f64) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let mut pts = Vec::new();
    let mut nrm = Vec::new();
    for axis in 0..3 {
        let (u, v) = match axis {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        };
        let nu = (((hi[u] - lo[u]) / spacing).round() as usize).max(1);
        let nv = (((hi[v] - lo[v]) / spacing).round() as usize).max(1);
        for (side, sign) in [(lo[axis], 1.0f32), (hi[axis], -1.0)] {
            for i in 0..nu {
                for j in 0..nv {
                    let mut p = [0f64; 3];
                    p[axis] = side;
                    p[u] = lo[u] + (i as f64 + 0.5) * (hi[u] - lo[u]) / nu as f64;
                    p[v] = lo[v] + (j as f64 + 0.5) * (hi[v] - lo[v]) / nv as f64;
                    let mut n = [0f32; 3];
                    n[axis] = sign;
                    pts.push(p.map(|c| c as f32));
                    nrm.push(n);
                }
            }
        }
    }
    (pts, nrm)
}

/// A block of `n` fluid particles (cubic lattice of spacing 2r, x fastest, seeded jitter) in a
/// closed box [−h, h] × [0, H] × [−h, h], its lowest layer `drop_height` above the floor and
/// centred in x/z, all moving with `velocity`.
pub fn block_in_box(
    n: usize,
    wall_spacing: f64,
    velocity: [f32; 3],
    jitter: f64,
    seed: u64,
    drop_height: f64,
) -> BoxScene {
    let r = PARTICLE_RADIUS as f64;
    let s = ((n as f64).powf(1.0 / 3.0) - 1e-9).ceil() as usize;
    let side = s as f64 * 2.0 * r;
    let half = (0.8 * side).max(0.5);
    let lo = [-half, 0.0, -half];
    let hi = [half, side + drop_height + 0.4, half];
    let origin = [-side / 2.0, lo[1] + drop_height, -side / 2.0];
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let pos: Vec<[f32; 3]> = (0..n)
        .map(|idx| {
            let ijk = [idx % s, (idx / s) % s, idx / (s * s)];
            std::array::from_fn(|k| {
                let j = if jitter > 0.0 {
                    rng.random_range(-jitter..jitter)
                } else {
                    0.0
                };
                (origin[k] + (ijk[k] as f64 + 0.5) * 2.0 * r + j) as f32
            })
        })
        .collect();
    let (box_points, box_normals) = box_walls(lo, hi, wall_spacing);
    BoxScene {
        vel: vec![velocity; n],
        pos,
        box_points,
        box_normals,
        box_lo: lo.map(|c| c as f32),
        box_hi: hi.map(|c| c as f32),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn walls_have_dlf_density_and_inward_normals() {
        let (p, n) = box_walls([-0.5, 0.0, -0.5], [0.5, 1.0, 0.5], dlf_wall_spacing());
        let area = 6.0;
        let density = p.len() as f64 / area;
        assert!((density - 968.0).abs() < 60.0, "{density}");
        for (q, m) in p.iter().zip(&n) {
            // moving along the normal goes towards the box centre (0, 0.5, 0)
            let c = [0.0, 0.5, 0.0];
            let before: f32 = (0..3).map(|k| (q[k] - c[k]).powi(2)).sum();
            let after: f32 = (0..3).map(|k| (q[k] + 0.01 * m[k] - c[k]).powi(2)).sum();
            assert!(after < before);
        }
    }

    #[test]
    fn block_has_requested_size_and_sits_above_floor() {
        let s = block_in_box(1000, dlf_wall_spacing(), [0.3, 0.0, 0.2], 0.002, 1, 0.05);
        assert_eq!(s.pos.len(), 1000);
        let min_y = s.pos.iter().map(|p| p[1]).fold(f32::INFINITY, f32::min);
        assert!((min_y - 0.075).abs() < 0.003, "{min_y}");
        assert!(
            s.pos
                .iter()
                .all(|p| (0..3).all(|k| p[k] > s.box_lo[k] && p[k] < s.box_hi[k]))
        );
    }
}
