//! The truth (`[joint.terms.truth]`): each step's predicted positions held to the true ones of
//! the same frame, matched by particle index, in particle radii².
//!
//! A reference, never a method: the images are all NeuroFluid may see. With it, grounding at the
//! same budget and rules is given every particle's truth, a reference for what the images could
//! teach DLF. It needs the scene's true particles of every training frame, the predicted
//! particles (not initial particles from images).

use anyhow::Context;
use burn::prelude::*;
use serde::{Deserialize, Serialize};

use super::anchor::mean_square_distance;
use super::{ParticleTerm, TermContext, TermSettings, Transition, weight_problem};
use neurofluid_core::tensors::points_tensor;

/// `[joint.terms.truth]`: each step's prediction held to the true particles of its frame
/// (a reference given the truth, never a method).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TruthSettings {
    /// w, per particle radius² of mean squared distance to the truth.
    pub weight: f64,
}

impl TermSettings for TruthSettings {
    fn build(&self, ctx: &TermContext) -> anyhow::Result<Option<Box<dyn ParticleTerm>>> {
        if self.weight <= 0.0 {
            return Ok(None);
        }
        let truth = ctx.truth.with_context(|| {
            "joint.terms.truth needs the scene's true particles of every training frame; this \
             scene has none"
        })?;
        anyhow::ensure!(
            truth.len() as u64 > ctx.transitions && truth[0].len() == ctx.particles,
            "joint.terms.truth needs the true particles of every training frame matched to the \
             predicted ones by index: the truth has {} frames of {} particles, the joint stage {} \
             transitions from {} particles",
            truth.len(),
            truth.first().map_or(0, Vec::len),
            ctx.transitions,
            ctx.particles
        );
        let device = ctx.pretrained.device();
        Ok(Some(Box::new(Truth {
            frames: truth.iter().map(|p| points_tensor(p, &device)).collect(),
            radius: ctx.radius,
            weight: self.weight,
        })))
    }

    fn problem(&self) -> Option<(&'static str, String)> {
        weight_problem(self.weight)
    }
}

/// The truth term with every training frame's true particles on the device.
pub struct Truth {
    frames: Vec<Tensor<2>>,
    radius: f32,
    weight: f64,
}

impl ParticleTerm for Truth {
    fn name(&self) -> &'static str {
        "truth"
    }

    fn loss(&self, step: &Transition) -> Tensor<1> {
        let target = self.frames[step.frame].clone();
        mean_square_distance(step.after.0.clone(), target, self.radius).mul_scalar(self.weight)
    }
}
