//! Host-side geometry of one neighbour pair: Open3D's volume-preserving ball→cube mapping with
//! `align_corners`, the clamped trilinear corners and the poly6 window (docs/spec/dlf.md §2.3–2.5).
//!
//! Everything is float32 and follows the order of operations of the reference, so that the
//! corner weights agree with Open3D's to a few ulp.

/// Kernel cells along one axis.
pub const KERNEL_SIZE: usize = 4;
/// Kernel cells in all (4³); the flat cell index is `(iz·4 + iy)·4 + ix`.
pub const KERNEL_CELLS: usize = KERNEL_SIZE * KERNEL_SIZE * KERNEL_SIZE;

/// The branch taken by each stage of the mapping, for one pair (needed by the differentiable path).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MappingBranches {
    /// |p|² < 1e-12: the point maps to the centre.
    pub zero: bool,
    /// (5/4)·z² > x² + y²: the polar-cap branch of sphere→cylinder.
    pub cap: bool,
    /// x² + y² < 1e-12 after sphere→cylinder: x and y map to 0.
    pub zero_xy: bool,
    /// |y| ≤ |x| after sphere→cylinder: the x-dominant branch of cylinder→cube.
    pub x_dominant: bool,
    /// copysign(1, x) after sphere→cylinder.
    pub sign_x: f32,
    /// copysign(1, y) after sphere→cylinder.
    pub sign_y: f32,
}

/// Maps a point of the unit ball to the cube [−1, 1]³ (sphere→cylinder, then cylinder→cube).
pub fn ball_to_cube_volume_preserving(p: [f32; 3]) -> ([f32; 3], MappingBranches) {
    let [x, y, z] = p;
    let mut br = MappingBranches::default();
    let sq = x * x + y * y + z * z;
    let norm = sq.sqrt();
    let (x1, y1, z1) = if sq < 1e-12 {
        br.zero = true;
        (0.0, 0.0, 0.0)
    } else if 1.25 * z * z > x * x + y * y {
        br.cap = true;
        let s = (3.0 * norm / (norm + z.abs())).sqrt();
        (x * s, y * s, norm.copysign(z))
    } else {
        let s = norm / (x * x + y * y).sqrt();
        (x * s, y * s, 1.5 * z)
    };
    let sqxy = x1 * x1 + y1 * y1;
    let nxy = sqxy.sqrt();
    br.sign_x = 1.0f32.copysign(x1);
    br.sign_y = 1.0f32.copysign(y1);
    br.x_dominant = y1.abs() <= x1.abs();
    const FOUR_OVER_PI: f32 = 4.0 / std::f32::consts::PI;
    let (x2, y2) = if sqxy < 1e-12 {
        br.zero_xy = true;
        (0.0, 0.0)
    } else if br.x_dominant {
        let t = nxy.copysign(x1);
        (t, t * FOUR_OVER_PI * (y1 / x1).atan())
    } else {
        let t = nxy.copysign(y1);
        (t * FOUR_OVER_PI * (x1 / y1).atan(), t)
    };
    ([x2, y2, z1], br)
}

/// Relative position (neighbour − query) → continuous filter coordinates in [0, 3]³ (x, y, z).
///
/// `inv_radius2` is `2 / extent` computed in float32 (the scale into the unit ball).
pub fn filter_coordinates(rel: [f32; 3], two_over_extent: f32) -> ([f32; 3], MappingBranches) {
    let p = rel.map(|c| c * two_over_extent);
    let (q, br) = ball_to_cube_volume_preserving(p);
    let k1 = (KERNEL_SIZE - 1) as f32;
    (q.map(|c| (0.5 * c + 0.5) * k1), br)
}

/// Clamped trilinear interpolation along one axis: (i0, i1, fraction).
#[inline]
pub fn axis_interp(u: f32) -> (usize, usize, f32) {
    let max = (KERNEL_SIZE - 1) as i64;
    let i0 = (u.trunc() as i64).clamp(0, max);
    let i1 = (i0 + 1).clamp(0, max);
    let a = (u - i0 as f32).clamp(0.0, 1.0);
    (i0 as usize, i1 as usize, a)
}

