//! The PhysNeRF renderer: coarse pass, importance sampling, fine pass, loss.

use std::time::{Duration, Instant};

use burn::prelude::*;
use burn::tensor::DType;
use rand::RngCore;

use crate::config::PhysNerfConfig;
use crate::error::{PhysNerfError, Result};
use crate::hierarchical::{CoarseFine, CoarseFineConfig, Pass, read, render_hierarchical};
use crate::mlp::NerfMlp;
use crate::pass;
use crate::real::Real;

/// The renderer R_φ: two NeRF networks and the configuration.
pub type PhysNerf = CoarseFine<PhysNerfConfig>;

impl CoarseFineConfig for PhysNerfConfig {
    fn check(&self) -> std::result::Result<(), String> {
        self.validate()
    }
    fn shape(&self) -> crate::mlp::MlpShape {
        self.mlp_shape()
    }
}

/// A batch of rays in world units. Kept in f64 on the host; the renderer rounds them to the
/// precision of the particle tensor (exact for rays that came from f32).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RayBatch {
    /// Ray origins (the camera centre; also used for d_c).
    pub origins: Vec<[f64; 3]>,
    /// Unit ray directions.
    pub dirs: Vec<[f64; 3]>,
}

impl RayBatch {
    /// Number of rays.
    pub fn len(&self) -> usize {
        self.dirs.len()
    }

    /// True when there are no rays.
    pub fn is_empty(&self) -> bool {
        self.dirs.is_empty()
    }

    /// The rays `start..end`.
    pub fn slice(&self, start: usize, end: usize) -> Self {
        Self {
            origins: self.origins[start..end].to_vec(),
            dirs: self.dirs[start..end].to_vec(),
        }
    }
}

impl From<&neurofluid_core::camera::Rays> for RayBatch {
    fn from(r: &neurofluid_core::camera::Rays) -> Self {
        Self {
            origins: r.origins.iter().map(|v| v.map(f64::from)).collect(),
            dirs: r.dirs.iter().map(|v| v.map(f64::from)).collect(),
        }
    }
}

/// What one pass (coarse or fine) produced.
#[derive(Debug, Clone)]
pub struct PassOutput {
    /// Samples per ray S.
    pub samples: usize,
    /// `[R·S]` sorted depths of every ray (host, f64).
    pub z: Vec<f64>,
    /// `[R, 3]` colours on the background.
    pub rgb_map: Tensor<2>,
    /// `[R, S]` compositing weights.
    pub weights: Tensor<2>,
    /// `[R, S]` opacities.
    pub alpha: Tensor<2>,
    /// `[R, 1]` accumulated opacity.
    pub acc: Tensor<2>,
    /// `[R·S]` filled neighbour slots (0…K).
    pub num_nn: Vec<u8>,
    /// `[R·S]` occupancy gate (all K slots filled).
    pub mask: Vec<bool>,
    /// `[R·S]` sum of the neighbour indices (empty slots count 0).
    pub nbr_idx_sum: Vec<u32>,
    /// Samples that went through the MLP.
    pub evaluated: usize,
}

/// Wall-clock time of the forward stages (host-synchronous CPU backends).
#[derive(Debug, Clone, Copy, Default)]
pub struct Timings {
    /// Sample positions and ball queries (host).
    pub neighbors: Duration,
    /// Gather, features and encodings (tensor ops).
    pub encoding: Duration,
    /// MLP forward passes.
    pub mlp: Duration,
    /// Scatter of the gated samples, compositing and importance sampling.
    pub composite: Duration,
}

/// Output of [`PhysNerf::render_rays`].
#[derive(Debug, Clone)]
pub struct RenderOutput {
    /// The coarse pass.
    pub coarse: PassOutput,
    /// The fine pass (absent when `n_importance == 0`).
    pub fine: Option<PassOutput>,
    /// `[R·n_importance]` importance depths in u order (unsorted), host f64.
    pub z_importance: Vec<f64>,
    /// Stage timings of this call.
    pub timings: Timings,
}

impl RenderOutput {
    /// The fine colours when there is a fine pass, else the coarse ones (`[R, 3]`).
    pub fn final_rgb(&self) -> Tensor<2> {
        self.fine.as_ref().unwrap_or(&self.coarse).rgb_map.clone()
    }

