//! The nerf_pl NeRF MLP with widened inputs (spec §2.6): D = 8 layers of width 256 with ReLU,
//! the input concatenated in front of the hidden state at layer 4, a σ head without
//! activation, and a colour branch `Linear(256→256) → cat[feat, e_d] → Linear→128 + ReLU →
//! Linear→3 + sigmoid`.

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::sigmoid;
use neurofluid_core::dense::{Activation, first_rows, linear, linear_of_cat, pad_to_row_blocks};

/// The shape of a NeRF network: trunk depth and width, the skip layer and the input widths.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MlpShape {
    /// Trunk layers D.
    pub depth: usize,
    /// Trunk width W.
    pub width: usize,
    /// Index of the layer whose input is `cat[e_x, h]`.
    pub skip: usize,
    /// Width of the position-like input e_x.
    pub in_xyz: usize,
    /// Width of the direction-like input e_d.
    pub in_dir: usize,
}

impl MlpShape {
    /// The first field with an invalid value, and what was expected.
    pub fn problem(&self) -> Option<(&'static str, String)> {
        if self.depth < 2 {
            return Some((
                "depth",
                format!("expected an MLP of depth ≥ 2, got {}", self.depth),
            ));
        }
        if self.width == 0 {
            return Some(("width", "expected an MLP of width ≥ 1, got 0".into()));
        }
        if self.skip == 0 || self.skip >= self.depth {
            return Some((
                "skip",
                format!(
                    "expected 0 < skip < depth ({}), got {}",
                    self.depth, self.skip
                ),
            ));
        }
        None
    }
}

/// One NeRF network (coarse or fine). Field names follow nerf_pl's parameter names.
#[derive(Module, Debug)]
pub struct NerfMlp {
    /// `xyz_encoding_{1..D}.0`: the trunk layers.
    pub xyz_encoding: Vec<Linear>,
    /// `xyz_encoding_final`: 256 → 256, no activation.
    pub xyz_encoding_final: Linear,
    /// `sigma`: 256 → 1, raw density.
    pub sigma: Linear,
    /// `dir_encoding.0`: (256 + in_dir) → 128, ReLU.
    pub dir_encoding: Linear,
    /// `rgb.0`: 128 → 3, sigmoid.
    pub rgb: Linear,
    /// Index of the layer whose input is `cat[e_x, h]`.
    pub skip: usize,
}

/// Hidden activations of a forward pass (for parity tests).
#[derive(Debug, Clone)]
pub struct MlpTrace {
    /// Post-ReLU output of every trunk layer, `h1 … hD`.
    pub hidden: Vec<Tensor<2>>,
    /// Output of `xyz_encoding_final`.
    pub feat: Tensor<2>,
    /// Output of `dir_encoding` (post-ReLU).
    pub hd: Tensor<2>,
}

/// The shapes `[in, out]` of every layer of a network, keyed by the nerf_pl name (without
/// the `nerf_coarse.` prefix and the `.weight` suffix).
pub fn layer_shapes(shape: &MlpShape) -> Vec<(String, [usize; 2])> {
    let (w, ix, id) = (shape.width, shape.in_xyz, shape.in_dir);
    let mut v = Vec::new();
    for i in 0..shape.depth {
        let d_in = if i == 0 {
            ix
        } else if i == shape.skip {
            ix + w
        } else {
            w
        };
        v.push((format!("xyz_encoding_{}.0", i + 1), [d_in, w]));
    }
    v.push(("xyz_encoding_final".into(), [w, w]));
    v.push(("sigma".into(), [w, 1]));
    v.push(("dir_encoding.0".into(), [w + id, w / 2]));
    v.push(("rgb.0".into(), [w / 2, 3]));
    v
}

impl NerfMlp {
    /// A randomly initialised network (PyTorch's default Linear initialisation), f32.
    pub fn new(shape: &MlpShape, device: &Device) -> Self {
        let mut layers: Vec<Linear> = layer_shapes(shape)
            .into_iter()
            .map(|(_, [i, o])| LinearConfig::new(i, o).init(device))
            .collect();
        Self::from_layers(&mut layers, shape.skip)
    }

    /// Assembles a network from its layers in the order of [`layer_shapes`].
    pub fn from_layers(layers: &mut Vec<Linear>, skip: usize) -> Self {
        let rgb = layers.pop().expect("rgb layer");
        let dir_encoding = layers.pop().expect("dir layer");
        let sigma = layers.pop().expect("sigma layer");
        let xyz_encoding_final = layers.pop().expect("final layer");
        Self {
            xyz_encoding: std::mem::take(layers),
            xyz_encoding_final,
            sigma,
            dir_encoding,
            rgb,
            skip,
        }
    }

    /// Every layer with its nerf_pl name, in the order of [`layer_shapes`].
    pub fn named_layers(&self) -> Vec<(String, &Linear)> {
        let mut v: Vec<(String, &Linear)> = self
            .xyz_encoding
            .iter()
            .enumerate()
            .map(|(i, l)| (format!("xyz_encoding_{}.0", i + 1), l))
            .collect();
        v.push(("xyz_encoding_final".into(), &self.xyz_encoding_final));
        v.push(("sigma".into(), &self.sigma));
        v.push(("dir_encoding.0".into(), &self.dir_encoding));
        v.push(("rgb.0".into(), &self.rgb));
        v
    }

    /// `(rgb [Q, 3] after the sigmoid, σ_raw [Q, 1] without activation)`.
    pub fn forward(&self, e_x: Tensor<2>, e_d: Tensor<2>) -> (Tensor<2>, Tensor<2>) {
        let (rgb, sigma, _) = self.forward_impl(e_x, e_d, false);
        (rgb, sigma)
    }

    /// Like [`NerfMlp::forward`], also returning the hidden activations.
    pub fn forward_traced(
        &self,
        e_x: Tensor<2>,
        e_d: Tensor<2>,
    ) -> (Tensor<2>, Tensor<2>, MlpTrace) {
        let (rgb, sigma, trace) = self.forward_impl(e_x, e_d, true);
        (rgb, sigma, trace.expect("trace requested"))
    }

    fn forward_impl(
        &self,
        e_x: Tensor<2>,
        e_d: Tensor<2>,
        trace: bool,
    ) -> (Tensor<2>, Tensor<2>, Option<MlpTrace>) {
        let (inputs, m) = pad_to_row_blocks(vec![e_x, e_d]);
        let [e_x, e_d] = <[Tensor<2>; 2]>::try_from(inputs).expect("two inputs");
        let mut hidden = Vec::new();
        let mut h = e_x.clone();
        for (i, layer) in self.xyz_encoding.iter().enumerate() {
            h = if i == self.skip {
                linear_of_cat(layer, vec![e_x.clone(), h], Activation::Relu)
            } else {
                linear(layer, h, Activation::Relu)
            };
            if trace {
                hidden.push(h.clone());
            }
        }
        let sigma = linear(&self.sigma, h.clone(), Activation::Identity);
        let feat = linear(&self.xyz_encoding_final, h, Activation::Identity);
        let hd = linear_of_cat(
            &self.dir_encoding,
            vec![feat.clone(), e_d],
            Activation::Relu,
        );
        let rgb = sigmoid(linear(&self.rgb, hd.clone(), Activation::Identity));
        let t = trace.then(|| MlpTrace {
            hidden: hidden.into_iter().map(|h| first_rows(h, m)).collect(),
            feat: first_rows(feat, m),
            hd: first_rows(hd, m),
        });
        (first_rows(rgb, m), first_rows(sigma, m), t)
    }
}
