//! A plain NeRF (Mildenhall et al., 2020) and NeRF-T (NeRF with the time as a further input),
//! the novel-view baselines of NeuroFluid's Tables 3–4 and the density field from which the
//! initial particles are recovered when they are unknown.
//!
//! Everything but the network inputs is PhysNeRF's: the nerf_pl MLP ([`NerfMlp`]), the
//! hierarchical sampling ([`render_hierarchical`]), the volume rendering and the loss. The inputs
//! are `e_x = [γ(x), γ(t)?]` and `e_d = γ(d)`; every sample is evaluated (there is no particle
//! gate). The density is ReLU'd in the volume rendering, as in the original; `density =
//! "softplus"` (a network that cannot start dead) needs the box bounds, outside which the density
//! is zero: with the infinite last interval a softplus density there would leave every ray's last
//! sample opaque, hiding the background.

use burn::prelude::*;
use burn::tensor::activation::relu;
use rand::RngCore;
use serde::{Deserialize, Serialize};

use crate::config::{DensityActivation, encoded_width};
use crate::encoding::{posenc, posenc_cat};
use crate::error::{PhysNerfError, Result};
use crate::features::host_tensor;
use crate::hierarchical::{
    CoarseFine, CoarseFineConfig, DepthPlan, Pass, read, render_hierarchical,
};
use crate::mlp::{MlpShape, NerfMlp};
use crate::real::Real;
use crate::renderer::{PassOutput, RayBatch, RenderOutput, Timings};
use crate::view::{RenderedImage, render_image_with};
use crate::volume::{deltas, volume_render};
use neurofluid_core::camera::Camera;

/// A NeRF's constants. Serde-friendly (the experiment's `[nerf]` table); missing fields take
/// the original NeRF's values, unknown fields are rejected. The ray segment is the scene's and
/// whether time is an input is the baseline's (NeRF or NeRF-T); neither is a file key.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NerfConfig {
    /// Near bound of the ray segment (world units).
    #[serde(skip)]
    pub near: f64,
    /// Far bound of the ray segment.
    #[serde(skip)]
    pub far: f64,
    /// NeRF-T: the time is an input.
    #[serde(skip)]
    pub time: bool,
    /// Density only inside this box (min, max): none outside it. Off in the original NeRF; with
    /// few views a NeRF otherwise explains each view by floaters near its camera.
    #[serde(skip)]
    pub bounds: Option<([f64; 3], [f64; 3])>,
    /// Coarse samples per ray (64).
    pub n_samples: usize,
    /// Importance samples per ray (128); 0 renders coarse only.
    pub n_importance: usize,
    /// Frequencies of γ(x) (10).
    pub freq_x: usize,
    /// Frequencies of γ(d) (4).
    pub freq_d: usize,
    /// Frequencies of γ(t) in NeRF-T (4), t being the frame index over the training frame count.
    pub freq_t: usize,
    /// MLP depth (8).
    pub depth: usize,
    /// MLP width (256).
    pub width: usize,
    /// Layer whose input is `cat[e_x, h]` (4).
    pub skip: usize,
    /// Stratified jitter of the depths in training (on in the original NeRF).
    pub stratified: bool,
    /// Composite on a white background (the scenes' background).
    pub white_background: bool,
    /// Rays per chunk when a whole image is rendered (memory only).
    pub chunk: usize,
    /// The density activation: `relu` (the original NeRF; a network can start dead, σ ≤ 0 on
    /// every sample and no gradient) or `softplus` (σ = softplus(raw − 1) inside the box bounds,
    /// which it needs).
    pub density: DensityActivation,
}

impl Default for NerfConfig {
    fn default() -> Self {
        Self {
            near: 2.0,
            far: 6.0,
            time: false,
            bounds: None,
            n_samples: 64,
            n_importance: 128,
            freq_x: 10,
            freq_d: 4,
            freq_t: 4,
            depth: 8,
            width: 256,
            skip: 4,
            stratified: true,
            white_background: true,
            chunk: 1024,
            density: DensityActivation::Relu,
        }
    }
}

impl NerfConfig {
    /// The shape of its networks.
    pub fn mlp_shape(&self) -> MlpShape {
        MlpShape {
            depth: self.depth,
            width: self.width,
            skip: self.skip,
            in_xyz: encoded_width(3, self.freq_x)
                + usize::from(self.time) * encoded_width(1, self.freq_t),
            in_dir: encoded_width(3, self.freq_d),
        }
    }

