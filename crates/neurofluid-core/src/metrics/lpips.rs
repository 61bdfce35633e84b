//! LPIPS v0.1 with the AlexNet trunk (Zhang et al., CVPR 2018), the perceptual distance
//! NeuroFluid reports beside PSNR and SSIM.
//!
//! Both images go from [0, 1] to [−1, 1] and through LPIPS's scaling layer; the five ReLU outputs
//! of AlexNet's features (torchvision's layout: conv 11×11/4 pad 2, max-pool 3/2, conv 5×5 pad 2,
//! max-pool 3/2, three conv 3×3 pad 1) are normalised over channels (`f / (‖f‖ + 1e-10)`); the
//! squared differences go through each layer's 1×1 linear head, are averaged over space and
//! summed over layers. The weights (`assets/lpips/alex_v0.1.safetensors`, made by
//! `tests/data/lpips/make_lpips.py`; licences beside it) are compiled in.

use burn::prelude::*;
use burn::tensor::activation::relu;
use burn::tensor::module::{conv2d, max_pool2d};
use burn::tensor::ops::{ConvOptions, MaxPoolOptions};

use super::RgbImage;

/// The weights, compiled in.
const WEIGHTS: &[u8] = include_bytes!(concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../assets/lpips/alex_v0.1.safetensors"
));

/// The smallest image side the trunk accepts (its last pooling needs a 3×3 window).
pub const MIN_SIDE: usize = 31;

/// Why LPIPS could not be computed.
#[derive(Debug, thiserror::Error)]
pub enum LpipsError {
    /// The weights could not be read.
    #[error("LPIPS weights: {0}")]
    Weights(String),
    /// The two images do not fit.
    #[error("LPIPS: {0}")]
    Images(String),
}

/// AlexNet's five convolutions (stride, padding) in torchvision's `features` numbering.
const CONVS: [(usize, usize, usize); 5] = [(0, 4, 2), (3, 1, 2), (6, 1, 1), (8, 1, 1), (10, 1, 1)];

/// LPIPS (AlexNet, v0.1) on one device.
#[derive(Debug, Clone)]
pub struct Lpips {
    convs: Vec<(Tensor<4>, Tensor<1>, usize, usize)>,
    heads: Vec<Tensor<4>>,
    device: Device,
}

fn tensor_f32<const D: usize>(
    st: &safetensors::SafeTensors<'_>,
    name: &str,
    device: &Device,
) -> Result<Tensor<D>, LpipsError> {
    let view = st
        .tensor(name)
        .map_err(|e| LpipsError::Weights(format!("`{name}`: {e}")))?;
    if view.dtype() != safetensors::Dtype::F32 || view.shape().len() != D {
        return Err(LpipsError::Weights(format!(
            "`{name}`: expected a {D}-d float32 tensor"
        )));
    }
    let data: Vec<f32> = view
        .data()
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Ok(crate::transfer::upload(
        TensorData::new(data, view.shape().to_vec()),
        device,
    ))
}

impl Lpips {
    /// The compiled-in network on `device`.
    pub fn new(device: &Device) -> Result<Self, LpipsError> {
        let st = safetensors::SafeTensors::deserialize(WEIGHTS)
            .map_err(|e| LpipsError::Weights(e.to_string()))?;
        let convs = CONVS
            .iter()
            .map(|&(i, stride, pad)| {
                Ok((
                    tensor_f32::<4>(&st, &format!("features.{i}.weight"), device)?,
                    tensor_f32::<1>(&st, &format!("features.{i}.bias"), device)?,
                    stride,
                    pad,
                ))
            })
            .collect::<Result<Vec<_>, LpipsError>>()?;
        let heads = (0..5)
            .map(|k| tensor_f32::<4>(&st, &format!("lin{k}.weight"), device))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            convs,
            heads,
            device: device.clone(),
        })
    }

    /// The five ReLU outputs of the trunk for an image `[1, 3, H, W]` in LPIPS's input scale.
    fn features(&self, x: Tensor<4>) -> Vec<Tensor<4>> {
        let pool = || MaxPoolOptions::new([3, 3]).with_stride([2, 2]);
        let mut out = Vec::with_capacity(5);
        let mut h = x;
        for (k, (w, b, stride, pad)) in self.convs.iter().enumerate() {
            if k == 1 || k == 2 {
                h = max_pool2d(h, pool());
            }
            let options = ConvOptions::new([*stride; 2], [*pad; 2], [1, 1], 1);
            h = relu(conv2d(h, w.clone(), Some(b.clone()), options));
            out.push(h.clone());
        }
        out
    }

    fn input(&self, img: &RgbImage) -> Tensor<4> {
        const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
        const SCALE: [f32; 3] = [0.458, 0.448, 0.450];
        let (w, h) = (img.width, img.height);
        let mut chw = vec![0.0f32; 3 * w * h];
        for (p, px) in img.data.chunks_exact(3).enumerate() {
            for c in 0..3 {
                chw[c * w * h + p] = (2.0 * px[c] - 1.0 - SHIFT[c]) / SCALE[c];
            }
        }
        crate::transfer::upload(TensorData::new(chw, [1, 3, h, w]), &self.device)
    }

    /// The LPIPS distance between two images of one size (colours in [0, 1]).
    pub fn distance(&self, a: &RgbImage, b: &RgbImage) -> Result<f64, LpipsError> {
        if (a.width, a.height) != (b.width, b.height) {
            return Err(LpipsError::Images(format!(
                "images of {}×{} and {}×{} pixels",
                a.width, a.height, b.width, b.height
            )));
        }
        if a.width.min(a.height) < MIN_SIDE {
            return Err(LpipsError::Images(format!(
                "images of {}×{} pixels; AlexNet needs at least {MIN_SIDE} on each side",
                a.width, a.height
            )));
        }
        let (fa, fb) = (self.features(self.input(a)), self.features(self.input(b)));
        let mut total = 0.0f64;
        for ((xa, xb), head) in fa.into_iter().zip(fb).zip(&self.heads) {
            let unit = |f: Tensor<4>| {
                let norm = f.clone().powi_scalar(2).sum_dim(1).sqrt().add_scalar(1e-10);
                f / norm
            };
            let d = (unit(xa) - unit(xb)).powi_scalar(2);
            let layer = conv2d(
                d,
                head.clone(),
                None,
                ConvOptions::new([1, 1], [0, 0], [1, 1], 1),
            );
            total += crate::transfer::read_scalar(crate::tensors::mean_all(layer));
        }
        Ok(total)
    }
}
