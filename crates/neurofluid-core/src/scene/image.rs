//! RGBA PNG frames: read (composited on white, float32) and written atomically.

use std::path::Path;

use super::error::{Result, SceneError};

/// An image composited on white: `rgb` is row-major H×W×3 in [0, 1]; `alpha` is H×W.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Colour composited on white, row-major, 3 values per pixel.
    pub rgb: Vec<f32>,
    /// Coverage (the PNG's alpha; 1 for images without alpha).
    pub alpha: Vec<f32>,
}

impl Image {
    /// Reads a PNG (any colour type) and composites it on white: c·a + (1 − a). The size in
    /// its header is checked against [`crate::limits::max_image_pixels`] before decoding.
    pub fn read(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| SceneError::io(path, e))?;
        let reader = || {
            image::ImageReader::with_format(std::io::Cursor::new(&bytes), image::ImageFormat::Png)
        };
        let (w, h) = reader()
            .into_dimensions()
            .map_err(|e| image_error(path, e))?;
        check_pixels(path, w, h)?;
        let img = reader()
            .decode()
            .map_err(|e| image_error(path, e))?
            .into_rgba32f();
        let (width, height) = img.dimensions();
        let n = (width * height) as usize;
        let mut rgb = Vec::with_capacity(n * 3);
        let mut alpha = Vec::with_capacity(n);
        for px in img.pixels() {
            let a = px[3];
            for c in 0..3 {
                rgb.push(px[c] * a + (1.0 - a));
            }
            alpha.push(a);
        }
        Ok(Self {
            width,
            height,
            rgb,
            alpha,
        })
    }
}

/// Width and height of a PNG, read from its header only, within
/// [`crate::limits::max_image_pixels`].
pub fn png_size(path: &Path) -> Result<(u32, u32)> {
    let (w, h) = image::image_dimensions(path).map_err(|e| image_error(path, e))?;
    check_pixels(path, w, h)?;
    Ok((w, h))
}

fn image_error(path: &Path, e: image::ImageError) -> SceneError {
    match e {
        image::ImageError::IoError(io) => SceneError::io(path, io),
        e => SceneError::Image {
            path: path.to_path_buf(),
            message: e.to_string(),
        },
    }
}

fn check_pixels(path: &Path, w: u32, h: u32) -> Result<()> {
    crate::limits::check_image(w, h).map_err(|message| SceneError::Image {
        path: path.to_path_buf(),
        message,
    })
}

/// Writes an 8-bit RGBA image (row-major, 4 bytes per pixel) as PNG, atomically.
pub fn write_png_rgba(path: &Path, width: u32, height: u32, rgba: &[u8]) -> Result<()> {
    if rgba.len() != width as usize * height as usize * 4 {
        return Err(SceneError::Image {
            path: path.to_path_buf(),
            message: format!(
                "{} bytes given for a {width}×{height} RGBA image (expected {})",
                rgba.len(),
                width as usize * height as usize * 4
            ),
        });
    }
    let mut buf = Vec::new();
    {
        use image::ImageEncoder;
        let enc = image::codecs::png::PngEncoder::new(&mut buf);
        enc.write_image(rgba, width, height, image::ExtendedColorType::Rgba8)
            .map_err(|e| SceneError::Image {
                path: path.to_path_buf(),
                message: e.to_string(),
            })?;
    }
    crate::atomic::write_bytes(path, &buf).map_err(|e| SceneError::io(path, e))
}
