//! Image metrics on RGB images in [0, 1]: PSNR and SSIM as NeuroFluid's evaluation computes them
//! (spec §6.3): SSIM with an 11-tap Gaussian window (σ = 1.5), per channel, **valid** filtering (no
//! padding), C1 = 0.01², C2 = 0.03², the mean of the SSIM map over positions and channels.
//!
//! Why not a crate: the crates' SSIM (image-compare, dssim, …) pad, use other windows or work in
//! other colour spaces, so their values differ from the paper's evaluation; this one matches the
//! reference implementation (`tests/image_metrics_reference.rs`).

/// An RGB image, row-major, 3 interleaved channels, values in [0, 1].
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `height × width × 3` values.
    pub data: Vec<f32>,
}

/// Why two images cannot be compared.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ImageError {
    /// The images differ in size.
    #[error("image sizes differ: {0}×{1} vs {2}×{3}")]
    SizeMismatch(usize, usize, usize, usize),
    /// The data length does not match width × height × 3.
    #[error("image data holds {found} values, {width}×{height}×3 needs {expected}")]
    BadLength {
        /// Width.
        width: usize,
        /// Height.
        height: usize,
        /// width × height × 3.
        expected: usize,
        /// What the data holds.
        found: usize,
    },
    /// SSIM's valid filtering needs at least 11×11 pixels.
    #[error("SSIM needs images of at least 11×11 pixels, got {0}×{1}")]
    TooSmall(usize, usize),
}

