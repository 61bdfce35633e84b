//! What a person looks at after an evaluation: animated PNGs (APNG, played by every browser and
//! by GitHub's README view) and pictures of the particles themselves, seen from a test camera and
//! coloured by each predicted particle's distance to the nearest true one; the training curves
//! and d(t) plots ([`plot`]) and the evaluation's page ([`viewer`]).

pub mod plot;
pub mod viewer;

use std::path::Path;

use anyhow::Context;
use neurofluid_core::camera::Camera;
use neurofluid_core::metrics::RgbImage;
use plotters::prelude::*;

use crate::pictures::plot::{FONT_FAMILY, register_bundled_font};

/// A picture, RGB in [0, 1], row-major (a stage's evaluation: `[render | truth]` side by side).
#[derive(Debug, Clone, PartialEq)]
pub struct Picture {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width · height · 3` values.
    pub rgb: Vec<f32>,
}

impl From<&RgbImage> for Picture {
    fn from(image: &RgbImage) -> Self {
        Self {
            width: image.width as u32,
            height: image.height as u32,
            rgb: image.data.clone(),
        }
    }
}

/// The frame time (ms) of an animation of every `every`-th frame of a sequence of `fps` frames
/// per second at half speed (two frame intervals per frame shown), within 20 ms … 5 s.
pub fn half_speed_frame_ms(every: usize, fps: f32) -> u16 {
    (2000.0 * every.max(1) as f64 / f64::from(fps))
        .round()
        .clamp(20.0, 5000.0) as u16
}

/// Writes `frames` (all of one size) as an endlessly looping animated PNG, `frame_ms` per
/// frame, atomically.
pub fn write_apng(path: &Path, frames: &[Picture], frame_ms: u16) -> anyhow::Result<()> {
    let first = frames
        .first()
        .context("an animation needs at least one frame")?;
    let (w, h) = (first.width, first.height);
    anyhow::ensure!(
        frames.iter().all(|f| (f.width, f.height) == (w, h)),
        "the frames of an animation must have one size"
    );
    let mut bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut bytes, w, h);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_animated(frames.len() as u32, 0)?;
        enc.set_frame_delay(frame_ms, 1000)?;
        let mut writer = enc.write_header()?;
        for f in frames {
            let data: Vec<u8> = f
                .rgb
                .iter()
                .map(|&v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
                .collect();
            writer.write_image_data(&data)?;
        }
        writer.finish()?;
    }
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    neurofluid_core::atomic::write_bytes(path, &bytes)
        .with_context(|| format!("writing {}", path.display()))
}

/// Height of the label strip above each picture of [`row_of`].
pub const LABEL_HEIGHT: u32 = 16;

/// Pictures side by side, left to right, on a white background, each under its label (in the
/// bundled font, cut to the picture's width).
pub fn row_of(pictures: &[(&str, &Picture)]) -> Picture {
    let w: u32 = pictures.iter().map(|(_, p)| p.width).sum();
    let h = pictures.iter().map(|(_, p)| p.height).max().unwrap_or(0) + LABEL_HEIGHT;
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let mut x0 = 0;
    for (_, p) in pictures {
        for y in 0..p.height {
            for x in 0..p.width {
                let src = ((y * p.width + x) * 3) as usize;
                let dst = (((y + LABEL_HEIGHT) * w + x0 + x) * 3) as usize;
                for k in 0..3 {
                    buf[dst + k] = (p.rgb[src + k].clamp(0.0, 1.0) * 255.0).round() as u8;
                }
            }
        }
        x0 += p.width;
    }
    if w > 0 && h > 0 {
        register_bundled_font();
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let mut x0 = 0;
        for (label, p) in pictures {
            let cell = root.clone().shrink((x0, 0), (p.width, LABEL_HEIGHT));
            let style = (FONT_FAMILY, 12).into_text_style(&cell);
            if let Err(e) = cell.draw_text(label, &style, (2, 1)) {
                tracing::warn!("drawing a label: {e}");
            }
            x0 += p.width;
        }
        if let Err(e) = root.present() {
            tracing::warn!("drawing the labels: {e}");
        }
    }
    Picture {
        width: w,
        height: h,
        rgb: buf.iter().map(|&v| v as f32 / 255.0).collect(),
    }
}

/// Pictures stacked top to bottom (each row as wide as the widest).
pub fn column_of(rows: &[Picture]) -> Picture {
    let w = rows.iter().map(|p| p.width).max().unwrap_or(0);
    let h: u32 = rows.iter().map(|p| p.height).sum();
    let mut rgb = vec![1.0f32; (w * h * 3) as usize];
    let mut y0 = 0;
    for p in rows {
        for y in 0..p.height {
            let src = (y * p.width * 3) as usize;
            let dst = ((y0 + y) * w * 3) as usize;
            rgb[dst..dst + (p.width * 3) as usize]
                .copy_from_slice(&p.rgb[src..src + (p.width * 3) as usize]);
        }
        y0 += p.height;
    }
    Picture {
        width: w,
        height: h,
        rgb,
    }
}

/// `[a | b]`: two images of the same size side by side.
pub fn side_by_side(a: &RgbImage, b: &RgbImage) -> Picture {
    let (w, h) = (a.width, a.height);
    let mut rgb = Vec::with_capacity(2 * w * h * 3);
    for row in 0..h {
        rgb.extend_from_slice(&a.data[row * w * 3..(row + 1) * w * 3]);
        rgb.extend_from_slice(&b.data[row * w * 3..(row + 1) * w * 3]);
    }
    Picture {
        width: 2 * w as u32,
        height: h as u32,
        rgb,
    }
}

/// The colour of the true particles.
pub const TRUTH_COLOUR: [f32; 3] = [0.25, 0.45, 0.8];

/// Viridis at `t` ∈ [0, 1] (five stops, linearly interpolated): dark purple for near, yellow for
/// far.
pub fn viridis(t: f64) -> [f32; 3] {
    const STOPS: [[f32; 3]; 5] = [
        [0.267, 0.005, 0.329],
        [0.231, 0.322, 0.545],
        [0.129, 0.569, 0.549],
        [0.369, 0.788, 0.384],
        [0.993, 0.906, 0.144],
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        1.0
    };
    let x = t * (STOPS.len() - 1) as f64;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = (x - i as f64) as f32;
    std::array::from_fn(|k| STOPS[i][k] * (1.0 - f) + STOPS[i + 1][k] * f)
}

/// Particles seen from `camera` (at its resolution), each a disc of the particle radius in
/// projection, drawn far to near on white. `colour(i)` colours particle `i`.
pub fn particle_view(
    camera: &Camera,
    pos: &[[f32; 3]],
    radius: f32,
    colour: impl Fn(usize) -> [f32; 3],
) -> Picture {
    let (w, h) = (camera.width, camera.height);
    let mut rgb = vec![1.0f32; (w * h * 3) as usize];
    let mut projected: Vec<(usize, f32, f32, f32)> = pos
        .iter()
        .enumerate()
        .filter_map(|(i, &p)| camera.project(p).map(|(c, r, d)| (i, c, r, d)))
        .collect();
    projected.sort_by(|a, b| b.3.total_cmp(&a.3));
    // the c2w scale cancels in pixel coordinates but not in depth: measure the disc in pixels
    // from the projection of a point one radius to the side
    let scale = {
        let r = &camera.c2w;
        (r[0][0] * r[0][0] + r[1][0] * r[1][0] + r[2][0] * r[2][0]).sqrt()
    };
    for (i, col, row, depth) in projected {
        let px = (camera.fx * radius * scale / depth).max(0.75);
        let c = colour(i);
        let (x0, x1) = ((col - px).floor() as i64, (col + px).ceil() as i64);
        let (y0, y1) = ((row - px).floor() as i64, (row + px).ceil() as i64);
        for y in y0.max(0)..=y1.min(h as i64 - 1) {
            for x in x0.max(0)..=x1.min(w as i64 - 1) {
                let (dx, dy) = (x as f32 - col, y as f32 - row);
                if dx * dx + dy * dy <= px * px {
                    let k = ((y as u32 * w + x as u32) * 3) as usize;
                    rgb[k..k + 3].copy_from_slice(&c);
                }
            }
        }
    }
    Picture {
        width: w,
        height: h,
        rgb,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(w: u32, h: u32, v: f32) -> Picture {
        Picture {
            width: w,
            height: h,
            rgb: vec![v; (w * h * 3) as usize],
        }
    }

    #[test]
    fn an_apng_plays_its_frames_in_order() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a/anim.png");
        let frames: Vec<Picture> = (0..5).map(|k| flat(6, 4, k as f32 / 4.0)).collect();
        write_apng(&path, &frames, 80).unwrap();
        let mut dec =
            png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()))
                .read_info()
                .unwrap();
        let ctl = dec.info().animation_control.unwrap();
        assert_eq!((ctl.num_frames, ctl.num_plays), (5, 0));
        let mut buf = vec![0; dec.output_buffer_size().unwrap()];
        for k in 0..5 {
            let info = dec.next_frame(&mut buf).unwrap();
            assert_eq!((info.width, info.height), (6, 4));
            assert_eq!(buf[0], (k as f32 / 4.0 * 255.0).round() as u8);
        }
        assert!(write_apng(&path, &[flat(6, 4, 0.0), flat(5, 4, 0.0)], 80).is_err());
    }

    #[test]
    fn a_particle_in_front_of_the_camera_is_drawn_where_it_projects() {
        // focal 40 px at 32 px wide
        let angle = 2.0 * 0.4f32.atan();
        let cam = Camera::look_at(32, 32, angle, [0.0, 0.0, 5.0], [0.0; 3], [0.0, 1.0, 0.0]);
        let pic = particle_view(&cam, &[[0.0, 0.0, 0.0], [0.0, 0.0, 9.0]], 0.05, |_| {
            [1.0, 0.0, 0.0]
        });
        // the centre pixel is red, a corner stays white, the particle behind the camera is not
        // drawn anywhere
        let at = |x: u32, y: u32| &pic.rgb[((y * 32 + x) * 3) as usize..][..3];
        assert_eq!(at(16, 16), [1.0, 0.0, 0.0]);
        assert_eq!(at(0, 0), [1.0, 1.0, 1.0]);
        let red = pic.rgb.chunks(3).filter(|c| c == &[1.0, 0.0, 0.0]).count();
        // radius 0.05 at depth 5 with focal 40 px: a disc of 0.4 px, drawn at the minimum
        assert!((1..=9).contains(&red), "{red}");
    }

    #[test]
    fn viridis_runs_from_purple_to_yellow() {
        assert_eq!(viridis(0.0), [0.267, 0.005, 0.329]);
        assert_eq!(viridis(1.0), [0.993, 0.906, 0.144]);
        assert_eq!(viridis(f64::NAN), viridis(1.0));
        let mid = viridis(0.5);
        assert!((mid[1] - 0.569).abs() < 1e-6);
    }

    #[test]
    fn rows_and_columns_keep_their_pictures() {
        let r = row_of(&[("a", &flat(3, 2, 0.0)), ("b", &flat(4, 5, 0.0))]);
        assert_eq!((r.width, r.height), (7, 5 + LABEL_HEIGHT));
        let c = column_of(&[flat(3, 2, 0.0), flat(4, 5, 0.5)]);
        assert_eq!((c.width, c.height), (4, 7));
        // the narrower row is padded with white
        assert_eq!(c.rgb[3 * 3], 1.0);
        assert_eq!(c.rgb[(2 * 4) * 3], 0.5);
    }
}