    /// The MSE loss against `target [R, 3]` (the same rays, same order).
    pub fn loss(&self, target: Tensor<2>) -> Loss {
        let coarse = mse(self.coarse.rgb_map.clone(), target.clone());
        let fine = match &self.fine {
            Some(f) => mse(f.rgb_map.clone(), target),
            None => coarse.zeros_like(),
        };
        Loss {
            total: coarse.clone() + fine.clone(),
            coarse,
            fine,
        }
    }
}

/// The image loss: `MSE(coarse) + MSE(fine)` (means over rays × 3).
#[derive(Debug, Clone)]
pub struct Loss {
    /// coarse + fine (scalar tensor `[1]`).
    pub total: Tensor<1>,
    /// MSE of the coarse colours.
    pub coarse: Tensor<1>,
    /// MSE of the fine colours (0 without a fine pass).
    pub fine: Tensor<1>,
}

/// `mean((rgb − target)²)` over all entries.
pub fn mse(rgb: Tensor<2>, target: Tensor<2>) -> Tensor<1> {
    let d = rgb - target;
    neurofluid_core::tensors::mean_all(d.clone() * d)
}

impl PhysNerf {
    /// The MSE loss of a render against `target [R, 3]` (the same rays, same order).
    pub fn loss(&self, out: &RenderOutput, target: Tensor<2>) -> Loss {
        out.loss(target)
    }

    /// Renders a batch of rays through `particles [N, 3]` (same device and dtype as the
    /// weights; put it on an autodiff device with `require_grad` to get d loss / d positions).
    ///
    /// Deterministic unless `config.stratified` is set, in which case `rng` must be given.
    /// The neighbour indices, the gate and the fine depths are constants of the graph.
    pub fn render_rays(
        &self,
        particles: &Tensor<2>,
        rays: &RayBatch,
        rng: Option<&mut dyn RngCore>,
    ) -> Result<RenderOutput> {
        let rng = self.jitter(rng)?;
        self.dispatch(particles, None, rays, rng, None)
    }