    /// The segment and sample counts of a ray.
    pub fn depth_plan(&self) -> DepthPlan {
        DepthPlan {
            near: self.near,
            far: self.far,
            n_samples: self.n_samples,
            n_importance: self.n_importance,
        }
    }

    /// The first field with an invalid value, and what was expected.
    pub fn problem(&self) -> Option<(&'static str, String)> {
        if let Some(p) = self.depth_plan().problem() {
            return Some(p);
        }
        if let Some(p) = self.mlp_shape().problem() {
            return Some(p);
        }
        if self.chunk == 0 {
            return Some(("chunk", "expected at least 1 ray per chunk".into()));
        }
        [
            ("freq_x", self.freq_x),
            ("freq_d", self.freq_d),
            ("freq_t", self.freq_t),
        ]
        .into_iter()
        .find(|&(_, f)| f > 20)
        .map(|(field, f)| {
            (
                field,
                format!("expected at most 20 frequencies per input (2^19 rad per unit), got {f}"),
            )
        })
    }
}

/// A NeRF or NeRF-T: coarse and fine networks.
pub type Nerf = CoarseFine<NerfConfig>;

impl CoarseFineConfig for NerfConfig {
    /// The values' own rules ([`NerfConfig::problem`]) and what rendering adds: a softplus
    /// density needs the box bounds, which the trainer fills in from the scene.
    fn check(&self) -> std::result::Result<(), String> {
        if let Some((field, message)) = self.problem() {
            return Err(format!("{field}: {message}"));
        }
        if self.density == DensityActivation::Softplus && self.bounds.is_none() {
            return Err(
                "density: a softplus density needs box bounds (without them every \
                        ray's last, infinite interval would be opaque)"
                    .into(),
            );
        }
        Ok(())
    }
    fn shape(&self) -> MlpShape {
        self.mlp_shape()
    }
}

impl Nerf {
    /// Renders `rays`; `times` holds one time per ray for NeRF-T and must be `None` for NeRF.
    /// With `rng` the depths are jittered (stratified sampling, for training), without it the
    /// render is deterministic.
    pub fn render_rays(
        &self,
        rays: &RayBatch,
        times: Option<&[f64]>,
        rng: Option<&mut dyn RngCore>,
    ) -> Result<RenderOutput> {
        if rays.origins.len() != rays.dirs.len() {
            return Err(PhysNerfError::Invalid(format!(
                "ray batch has {} origins but {} directions",
                rays.origins.len(),
                rays.dirs.len()
            )));
        }
        match (self.config.time, times) {
            (true, Some(t)) if t.len() == rays.len() => {}
            (true, Some(t)) => {
                return Err(PhysNerfError::Invalid(format!(
                    "NeRF-T needs one time per ray: {} times for {} rays",
                    t.len(),
                    rays.len()
                )));
            }
            (true, None) => {
                return Err(PhysNerfError::Invalid(
                    "NeRF-T needs the time of every ray".into(),
                ));
            }
            (false, Some(_)) => {
                return Err(PhysNerfError::Invalid(
                    "a NeRF without a time input was given times".into(),
                ));
            }
            (false, None) => {}
        }
        let origins: Vec<[f32; 3]> = rays.origins.iter().map(|v| v.map(|c| c as f32)).collect();
        let dirs: Vec<[f32; 3]> = rays.dirs.iter().map(|v| v.map(|c| c as f32)).collect();
        render_hierarchical(
            &self.config.depth_plan(),
            rays.len(),
            rng,
            None,
            |which, z: &[f32], s, timings| {
                let net = match which {
                    Pass::Coarse => &self.coarse,
                    Pass::Fine => &self.fine,
                };
                self.run_pass(net, &origins, &dirs, times, z, s, timings)
            },
        )
    }

    /// Renders every pixel of `camera` (at `time` for NeRF-T), deterministically and without
    /// gradients, `config.chunk` rays at a time.
    pub fn render_image(&self, camera: &Camera, time: Option<f64>) -> Result<RenderedImage> {
        let model = self.valid();
        render_image_with(camera, self.config.chunk, &mut |_, _| {}, &mut |rays| {
            let times = time.map(|t| vec![t; rays.len()]);
            model.render_rays(rays, times.as_deref(), None)
        })
    }

