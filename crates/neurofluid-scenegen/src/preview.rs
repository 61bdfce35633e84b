//! A contact sheet of a scene on white: the warm-up views at their first frame on top, the
//! first test view at six evenly spaced frames below.

use std::path::Path;

use neurofluid_core::scene::{Image, Role, Scene, SceneError, write_png_rgba};

/// Writes the contact sheet of the scene at `scene_dir` to `out` (PNG).
pub fn contact_sheet(scene_dir: &Path, out: &Path) -> Result<(), SceneError> {
    let scene = Scene::open(scene_dir)?;
    let mut top = Vec::new();
    let t0 = scene.frames(Role::Warmup).start;
    for v in scene.views(Role::Warmup) {
        top.push(scene.image(Role::Warmup, v, t0)?);
    }
    let test_view = &scene.views(Role::Test)[0];
    let r = scene.frames(Role::Test);
    let last = r.end - 1;
    let mut bottom = Vec::new();
    for k in 0..6 {
        let t = r.start + (last - r.start) * k / 5;
        bottom.push(scene.image(Role::Test, test_view, t)?);
    }
    let (w, h) = (bottom[0].width as usize, bottom[0].height as usize);
    let cols = top.len().max(bottom.len());
    let (cw, ch) = (cols * w, 2 * h);
    let mut canvas = vec![255u8; cw * ch * 4];
    for (row, images) in [top, bottom].iter().enumerate() {
        for (col, img) in images.iter().enumerate() {
            paste(&mut canvas, cw, img, col * w, row * h);
        }
    }
    write_png_rgba(out, cw as u32, ch as u32, &canvas)
}

fn paste(canvas: &mut [u8], cw: usize, img: &Image, x0: usize, y0: usize) {
    let w = img.width as usize;
    for y in 0..img.height as usize {
        for x in 0..w {
            let src = &img.rgb[(y * w + x) * 3..(y * w + x) * 3 + 3];
            let dst = ((y0 + y) * cw + x0 + x) * 4;
            for c in 0..3 {
                canvas[dst + c] = (src[c].clamp(0.0, 1.0) * 255.0).round() as u8;
            }
            canvas[dst + 3] = 255;
        }
    }
}
