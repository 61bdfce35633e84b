//! Cameras all round the fluid above its floor, and the warm-up renderer's images from them:
//! what `joint.replay_of = "renders"` holds the grounded renderer to. A rig's cameras look
//! from a few directions (the bed's warm-up views from one ring); grounding on one view moves
//! the colour the renderer draws from the others, the farthest from the ring the most. These
//! views ask it to keep drawing, from every direction, what the warm-up left it drawing.

use neurofluid_core::camera::{Camera, orbit_cameras};
use neurofluid_core::scene::Image;
use neurofluid_physnerf::{PhysNerf, render_image};

use super::views::{ViewFrame, points_tensor};
use super::warmup::WarmupData;

/// Cameras of the orbit.
pub const ORBIT_CAMERAS: usize = 16;

/// The orbit's images are at most this many pixels wide (a distillation needs no more).
pub const ORBIT_MAX_WIDTH: u32 = 128;

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
    orbit_cameras(
        like,
        centre,
        distance,
        up_axis,
        ORBIT_CAMERAS,
        ORBIT_MAX_WIDTH,
    )
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
