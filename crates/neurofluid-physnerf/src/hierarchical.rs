//! The hierarchical sampling every renderer here shares (NeRF's): coarse depths (optionally
//! jittered), a coarse pass, importance depths drawn from its weights, and a fine pass on the
//! merged, sorted depths. What a pass does at its samples is the caller's. [`CoarseFine`] is the
//! pair of networks every such renderer holds, with its constants ([`CoarseFineConfig`]).

use std::time::Instant;

use burn::prelude::*;
use burn::tensor::DType;
use rand::RngCore;

use crate::error::{PhysNerfError, Result};
use crate::mlp::{MlpShape, NerfMlp};
use crate::real::Real;
use crate::renderer::{PassOutput, RenderOutput, Timings};
use crate::sampling::{coarse_depths, fine_u, jitter_depths, merge_sorted, midpoints, sample_pdf};

/// The constants of a hierarchical renderer as its networks see them: their shape, and whether
/// the values hold together.
pub trait CoarseFineConfig: Clone + std::fmt::Debug + Send + Sync + 'static {
    /// `Err("field: what was expected")` for the first invalid value.
    fn check(&self) -> std::result::Result<(), String>;
    /// The shape of the coarse and of the fine network.
    fn shape(&self) -> MlpShape;
}

/// A hierarchical renderer: the coarse and the fine network and the constants `C` that say how
/// they render (PhysNeRF's, [`crate::PhysNerf`], or NeRF's, [`crate::Nerf`]).
#[derive(Module, Debug)]
pub struct CoarseFine<C: CoarseFineConfig> {
    /// The coarse network (the coarse depths).
    pub coarse: NerfMlp,
    /// The fine network (the coarse and the importance depths, merged).
    pub fine: NerfMlp,
    /// Constants and switches.
    #[module(skip)]
    pub config: C,
}

impl<C: CoarseFineConfig> CoarseFine<C> {
    /// Randomly initialised networks (f32) on `device`, the coarse one's weights drawn first.
    pub fn new(config: C, device: &Device) -> Result<Self> {
        config.check().map_err(PhysNerfError::Invalid)?;
        let coarse = NerfMlp::new(&config.shape(), device);
        let fine = NerfMlp::new(&config.shape(), device);
        Ok(Self {
            coarse,
            fine,
            config,
        })
    }

    /// The device of the weights.
    pub fn device(&self) -> Device {
        self.coarse.sigma.weight.val().device()
    }

    /// The float dtype of the weights.
    pub fn dtype(&self) -> DType {
        self.coarse.sigma.weight.val().dtype()
    }
}

/// Which network a pass runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pass {
    /// The coarse network on the coarse depths.
    Coarse,
    /// The fine network on the coarse and importance depths.
    Fine,
}

/// The depths of a ray: the segment and the sample counts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthPlan {
    /// Near bound of the segment.
    pub near: f64,
    /// Far bound of the segment.
    pub far: f64,
    /// Coarse samples per ray.
    pub n_samples: usize,
    /// Importance samples per ray (0: coarse only).
    pub n_importance: usize,
}

impl DepthPlan {
    /// The first field with an invalid value, and what was expected.
    pub fn problem(&self) -> Option<(&'static str, String)> {
        let (near, far) = (self.near, self.far);
        if !(near.is_finite() && far.is_finite() && near >= 0.0) {
            return Some((
                "near",
                format!("expected finite bounds ≥ 0, got {near}/{far}"),
            ));
        }
        if far <= near {
            return Some(("far", format!("expected far > near, got {near}/{far}")));
        }
        if self.n_samples < 3 {
            return Some((
                "n_samples",
                format!("expected at least 3, got {}", self.n_samples),
            ));
        }
        None
    }
}

pub(crate) fn read<T: Real, const D: usize>(t: Tensor<D>) -> Result<Vec<T>> {
    neurofluid_core::transfer::read_vec(t).map_err(|e| PhysNerfError::Readback(format!("{e:?}")))
}

/// Renders `rays` rays: `pass(which, z, s, timings)` evaluates and composites one pass on the
/// sorted depths `z [R·S]` (S per ray). With `rng` the coarse depths are jittered and the fine
/// u drawn at random; `fixed_fine` replaces the fine depths.
pub fn render_hierarchical<T: Real>(
    plan: &DepthPlan,
    rays: usize,
    mut rng: Option<&mut dyn RngCore>,
    fixed_fine: Option<&[f64]>,
    mut pass: impl FnMut(Pass, &[T], usize, &mut Timings) -> Result<PassOutput>,
) -> Result<RenderOutput> {
    let mut timings = Timings::default();
    let s = plan.n_samples;
    let z0: Vec<T> = coarse_depths(plan.near, plan.far, s);
    let mut z_c = Vec::with_capacity(rays * s);
    for _ in 0..rays {
        match rng.as_deref_mut() {
            Some(g) => z_c.extend(jitter_depths(&z0, g)),
            None => z_c.extend_from_slice(&z0),
        }
    }
    let coarse = pass(Pass::Coarse, &z_c, s, &mut timings)?;
    let mut z_importance = Vec::new();
    let fine = if plan.n_importance > 0 && rays > 0 {
        let t0 = Instant::now();
        let n = plan.n_importance;
        let w: Vec<T> = read(coarse.weights.clone().detach())?;
        let mut z_f = Vec::with_capacity(rays * (s + n));
        let u_det: Vec<T> = fine_u(n, None);
        for ray in 0..rays {
            let zr = &z_c[ray * s..(ray + 1) * s];
            let u = match rng.as_deref_mut() {
                Some(g) => fine_u(n, Some(g)),
                None => u_det.clone(),
            };
            let zi = sample_pdf(&midpoints(zr), &w[ray * s + 1..(ray + 1) * s - 1], &u);
            z_importance.extend(zi.iter().map(|v| v.f64()));
            z_f.extend(merge_sorted(zr, &zi));
        }
        if let Some(fixed) = fixed_fine {
            z_f = fixed.iter().map(|&v| T::of(v)).collect();
        }
        timings.composite += t0.elapsed();
        Some(pass(Pass::Fine, &z_f, s + n, &mut timings)?)
    } else {
        None
    };
    Ok(RenderOutput {
        coarse,
        fine,
        z_importance,
        timings,
    })
}