    /// Density σ ≥ 0 (after the activation) of the fine network at `points`, at time `time`
    /// for NeRF-T; evaluated in chunks of `config.chunk · 64` points without gradients.
    pub fn density_at(&self, points: &[[f64; 3]], time: Option<f64>) -> Result<Vec<f32>> {
        if self.config.time != time.is_some() {
            return Err(PhysNerfError::Invalid(
                "a time is needed exactly for NeRF-T".into(),
            ));
        }
        let model = self.valid();
        let device = model.device();
        let mut out = Vec::with_capacity(points.len());
        for chunk in points.chunks((self.config.chunk * 64).max(1)) {
            let q = chunk.len();
            let flat: Vec<f32> = chunk.iter().flat_map(|p| p.map(|c| c as f32)).collect();
            let inside = model.inside_bounds(&flat, &device);
            let x = host_tensor(flat, [q, 3], &device);
            let e_x = model.position_input(x, time.map(|t| vec![t as f32; q]), &device);
            // density does not depend on the direction: any unit vector will do
            let d = host_tensor([0.0f32, 0.0, 1.0].repeat(q), [q, 3], &device);
            let (_, sigma) = model.fine.forward(e_x, posenc(d, self.config.freq_d));
            let sigma = self.config.density.before_mask(sigma);
            let sigma = match inside {
                Some(m) => sigma * m,
                None => sigma,
            };
            out.extend(read::<f32, 2>(relu(sigma))?);
        }
        Ok(out)
    }

    /// `[Q, 1]` ones inside `config.bounds` and zeros outside (`None` without bounds); `x` is
    /// `[Q·3]` flat.
    fn inside_bounds(&self, x: &[f32], device: &Device) -> Option<Tensor<2>> {
        let (lo, hi) = self.config.bounds?;
        let m: Vec<f32> = x
            .chunks_exact(3)
            .map(|p| {
                let inside = (0..3).all(|a| f64::from(p[a]) >= lo[a] && f64::from(p[a]) <= hi[a]);
                if inside { 1.0 } else { 0.0 }
            })
            .collect();
        let q = m.len();
        Some(host_tensor(m, [q, 1], device))
    }

    fn position_input(&self, x: Tensor<2>, times: Option<Vec<f32>>, device: &Device) -> Tensor<2> {
        let q = x.dims()[0];
        let mut inputs = vec![(x, self.config.freq_x)];
        if let Some(t) = times {
            inputs.push((host_tensor(t, [q, 1], device), self.config.freq_t));
        }
        posenc_cat(inputs)
    }

