//! Cameras all round the fluid above its floor, and the warm-up renderer's images from them:
//! what `joint.replay_of = "renders"` holds the grounded renderer to. A rig's cameras look
//! from a few directions (the bed's warm-up views from one ring); grounding on one view moves
//! the colour the renderer draws from the others, the farthest from the ring the most. These
//! views ask it to keep drawing, from every direction, what the warm-up left it drawing.

use neurofluid_core::camera::Camera;
use neurofluid_core::scene::Image;
use neurofluid_physnerf::{PhysNerf, render_image};

use super::views::{ViewFrame, points_tensor};
use super::warmup::WarmupData;

/// Cameras of the orbit.
pub const ORBIT_CAMERAS: usize = 16;

/// The orbit's images are at most this many pixels wide (a distillation needs no more).
pub const ORBIT_MAX_WIDTH: u32 = 128;

/// `n` cameras at `distance` from `centre`, spread evenly over the half sphere above it (a
/// Fibonacci lattice, none on the up axis itself), each looking at `centre` with the
/// intrinsics of `like` (scaled to at most [`ORBIT_MAX_WIDTH`] pixels wide).
pub fn orbit_cameras(
    like: &Camera,
    centre: [f32; 3],
    distance: f32,
    up_axis: usize,
    n: usize,
) -> Vec<Camera> {
    let k = (ORBIT_MAX_WIDTH as f32 / like.width as f32).min(1.0);
    let scaled = like.resized(
        ((like.width as f32 * k).round() as u32).max(1),
        ((like.height as f32 * k).round() as u32).max(1),
    );
    let mut up = [0.0f32; 3];
    up[up_axis] = 1.0;
    let (a, b) = ((up_axis + 1) % 3, (up_axis + 2) % 3);
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..n)
        .map(|i| {
            // equal areas of the half sphere: the height above the centre uniform in (0, 1)
            let h = (i as f32 + 0.5) / n as f32;
            let r = (1.0 - h * h).sqrt();
            let phi = golden * i as f32;
            let mut eye = centre;
            eye[a] += distance * r * phi.cos();
            eye[b] += distance * r * phi.sin();
            eye[up_axis] += distance * h;
            let pose = Camera::look_at(scaled.width, scaled.height, 1.0, eye, centre, up);
            Camera {
                c2w: pose.c2w,
                ..scaled
            }
        })
        .collect()
}

/// What the replay of `joint.replay_of = "renders"` and `refit.replay_rays` holds a renderer
/// to: the warm-up frame of `warmup` (its particles) seen by [`orbit_renders`] with `teacher`'s
/// renders as the images, in place of the warm-up's own views (`up_axis`: the scene's).
pub fn orbit_replay(
    teacher: &PhysNerf,
    warmup: &WarmupData,
    up_axis: usize,
) -> anyhow::Result<WarmupData> {
    let cameras: Vec<Camera> = warmup.views.iter().map(|v| v.camera).collect();
    Ok(WarmupData {
        views: orbit_renders(teacher, &cameras, &warmup.particles, up_axis)?,
        particles: warmup.particles.clone(),
        held_out: None,
    })
}

/// The orbit of the warm-up frame: [`ORBIT_CAMERAS`] cameras round the particles' centroid at
/// the mean distance of the rig's `cameras` from it, with the first camera's intrinsics, each
/// with `physnerf`'s render of `particles` as its image.
fn orbit_renders(
    physnerf: &PhysNerf,
    cameras: &[Camera],
    particles: &[[f32; 3]],
    up_axis: usize,
) -> anyhow::Result<Vec<ViewFrame>> {
    let like = cameras
        .first()
        .ok_or_else(|| anyhow::anyhow!("no camera to take the orbit's intrinsics from"))?;
    anyhow::ensure!(
        !particles.is_empty(),
        "no particles to place the orbit round"
    );
    let n = particles.len() as f32;
    let centre: [f32; 3] = std::array::from_fn(|k| particles.iter().map(|p| p[k]).sum::<f32>() / n);
    let distance = cameras
        .iter()
        .map(|c| {
            let o = c.origin();
            (0..3)
                .map(|k| (o[k] - centre[k]).powi(2))
                .sum::<f32>()
                .sqrt()
        })
        .sum::<f32>()
        / cameras.len() as f32;
    let device = physnerf.device();
    let points = points_tensor(particles, &device);
    orbit_cameras(like, centre, distance, up_axis, ORBIT_CAMERAS)
        .into_iter()
        .map(|camera| {
            let image = render_image(
                physnerf,
                &camera,
                &points,
                physnerf.config.chunk,
                &mut |_, _| {},
            )?;
            let pixels = (camera.width * camera.height) as usize;
            Ok(ViewFrame {
                camera,
                image: Image {
                    width: camera.width,
                    height: camera.height,
                    rgb: image.best().to_vec(),
                    alpha: vec![1.0; pixels],
                },
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every camera sits at the distance asked, above the centre, looks at it through its
    /// principal point, keeps the intrinsics' field of view, and no two look from one place.
    #[test]
    fn the_orbit_surrounds_the_centre_from_above() {
        let like = Camera::look_at(400, 300, 0.6, [0.0, -4.0, 2.0], [0.0; 3], [0.0, 0.0, 1.0]);
        let centre = [0.2, -0.1, 0.3];
        let cams = orbit_cameras(&like, centre, 3.0, 2, ORBIT_CAMERAS);
        assert_eq!(cams.len(), ORBIT_CAMERAS);
        let mut azimuths = Vec::new();
        for c in &cams {
            assert_eq!((c.width, c.height), (128, 96));
            assert!((c.fx / c.width as f32 - like.fx / like.width as f32).abs() < 1e-5);
            let o = c.origin();
            let rel: [f32; 3] = std::array::from_fn(|k| o[k] - centre[k]);
            let dist = rel.iter().map(|x| x * x).sum::<f32>().sqrt();
            assert!((dist - 3.0).abs() < 1e-4, "{dist}");
            assert!(rel[2] > 0.0 && rel[2] < 3.0, "{rel:?}");
            // the principal ray (camera −z) points from the eye at the centre
            let ahead = [-c.c2w[0][2], -c.c2w[1][2], -c.c2w[2][2]];
            for k in 0..3 {
                assert!((ahead[k] + rel[k] / dist).abs() < 1e-4);
            }
            azimuths.push(rel[1].atan2(rel[0]));
        }
        // heights spread from near the floor to near the top, azimuths all round
        let heights: Vec<f32> = cams.iter().map(|c| c.origin()[2] - centre[2]).collect();
        assert!(heights.iter().cloned().fold(f32::MAX, f32::min) < 0.2);
        assert!(heights.iter().cloned().fold(f32::MIN, f32::max) > 2.8);
        for q in 0..4 {
            let lo = -std::f32::consts::PI + q as f32 * std::f32::consts::FRAC_PI_2;
            let hi = lo + std::f32::consts::FRAC_PI_2;
            assert!(azimuths.iter().filter(|a| (lo..hi).contains(*a)).count() >= 3);
        }
    }
}