/// The 8 trilinear corners of filter coordinates `u` = (x, y, z): (flat cell, weight), z outer,
/// x inner, weights `wx·wy·wz`.
pub fn trilinear_corners(u: [f32; 3]) -> [(u8, f32); 8] {
    let (x0, x1, a) = axis_interp(u[0]);
    let (y0, y1, b) = axis_interp(u[1]);
    let (z0, z1, c) = axis_interp(u[2]);
    let mut out = [(0u8, 0.0f32); 8];
    let mut k = 0;
    for (zi, wz) in [(z0, 1.0 - c), (z1, c)] {
        for (yi, wy) in [(y0, 1.0 - b), (y1, b)] {
            for (xi, wx) in [(x0, 1.0 - a), (x1, a)] {
                let cell = (zi * KERNEL_SIZE + yi) * KERNEL_SIZE + xi;
                out[k] = (cell as u8, wx * wy * wz);
                k += 1;
            }
        }
    }
    out
}

/// DLF's poly6-like window on the normalised squared distance: clamp((1 − r²)³, 0, 1).
#[inline]
pub fn window_poly6(r2: f32) -> f32 {
    let t = 1.0 - r2;
    (t * t * t).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_maps_to_middle_of_filter() {
        let (u, br) = filter_coordinates([0.0; 3], 2.0 / 0.225);
        assert!(br.zero);
        assert_eq!(u, [1.5, 1.5, 1.5]);
    }

    #[test]
    fn axis_points_map_to_faces() {
        // A point on the sphere along +x maps to the +x face centre of the cube.
        let (q, _) = ball_to_cube_volume_preserving([1.0, 0.0, 0.0]);
        assert!((q[0] - 1.0).abs() < 1e-6 && q[1].abs() < 1e-6 && q[2].abs() < 1e-6);
        let (q, br) = ball_to_cube_volume_preserving([0.0, 0.0, -1.0]);
        assert!(br.cap);
        assert!((q[2] + 1.0).abs() < 1e-6 && q[0].abs() < 1e-6);
        let (q, _) = ball_to_cube_volume_preserving([0.0, 1.0, 0.0]);
        assert!((q[1] - 1.0).abs() < 1e-6 && q[0].abs() < 1e-6);
    }

    #[test]
    fn mapping_stays_in_cube_and_preserves_volume() {
        // Monte-Carlo: uniform points in the ball map to (roughly) uniform points in the cube, so
        // each octant-of-octant cell receives the same share.
        let mut counts = [0usize; 8];
        let mut n = 0usize;
        let mut state = 12345u64;
        let mut rnd = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        };
        while n < 200_000 {
            let p = [rnd(), rnd(), rnd()];
            if p[0] * p[0] + p[1] * p[1] + p[2] * p[2] > 1.0 {
                continue;
            }
            n += 1;
            let (q, _) = ball_to_cube_volume_preserving(p);
            assert!(q.iter().all(|c| c.abs() <= 1.0 + 1e-5), "{p:?} -> {q:?}");
            // sub-cell of the positive octant at half resolution
            if q.iter().all(|&c| c > 0.0) {
                let i =
                    (q[0] > 0.5) as usize + 2 * (q[1] > 0.5) as usize + 4 * (q[2] > 0.5) as usize;
                counts[i] += 1;
            }
        }
        let total: usize = counts.iter().sum();
        for c in counts {
            let share = c as f64 / total as f64;
            assert!((share - 0.125).abs() < 0.01, "{counts:?}");
        }
    }

    #[test]
    fn trilinear_weights_sum_to_one_and_clamp() {
        for u in [
            [0.0, 0.0, 0.0],
            [1.3, 2.7, 0.2],
            [3.0, 3.0, 3.0],
            [2.999, 0.001, 1.5],
        ] {
            let c = trilinear_corners(u);
            let s: f32 = c.iter().map(|x| x.1).sum();
            assert!((s - 1.0).abs() < 1e-6);
            assert!(c.iter().all(|x| (x.0 as usize) < KERNEL_CELLS));
        }
        // At u = 3 both corners fall on cell 3 and carry the full weight.
        let c = trilinear_corners([3.0, 0.0, 0.0]);
        let w3: f32 = c.iter().filter(|x| x.0 == 3).map(|x| x.1).sum();
        assert!((w3 - 1.0).abs() < 1e-6);
    }

    #[test]
    fn window_is_one_at_centre_and_zero_at_boundary() {
        assert_eq!(window_poly6(0.0), 1.0);
        assert_eq!(window_poly6(1.0), 0.0);
        assert_eq!(window_poly6(1.5), 0.0);
        assert!((window_poly6(0.5) - 0.125).abs() < 1e-7);
    }
}