    /// The RNG a render uses: the given one with `config.stratified` (which needs one), else
    /// none.
    fn jitter<'a>(&self, rng: Option<&'a mut dyn RngCore>) -> Result<Option<&'a mut dyn RngCore>> {
        if !self.config.stratified {
            return Ok(None);
        }
        match rng {
            Some(rng) => Ok(Some(rng)),
            None => Err(PhysNerfError::Invalid(
                "config.stratified needs an RNG".into(),
            )),
        }
    }

    /// [`PhysNerf::render_rays`] given also the particles' values on the host (`host`, equal to
    /// `particles`, which must be f32): the neighbour search takes them (on the host, or uploaded
    /// to the GPU's kernel with `neighbour_search = "device"`), and a caller that already holds
    /// the positions spares the renderer reading them back from the device (a stall of a GPU's
    /// queue).
    pub fn render_rays_with_host(
        &self,
        particles: &Tensor<2>,
        host: &[[f32; 3]],
        rays: &RayBatch,
        rng: Option<&mut dyn RngCore>,
    ) -> Result<RenderOutput> {
        let rng = self.jitter(rng)?;
        if particles.dtype() != DType::F32 || host.len() != particles.dims()[0] {
            return Err(PhysNerfError::Invalid(format!(
                "host particles: {} given for a {:?} tensor of {:?}; they must be the f32 \
                 tensor's values",
                host.len(),
                particles.dtype(),
                particles.dims()
            )));
        }
        self.dispatch(particles, Some(host), rays, rng, None)
    }

    /// Like [`PhysNerf::render_rays`] (deterministic), but the fine pass runs on the given sorted
    /// depths `[R·(n_samples + n_importance)]` instead of sampling them: finite-difference checks
    /// hold the (detached) fine depths fixed this way.
    pub fn render_rays_fixed_fine(
        &self,
        particles: &Tensor<2>,
        rays: &RayBatch,
        fine_z: &[f64],
    ) -> Result<RenderOutput> {
        let per_ray = self.config.n_samples + self.config.n_importance;
        if self.config.n_importance == 0 || fine_z.len() != rays.len() * per_ray {
            return Err(PhysNerfError::Invalid(format!(
                "fixed fine depths: need {} values ({} rays × {per_ray}) and n_importance > 0, got {}",
                rays.len() * per_ray,
                rays.len(),
                fine_z.len()
            )));
        }
        self.dispatch(particles, None, rays, None, Some(fine_z))
    }

    fn dispatch(
        &self,
        particles: &Tensor<2>,
        host: Option<&[[f32; 3]]>,
        rays: &RayBatch,
        rng: Option<&mut dyn RngCore>,
        fine_z: Option<&[f64]>,
    ) -> Result<RenderOutput> {
        if rays.origins.len() != rays.dirs.len() {
            return Err(PhysNerfError::Invalid(format!(
                "ray batch has {} origins but {} directions",
                rays.origins.len(),
                rays.dirs.len()
            )));
        }
        if particles.dims()[1] != 3 {
            return Err(PhysNerfError::Invalid(format!(
                "particles must be [N, 3], got {:?}",
                particles.dims()
            )));
        }
        if particles.dtype() != self.dtype() {
            return Err(PhysNerfError::Invalid(format!(
                "particles are {:?} but the weights are {:?}",
                particles.dtype(),
                self.dtype()
            )));
        }
        match particles.dtype() {
            DType::F32 => self.render_impl::<f32>(particles, host, rays, rng, fine_z),
            DType::F64 => self.render_impl::<f64>(particles, None, rays, rng, fine_z),
            other => Err(PhysNerfError::Invalid(format!(
                "particles must be F32 or F64, got {other:?}"
            ))),
        }
    }

    fn render_impl<T: Real>(
        &self,
        particles: &Tensor<2>,
        host: Option<&[[f32; 3]]>,
        rays: &RayBatch,
        rng: Option<&mut dyn RngCore>,
        fixed_fine: Option<&[f64]>,
    ) -> Result<RenderOutput> {
        let p_host: Vec<[T; 3]> = match host {
            // exact: f32 values through f64 into T = f32
            Some(h) => h.iter().map(|p| p.map(|c| T::of(f64::from(c)))).collect(),
            None => {
                let flat: Vec<T> = read(particles.clone().detach())?;
                flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
            }
        };
        let origins: Vec<[T; 3]> = rays.origins.iter().map(|v| v.map(T::of)).collect();
        let dirs: Vec<[T; 3]> = rays.dirs.iter().map(|v| v.map(T::of)).collect();
        render_hierarchical(
            &self.config.depth_plan(),
            rays.len(),
            rng,
            fixed_fine,
            |which, z, s, timings| {
                let net = match which {
                    Pass::Coarse => &self.coarse,
                    Pass::Fine => &self.fine,
                };
                let rays = pass::Rays {
                    origins: &origins,
                    dirs: &dirs,
                    z,
                    s,
                };
                self.run_pass(net, particles, &p_host, &rays, timings)
            },
        )
    }

    /// One pass (coarse or fine) along `rays`, in the stages of [`crate::pass`]: neighbours →
    /// gate → features → field → composite.
    fn run_pass<T: Real>(
        &self,
        net: &NerfMlp,
        particles: &Tensor<2>,
        p_host: &[[T; 3]],
        rays: &pass::Rays<'_, T>,
        timings: &mut Timings,
    ) -> Result<PassOutput> {
        let cfg = &self.config;
        let t0 = Instant::now();
        let x = pass::sample_points(rays);
        let neighbours = pass::neighbours(p_host, &x, cfg, &particles.device())?;
        let gate = pass::Gate::of(neighbours, x.len(), cfg);
        timings.neighbors += t0.elapsed();
        let t1 = Instant::now();
        let inputs = pass::features(particles, rays, &x, &gate, cfg);
        timings.encoding += t1.elapsed();
        let t2 = Instant::now();
        let field = inputs.map(|(e_x, e_d)| pass::field(net, e_x, e_d, cfg));
        timings.mlp += t2.elapsed();
        let (rgb, sigma) = pass::place(field, &gate, &particles.device(), T::DTYPE, cfg);
        let t3 = Instant::now();
        let comp = pass::composite::<T>(rgb, sigma, rays, &particles.device(), cfg);
        timings.composite += t3.elapsed();
        Ok(PassOutput {
            samples: rays.s,
            z: rays.z.iter().map(|v| v.f64()).collect(),
            rgb_map: comp.rgb_map,
            weights: comp.weights,
            alpha: comp.alpha,
            acc: comp.acc,
            evaluated: gate.selected.len(),
            num_nn: gate.num_nn,
            mask: gate.mask,
            nbr_idx_sum: gate.nbr_idx_sum,
        })
    }
}
