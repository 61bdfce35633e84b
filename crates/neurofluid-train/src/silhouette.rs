//! A silhouette term for joint training (`joint.silhouette_weight`): a two-sided distance, in
//! the image plane, between the predicted particles' projections and the pixels where the
//! target image shows fluid.
//!
//! The image loss cannot pull particles into places where the truth has fluid and the prediction
//! has none: no particle near a sample means zero density there and no gradient. This term can:
//! every fluid pixel farther than a particle's projected radius from all projected particles
//! pulls the nearest one towards it, and every particle projected more than a pixel outside the
//! fluid is pulled to the nearest fluid pixel. Distances are in image widths, so the weight does
//! not depend on the resolution:
//!
//! L = (1/N) Σ_i max(0, d(u_i, F) − 1 px)² + (1/|F|) Σ_{p∈F} max(0, d(p, U) − r)²
//!
//! with u_i the projections, F the fluid pixels and r the projected particle radius. Without
//! `cover` only the first sum (the spray side) is taken.

use neurofluid_core::camera::Camera;

/// The silhouette term of one view and its gradient.
#[derive(Debug, Clone, PartialEq)]
pub struct Silhouette {
    /// L (see the module's documentation).
    pub loss: f64,
    /// ∂L/∂x per point (zero for points behind the camera).
    pub grad: Vec<[f32; 3]>,
}

/// A particle projected within this many pixels of a fluid pixel is inside the silhouette.
const INSIDE_PX: f64 = 1.0;

/// The silhouette term of `points` seen by `camera` against the fluid pixels `foreground`
/// (row-major, the camera's size); `radius_px` is the projected particle radius in pixels; with
/// `cover` the fluid pixels no particle covers pull the nearest one too.
pub fn silhouette_loss(
    camera: &Camera,
    foreground: &[bool],
    points: &[[f32; 3]],
    radius_px: f32,
    cover: bool,
) -> Silhouette {
    let w = camera.width as usize;
    let fluid: Vec<[f64; 2]> = foreground
        .iter()
        .enumerate()
        .filter(|&(_, &f)| f)
        .map(|(p, _)| [(p % w) as f64, (p / w) as f64])
        .collect();
    // projections (pixels) and their Jacobians, for the points in front of the camera
    let projected: Vec<(usize, [f64; 2], [[f32; 3]; 2])> = points
        .iter()
        .enumerate()
        .filter_map(|(i, &p)| {
            let (col, row, _) = camera.project(p)?;
            let jac = camera.project_jacobian(p)?;
            Some((i, [col as f64, row as f64], jac))
        })
        .collect();
    let mut grad = vec![[0.0f32; 3]; points.len()];
    if fluid.is_empty() || projected.is_empty() {
        return Silhouette { loss: 0.0, grad };
    }
    // ∂L/∂u per projected point, in pixels
    let mut d_u = vec![[0.0f64; 2]; projected.len()];
    let mut outside = 0.0;
    let n = projected.len() as f64;
    for (k, (_, u, _)) in projected.iter().enumerate() {
        let (col, row) = (u[0].round(), u[1].round());
        let on_fluid = col >= 0.0
            && row >= 0.0
            && (col as usize) < w
            && (row as usize) < foreground.len() / w
            && foreground[row as usize * w + col as usize];
        if on_fluid {
            continue; // within √½ px of a fluid pixel
        }
        let (k_f, dist) = nearest_index(u, fluid.iter().copied());
        let f = fluid[k_f];
        let excess = dist - INSIDE_PX;
        if excess > 0.0 {
            outside += excess * excess / n;
            let s = 2.0 * excess / (dist * n);
            d_u[k][0] += s * (u[0] - f[0]);
            d_u[k][1] += s * (u[1] - f[1]);
        }
    }
    let mut uncovered = 0.0;
    let m = fluid.len() as f64;
    let r = radius_px as f64;
    for p in fluid.iter().filter(|_| cover) {
        let (k, dist) = nearest_index(p, projected.iter().map(|(_, u, _)| *u));
        let excess = dist - r;
        if excess > 0.0 {
            uncovered += excess * excess / m;
            let u = projected[k].1;
            let s = 2.0 * excess / (dist * m);
            d_u[k][0] += s * (u[0] - p[0]);
            d_u[k][1] += s * (u[1] - p[1]);
        }
    }
    // pixels → image widths, then through the projection
    let scale = 1.0 / (w as f64 * w as f64);
    for ((i, _, jac), du) in projected.iter().zip(&d_u) {
        for a in 0..3 {
            grad[*i][a] = (scale * (du[0] * jac[0][a] as f64 + du[1] * jac[1][a] as f64)) as f32;
        }
    }
    Silhouette {
        loss: scale * (outside + uncovered),
        grad,
    }
}