    #[allow(clippy::too_many_arguments)]
    fn run_pass(
        &self,
        net: &NerfMlp,
        origins: &[[f32; 3]],
        dirs: &[[f32; 3]],
        times: Option<&[f64]>,
        z: &[f32],
        s: usize,
        timings: &mut Timings,
    ) -> Result<PassOutput> {
        let device = self.device();
        let r = dirs.len();
        let q = r * s;
        let t1 = std::time::Instant::now();
        let mut x = Vec::with_capacity(q * 3);
        let mut d = Vec::with_capacity(q * 3);
        for ray in 0..r {
            let (o, dr) = (origins[ray], dirs[ray]);
            for &zi in &z[ray * s..(ray + 1) * s] {
                x.extend([o[0] + dr[0] * zi, o[1] + dr[1] * zi, o[2] + dr[2] * zi]);
                d.extend(dr);
            }
        }
        let t_samples = times.map(|t| {
            t.iter()
                .flat_map(|&ti| std::iter::repeat_n(ti as f32, s))
                .collect()
        });
        let inside = self.inside_bounds(&x, &device);
        let e_x = self.position_input(host_tensor(x, [q, 3], &device), t_samples, &device);
        let e_d = posenc(host_tensor(d, [q, 3], &device), self.config.freq_d);
        timings.encoding += t1.elapsed();
        let t2 = std::time::Instant::now();
        let (rgb, sigma) = net.forward(e_x, e_d);
        let sigma = self.config.density.before_mask(sigma);
        let sigma = match inside {
            Some(m) => sigma * m,
            None => sigma,
        };
        timings.mlp += t2.elapsed();
        let t3 = std::time::Instant::now();
        let dl = host_tensor(deltas(z, s, dirs), [r, s], &device);
        let comp = volume_render(
            rgb.reshape([r, s, 3]),
            sigma.reshape([r, s]),
            dl,
            self.config.white_background,
        );
        timings.composite += t3.elapsed();
        Ok(PassOutput {
            samples: s,
            z: z.iter().map(|v| v.f64()).collect(),
            rgb_map: comp.rgb_map,
            weights: comp.weights,
            alpha: comp.alpha,
            acc: comp.acc,
            num_nn: Vec::new(),
            mask: Vec::new(),
            nbr_idx_sum: Vec::new(),
            evaluated: q,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounds_leave_no_density_outside_the_box_and_change_nothing_inside() {
        let device = Device::flex();
        device.seed(1);
        let free = Nerf::new(
            NerfConfig {
                width: 16,
                depth: 3,
                skip: 1,
                ..NerfConfig::default()
            },
            &device,
        )
        .unwrap();
        let boxed = Nerf {
            config: NerfConfig {
                bounds: Some(([-0.5; 3], [0.5; 3])),
                ..free.config.clone()
            },
            ..free.clone()
        };
        let inside = [[0.1, -0.2, 0.3], [0.49, 0.0, -0.49]];
        let outside = [[0.6, 0.0, 0.0], [0.0, -0.51, 0.0], [2.0, 2.0, 2.0]];
        assert_eq!(
            boxed.density_at(&inside, None).unwrap(),
            free.density_at(&inside, None).unwrap()
        );
        assert_eq!(boxed.density_at(&outside, None).unwrap(), vec![0.0; 3]);
    }

    /// A small NeRF in a box, its density heads' raw output −2 everywhere (weights zero): the
    /// start a ReLU density cannot leave.
    fn dead_start(density: DensityActivation, device: &Device) -> Nerf {
        device.seed(2);
        let mut nerf = Nerf::new(
            NerfConfig {
                width: 16,
                depth: 3,
                skip: 1,
                n_samples: 8,
                n_importance: 8,
                stratified: false,
                near: 1.0,
                far: 3.0,
                bounds: Some(([-0.5; 3], [0.5; 3])),
                density,
                ..NerfConfig::default()
            },
            device,
        )
        .unwrap();
        for net in [&mut nerf.coarse, &mut nerf.fine] {
            let w = net.sigma.weight.val();
            net.sigma.weight = burn::module::Param::from_tensor(w.zeros_like());
            let b = net.sigma.bias.take().unwrap().val();
            net.sigma.bias = Some(burn::module::Param::from_tensor(
                b.zeros_like().sub_scalar(2.0),
            ));
        }
        nerf
    }

    /// The gradient of a render's loss reaching the fine density head's bias.
    fn density_gradient(nerf: &Nerf) -> f32 {
        let rays = RayBatch {
            origins: vec![[0.0, 0.0, 2.0]; 3],
            dirs: vec![[0.0, 0.0, -1.0], [0.1, 0.0, -0.995], [0.0, -0.1, -0.995]],
        };
        let out = nerf.render_rays(&rays, None, None).unwrap();
        let target = Tensor::<2>::zeros([3, 3], &nerf.device());
        let grads = out.loss(target).total.backward();
        let g = nerf
            .fine
            .sigma
            .bias
            .as_ref()
            .unwrap()
            .val()
            .grad(&grads)
            .unwrap();
        g.into_data().try_to_vec::<f32>().unwrap()[0]
    }

    #[test]
    fn a_softplus_density_cannot_start_dead_where_a_relu_one_does() {
        let device = Device::flex().autodiff();
        let inside = [[0.1, -0.2, 0.3], [0.0, 0.0, 0.0], [-0.4, 0.4, 0.2]];
        let relu = dead_start(DensityActivation::Relu, &device);
        assert_eq!(relu.density_at(&inside, None).unwrap(), vec![0.0; 3]);
        assert_eq!(
            density_gradient(&relu),
            0.0,
            "a dead ReLU start gets no gradient"
        );
        let soft = dead_start(DensityActivation::Softplus, &device);
        let sigma = soft.density_at(&inside, None).unwrap();
        let expected = (1.0f32 + (-3.0f32).exp()).ln();
        for s in sigma {
            assert!(
                (s - expected).abs() < 1e-6,
                "softplus(−2 − 1) = {expected}, got {s}"
            );
        }
        assert!(
            density_gradient(&soft).abs() > 1e-6,
            "softplus passes a gradient to the density"
        );
        // outside the box: nothing, so the background shows
        assert_eq!(
            soft.density_at(&[[2.0, 0.0, 0.0]], None).unwrap(),
            vec![0.0]
        );
    }

    #[test]
    fn a_softplus_density_without_box_bounds_is_refused() {
        let e = Nerf::new(
            NerfConfig {
                density: DensityActivation::Softplus,
                ..NerfConfig::default()
            },
            &Device::flex(),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("softplus density needs box bounds"), "{e}");
    }
}