impl RgbImage {
    /// Wraps data, checking its length.
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Result<Self, ImageError> {
        if data.len() != width * height * 3 {
            return Err(ImageError::BadLength {
                width,
                height,
                expected: width * height * 3,
                found: data.len(),
            });
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// The image quantised to 8 bits and back, as the evaluation reads saved PNGs.
    pub fn quantised(&self) -> Self {
        Self {
            data: self
                .data
                .iter()
                .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() / 255.0)
                .collect(),
            ..*self
        }
    }
}

fn same_size(a: &RgbImage, b: &RgbImage) -> Result<(), ImageError> {
    if a.width != b.width || a.height != b.height {
        return Err(ImageError::SizeMismatch(
            a.width, a.height, b.width, b.height,
        ));
    }
    Ok(())
}

/// PSNR = 10·log10(1 / MSE) over all pixels and channels (infinite for identical images).
pub fn psnr(a: &RgbImage, b: &RgbImage) -> Result<f64, ImageError> {
    same_size(a, b)?;
    let mse = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
        .sum::<f64>()
        / a.data.len().max(1) as f64;
    Ok(10.0 * (1.0 / mse).log10())
}

/// The share of the squared error between `a` and `b` that lies on the pixels where `coverage`
/// (one value per pixel, e.g. the truth's alpha) is at least ½: how much of a render's error is
/// on the fluid rather than around it. `None` for identical images.
pub fn error_share_on(
    a: &RgbImage,
    b: &RgbImage,
    coverage: &[f32],
) -> Result<Option<f64>, ImageError> {
    same_size(a, b)?;
    if coverage.len() != a.width * a.height {
        return Err(ImageError::BadLength {
            width: a.width,
            height: a.height,
            expected: a.width * a.height,
            found: coverage.len(),
        });
    }
    let (mut on, mut all) = (0.0, 0.0);
    for ((pa, pb), c) in a.data.chunks(3).zip(b.data.chunks(3)).zip(coverage) {
        let e: f64 = pa
            .iter()
            .zip(pb)
            .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
            .sum();
        all += e;
        if *c >= 0.5 {
            on += e;
        }
    }
    Ok((all > 0.0).then(|| on / all))
}

const WIN: usize = 11;
const SIGMA: f64 = 1.5;

fn gaussian_window() -> [f64; WIN] {
    let mut g = [0.0; WIN];
    let c = (WIN / 2) as f64;
    for (i, v) in g.iter_mut().enumerate() {
        *v = (-((i as f64 - c).powi(2)) / (2.0 * SIGMA * SIGMA)).exp();
    }
    let s: f64 = g.iter().sum();
    g.map(|v| v / s)
}

/// Valid separable Gaussian filter of one `h × w` plane.
fn filter_valid(plane: &[f64], w: usize, h: usize, g: &[f64; WIN]) -> Vec<f64> {
    let (ow, oh) = (w - WIN + 1, h - WIN + 1);
    let mut rows = vec![0.0; h * ow];
    for y in 0..h {
        for x in 0..ow {
            rows[y * ow + x] = (0..WIN).map(|k| g[k] * plane[y * w + x + k]).sum();
        }
    }
    let mut out = vec![0.0; oh * ow];
    for y in 0..oh {
        for x in 0..ow {
            out[y * ow + x] = (0..WIN).map(|k| g[k] * rows[(y + k) * ow + x]).sum();
        }
    }
    out
}

/// Mean SSIM over the valid positions of every channel.
pub fn ssim(a: &RgbImage, b: &RgbImage) -> Result<f64, ImageError> {
    same_size(a, b)?;
    let (w, h) = (a.width, a.height);
    if w < WIN || h < WIN {
        return Err(ImageError::TooSmall(w, h));
    }
    let g = gaussian_window();
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let mut total = 0.0;
    let mut count = 0usize;
    for c in 0..3 {
        let x: Vec<f64> = a
            .data
            .iter()
            .skip(c)
            .step_by(3)
            .map(|&v| v as f64)
            .collect();
        let y: Vec<f64> = b
            .data
            .iter()
            .skip(c)
            .step_by(3)
            .map(|&v| v as f64)
            .collect();
        let prod = |p: &[f64], q: &[f64]| p.iter().zip(q).map(|(u, v)| u * v).collect::<Vec<_>>();
        let mu_x = filter_valid(&x, w, h, &g);
        let mu_y = filter_valid(&y, w, h, &g);
        let xx = filter_valid(&prod(&x, &x), w, h, &g);
        let yy = filter_valid(&prod(&y, &y), w, h, &g);
        let xy = filter_valid(&prod(&x, &y), w, h, &g);
        for i in 0..mu_x.len() {
            let (mx, my) = (mu_x[i], mu_y[i]);
            let sx = xx[i] - mx * mx;
            let sy = yy[i] - my * my;
            let sxy = xy[i] - mx * my;
            total += ((2.0 * mx * my + c1) * (2.0 * sxy + c2))
                / ((mx * mx + my * my + c1) * (sx + sy + c2));
            count += 1;
        }
    }
    Ok(total / count as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pattern(w: usize, h: usize, phase: f32) -> RgbImage {
        let data = (0..w * h * 3)
            .map(|i| {
                let (p, c) = (i / 3, i % 3);
                let (x, y) = ((p % w) as f32, (p / w) as f32);
                0.5 + 0.4 * (0.3 * x + 0.2 * y + phase + c as f32).sin()
            })
            .collect();
        RgbImage::new(w, h, data).unwrap()
    }

    #[test]
    fn identical_images() {
        let a = pattern(16, 12, 0.0);
        assert!(psnr(&a, &a).unwrap().is_infinite());
        assert!((ssim(&a, &a).unwrap() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn the_error_share_counts_the_covered_pixels_error() {
        // 2×2 image, one channel off per pixel: errors 0.01, 0.04, 0.09, 0.16 (sum 0.30)
        let a = RgbImage::new(2, 2, vec![0.5; 12]).unwrap();
        let mut b = a.clone();
        for (i, d) in [0.1f32, 0.2, 0.3, 0.4].iter().enumerate() {
            b.data[3 * i + i % 3] += d;
        }
        let share = error_share_on(&a, &b, &[1.0, 0.0, 0.5, 0.49])
            .unwrap()
            .unwrap();
        assert!((share - 0.10 / 0.30).abs() < 1e-6, "{share}");
        assert_eq!(error_share_on(&a, &a, &[1.0; 4]).unwrap(), None);
        assert!(matches!(
            error_share_on(&a, &b, &[1.0; 3]),
            Err(ImageError::BadLength { found: 3, .. })
        ));
    }

    #[test]
    fn psnr_of_a_known_mse() {
        let a = pattern(16, 12, 0.0);
        let mut b = a.clone();
        // every value off by 0.1 → MSE 0.01 → 20 dB
        b.data.iter_mut().for_each(|v| *v += 0.1);
        assert!((psnr(&a, &b).unwrap() - 20.0).abs() < 1e-5);
        // half the values off by 0.2 → MSE 0.02
        let mut c = a.clone();
        c.data.iter_mut().step_by(2).for_each(|v| *v += 0.2);
        let expected = 10.0 * (1.0f64 / (0.5 * 0.04)).log10();
        let got = psnr(&a, &c).unwrap();
        assert!((got - expected).abs() < 1e-4, "{got} vs {expected}");
    }

    #[test]
    fn ssim_of_a_constant_shift_by_hand() {
        // a constant image against a constant shifted by δ: σ terms vanish, so
        // SSIM = (2μ₁μ₂ + C1) / (μ₁² + μ₂² + C1) everywhere
        let a = RgbImage::new(12, 12, vec![0.3; 12 * 12 * 3]).unwrap();
        let b = RgbImage::new(12, 12, vec![0.5; 12 * 12 * 3]).unwrap();
        let c1 = 1e-4;
        let expected = (2.0 * 0.3 * 0.5 + c1) / (0.09 + 0.25 + c1);
        assert!((ssim(&a, &b).unwrap() - expected).abs() < 1e-6);
    }

    #[test]
    fn bad_shapes_are_errors() {
        let a = pattern(16, 12, 0.0);
        let b = pattern(12, 16, 0.0);
        assert_eq!(psnr(&a, &b), Err(ImageError::SizeMismatch(16, 12, 12, 16)));
        let small = pattern(10, 30, 0.0);
        assert_eq!(ssim(&small, &small), Err(ImageError::TooSmall(10, 30)));
        assert!(RgbImage::new(2, 2, vec![0.0; 11]).is_err());
    }

    #[test]
    fn quantisation_rounds_to_8_bits() {
        let a = RgbImage::new(1, 1, vec![0.5, 1.2, -0.1])
            .unwrap()
            .quantised();
        assert_eq!(a.data, vec![128.0 / 255.0, 1.0, 0.0]);
    }
}
