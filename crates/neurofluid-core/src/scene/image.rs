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
        let bytes = crate::input_file::read(path).map_err(|e| SceneError::io(path, e))?;
        let reader = || {
            image::ImageReader::with_format(std::io::Cursor::new(&bytes), image::ImageFormat::Png)
        };
        let (w, h) = reader()
            .into_dimensions()
            .map_err(|e| image_error(path, e))?;
        check_pixels(path, w, h)?;
        check_palette(&bytes).map_err(|message| SceneError::Image {
            path: path.to_path_buf(),
            message,
        })?;
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
    crate::input_file::check(path).map_err(|e| SceneError::io(path, e))?;
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

/// An indexed PNG's pixels must name entries its palette has: decoders show the others as
/// opaque black, a picture the file does not hold. Other colour types pass unread.
fn check_palette(bytes: &[u8]) -> std::result::Result<(), String> {
    // the IHDR chunk's colour type, byte 25 of a PNG: 3 is indexed
    if bytes.get(25) != Some(&3) {
        return Ok(());
    }
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .map_err(|e| e.to_string())?;
    let info = reader.info();
    let entries = info.palette.as_ref().map_or(0, |p| p.len() / 3);
    let depth = info.bit_depth as usize;
    if !matches!(depth, 1 | 2 | 4 | 8) {
        return Err(format!(
            "an indexed image of bit depth {depth}, expected 1, 2, 4 or 8"
        ));
    }
    let size = reader
        .output_buffer_size()
        .ok_or("an image too large to decode")?;
    let mut buf = vec![0; size];
    let frame = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
    let per_byte = 8 / depth;
    for (y, row) in buf[..frame.buffer_size()]
        .chunks(frame.line_size)
        .enumerate()
    {
        for x in 0..frame.width as usize {
            let shift = 8 - depth * (1 + x % per_byte);
            let index = (row[x / per_byte] >> shift) as usize & ((1 << depth) - 1);
            if index >= entries {
                return Err(format!(
                    "pixel ({x}, {y}) names palette entry {index}, and the palette has {entries} \
                     (a damaged image)"
                ));
            }
        }
    }
    Ok(())
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

#[cfg(test)]
mod tests {
    use super::*;

    /// An indexed PNG with `palette` (RGB triples) and one row of `indices` (8 bits each).
    fn indexed_png(path: &Path, palette: &[u8], indices: &[u8]) {
        let file = std::fs::File::create(path).unwrap();
        let mut encoder = png::Encoder::new(file, indices.len() as u32, 1);
        encoder.set_color(png::ColorType::Indexed);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_palette(palette.to_vec());
        let mut writer = encoder.write_header().unwrap();
        writer.write_image_data(indices).unwrap();
    }

    /// A pixel naming a palette entry the file lacks is an error, not a black pixel (issue 72);
    /// an indexed image within its palette reads as its colours.
    #[test]
    fn palette_indices_out_of_range_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.png");
        indexed_png(&path, &[255, 0, 0, 0, 0, 255], &[0, 1, 1]);
        let image = Image::read(&path).unwrap();
        assert_eq!(&image.rgb[..6], &[1.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
        indexed_png(&path, &[255, 0, 0, 0, 0, 255], &[0, 5, 1]);
        let e = Image::read(&path).unwrap_err().to_string();
        assert!(e.contains("p.png") && e.contains("palette entry 5"), "{e}");
    }
}
