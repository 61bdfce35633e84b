//! PhysNeRF, the particle-driven neural radiance field of NeuroFluid (ICML 2022), in Burn.
//!
//! The density and colour at a sample point come from the particles around it: a capped ball
//! query (r_s = 0.225, K = 20, lowest indices first) gives kernel weights, a fictitious centre
//! p_c, a density σ_p, a per-axis spread v_d and the camera→centre direction d_c; these are
//! positionally encoded and fed to nerf_pl's 8×256 MLPs (coarse and fine). Samples with fewer
//! than K neighbours are gated off. Gradients of the image loss reach the particle positions
//! through the gathered neighbour coordinates.
//!
//! ```no_run
//! use burn::prelude::*;
//! use neurofluid_physnerf::{PhysNerf, PhysNerfConfig, RayBatch};
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let device = Device::flex().autodiff();
//! let model = PhysNerf::new(PhysNerfConfig::default(), &device)?;
//! let particles = Tensor::<2>::zeros([100, 3], &device).require_grad();
//! let rays = RayBatch { origins: vec![[0.0, 0.0, 11.0]], dirs: vec![[0.0, 0.0, -1.0]] };
//! let out = model.render_rays(&particles, &rays, None)?;
//! let loss = model.loss(&out, Tensor::<2>::ones([1, 3], &device));
//! let grads = loss.total.backward();
//! let d_particles = particles.grad(&grads);
//! # Ok(()) }
//! ```

pub mod config;
pub mod encoding;
pub mod error;
pub mod features;
pub mod hierarchical;
pub mod mlp;
pub mod neighbors;
pub mod nerf;
pub mod pass;
pub mod real;
pub mod renderer;
pub mod safetensors_file;
pub mod sampling;
pub mod view;
pub mod volume;
pub mod weights;

pub use config::{
    DensityActivation, EncodingTerms, Frequencies, NeighborSelection, PhysNerfConfig, Positions,
};
pub use error::{PhysNerfError, Result};

pub use mlp::NerfMlp;
pub use nerf::{Nerf, NerfConfig};
pub use renderer::{Loss, PassOutput, PhysNerf, RayBatch, RenderOutput, Timings};
pub use view::{RenderedImage, render_image, render_image_with, save_png};