/// The index of the point of `candidates` nearest to `q` and its distance.
fn nearest_index(q: &[f64; 2], candidates: impl Iterator<Item = [f64; 2]>) -> (usize, f64) {
    let mut best = (0, f64::INFINITY);
    for (k, c) in candidates.enumerate() {
        let d2 = (c[0] - q[0]).powi(2) + (c[1] - q[1]).powi(2);
        if d2 < best.1 {
            best = (k, d2);
        }
    }
    (best.0, best.1.sqrt())
}

/// The projected radius, in pixels, of a particle of `radius` at the depth of `centre`
/// (a scene's box centre: one radius for the whole step); `None` when `centre` is behind the
/// camera.
pub fn projected_radius(camera: &Camera, centre: [f32; 3], radius: f32) -> Option<f32> {
    let (_, _, depth) = camera.project(centre)?;
    Some(camera.fx.max(camera.fy) * radius / depth)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampler::Rng;

    /// At (0, 0, 4) looking down −z, 64 × 48 pixels.
    fn camera() -> Camera {
        let c2w = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 4.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        Camera::from_angle_x(64, 48, 0.7, c2w)
    }

    /// Fluid pixels: a disc of 8 px around (40, 20).
    fn disc_mask(cam: &Camera) -> Vec<bool> {
        let (w, h) = (cam.width as usize, cam.height as usize);
        (0..w * h)
            .map(|p| ((p % w) as f32 - 40.0).powi(2) + ((p / w) as f32 - 20.0).powi(2) <= 64.0)
            .collect()
    }

    fn cloud(rng: &mut Rng, centre: [f32; 3], spread: f32, n: usize) -> Vec<[f32; 3]> {
        (0..n)
            .map(|_| std::array::from_fn(|a| centre[a] + spread * (rng.next_f32() - 0.5)))
            .collect()
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let cam = camera();
        let mask = disc_mask(&cam);
        let mut rng = Rng::new(3);
        // partly inside the fluid's disc, partly outside, a few too many to cover it
        let pts = cloud(&mut rng, [0.05, 0.0, 0.0], 0.5, 12);
        let s = silhouette_loss(&cam, &mask, &pts, 1.5, true);
        assert!(s.loss > 0.0);
        // small enough that few pixels change their nearest particle (the loss is C¹ elsewhere)
        let h = 1e-4f32;
        for i in 0..pts.len() {
            for a in 0..3 {
                let (mut p, mut q) = (pts.clone(), pts.clone());
                p[i][a] += h;
                q[i][a] -= h;
                let fd = (silhouette_loss(&cam, &mask, &p, 1.5, true).loss
                    - silhouette_loss(&cam, &mask, &q, 1.5, true).loss)
                    / (2.0 * h as f64);
                let g = s.grad[i][a] as f64;
                assert!(
                    (g - fd).abs() <= 2e-2 * fd.abs().max(1e-4),
                    "particle {i} axis {a}: {g} vs {fd}"
                );
            }
        }
    }

    #[test]
    fn particles_covering_the_fluid_cost_nothing() {
        let cam = camera();
        let mask = disc_mask(&cam);
        let w = cam.width as usize;
        // one particle on every fluid pixel's ray, at depth 4
        let pts: Vec<[f32; 3]> = (0..mask.len())
            .filter(|&p| mask[p])
            .map(|p| {
                let d = cam.ray_dir((p / w) as u32, (p % w) as u32);
                let t = 4.0 / -d[2];
                [d[0] * t, d[1] * t, 4.0 + d[2] * t]
            })
            .collect();
        let s = silhouette_loss(&cam, &mask, &pts, 0.5, true);
        assert!(s.loss < 1e-12, "{}", s.loss);
        assert!(s.grad.iter().flatten().all(|g| g.abs() < 1e-9));
        // no fluid, or nothing in front of the camera: nothing to pull
        let none = silhouette_loss(&cam, &vec![false; mask.len()], &pts, 0.5, true);
        assert_eq!(none.loss, 0.0);
        let behind = silhouette_loss(&cam, &mask, &[[0.0, 0.0, 9.0]], 0.5, true);
        assert_eq!((behind.loss, behind.grad), (0.0, vec![[0.0; 3]]));
    }

    /// Without `cover` only the particles outside the fluid cost anything: particles on part of
    /// the disc leave the rest uncovered for free, one particle beside it costs what it costs
    /// with a gradient that moves it towards the disc.
    #[test]
    fn the_spray_side_alone_ignores_uncovered_fluid() {
        let cam = camera();
        let mask = disc_mask(&cam);
        let w = cam.width as usize;
        let on_pixel = |p: usize| {
            let d = cam.ray_dir((p / w) as u32, (p % w) as u32);
            let t = 4.0 / -d[2];
            [d[0] * t, d[1] * t, 4.0 + d[2] * t]
        };
        // the disc's centre pixel only: most of the fluid uncovered
        let centre = on_pixel(20 * w + 40);
        let both = silhouette_loss(&cam, &mask, &[centre], 0.5, true);
        let spray = silhouette_loss(&cam, &mask, &[centre], 0.5, false);
        assert!(both.loss > 0.0);
        assert_eq!((spray.loss, spray.grad.clone()), (0.0, vec![[0.0; 3]]));
        // a particle far from the disc: pulled towards it, by the same amount as the first sum
        let lone = on_pixel(5 * w + 5);
        let spray = silhouette_loss(&cam, &mask, &[centre, lone], 0.5, false);
        assert!(spray.loss > 0.0);
        assert_eq!(spray.grad[0], [0.0; 3]);
        let (col, row, _) = cam.project(lone).unwrap();
        let step: [f32; 3] = std::array::from_fn(|a| lone[a] - 1e-2 * spray.grad[1][a]);
        let (col2, row2, _) = cam.project(step).unwrap();
        let dist = |c: f32, r: f32| ((c - 40.0).powi(2) + (r - 20.0).powi(2)).sqrt();
        assert!(
            dist(col2, row2) < dist(col, row),
            "descent moves it towards the disc"
        );
    }

    /// Gradient descent on the term alone moves a cloud beside the fluid onto it.
    #[test]
    fn descent_moves_a_cloud_onto_the_silhouette() {
        let cam = camera();
        let mask = disc_mask(&cam);
        let mut rng = Rng::new(5);
        let mut pts = cloud(&mut rng, [-0.3, 0.2, 0.0], 0.1, 30);
        let first = silhouette_loss(&cam, &mask, &pts, 1.5, true).loss;
        for _ in 0..300 {
            let s = silhouette_loss(&cam, &mask, &pts, 1.5, true);
            for (p, g) in pts.iter_mut().zip(&s.grad) {
                for a in 0..3 {
                    p[a] -= 2.0 * g[a];
                }
            }
        }
        let last = silhouette_loss(&cam, &mask, &pts, 1.5, true).loss;
        assert!(last < 0.02 * first, "{first} → {last}");
        // the cloud's projections sit on the disc
        let w = cam.width as usize;
        for p in &pts {
            let (col, row, _) = cam.project(*p).unwrap();
            let px = row.round() as usize * w + col.round() as usize;
            let d = ((col - 40.0).powi(2) + (row - 20.0).powi(2)).sqrt();
            assert!(mask[px] || d < 9.5, "({col}, {row})");
        }
    }

    #[test]
    fn projected_radius_shrinks_with_depth() {
        let cam = camera();
        let near = projected_radius(&cam, [0.0, 0.0, 2.0], 0.025).unwrap();
        let far = projected_radius(&cam, [0.0, 0.0, 0.0], 0.025).unwrap();
        assert!((near - 2.0 * far).abs() < 1e-4 * near, "{near} {far}");
        assert!(projected_radius(&cam, [0.0, 0.0, 5.0], 0.025).is_none());
    }
}
