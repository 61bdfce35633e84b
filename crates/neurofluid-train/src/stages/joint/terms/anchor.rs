//! The anchor (`[joint.terms.anchor]`): each grounded step held near the pretrained DLF's step
//! from the same state.
//!
//! One view cannot tell where along its rays the fluid is, nor see where it is not: the image
//! loss leaves DLF free to move mass there, and a grounded DLF does (the spray of the test bed:
//! dense fluid where the truth has none; docs/notebook/benchmarks-history.md, "Issue 34: the
//! spray"). The anchor keeps each step near the pretrained physics wherever the images do not ask
//! for a change: a trust region on DLF's step,
//!
//! L = w · (1/N) Σ_i |x′_i − x̂′_i|² / r²,
//!
//! with x̂′ the pretrained DLF's step from the same (detached) state, a constant, and r the
//! particle radius. Where `[joint.physics]` fits the physical scalars, x̂′ steps with the values
//! the grounded step used: the anchor holds DLF's weights near the pretrained ones and leaves the
//! scalars to the images (anchored to the rules' constants, it pulled a fitted gravity scale
//! back toward them).

use burn::prelude::*;
use neurofluid_core::tensors::sum_all;
use neurofluid_dlf::DlfNet;
use serde::{Deserialize, Serialize};

use super::{ParticleTerm, TermContext, TermSettings, Transition, weight_problem};

/// `[joint.terms.anchor]`: each grounded DLF step held near the pretrained DLF's step from the
/// same state (a trust region: `w · mean |x′ − x̂′|² / r²`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnchorSettings {
    /// w, per particle radius² of mean squared distance (the quick configs: 0.1).
    pub weight: f64,
}

impl TermSettings for AnchorSettings {
    fn build(&self, ctx: &TermContext) -> anyhow::Result<Option<Box<dyn ParticleTerm>>> {
        Ok((self.weight > 0.0).then(|| {
            Box::new(Anchor {
                pretrained: ctx.pretrained.clone().no_grad(),
                radius: ctx.radius,
                weight: self.weight,
            }) as Box<dyn ParticleTerm>
        }))
    }

    fn problem(&self) -> Option<(&'static str, String)> {
        weight_problem(self.weight)
    }
}

/// The anchor term with its frozen copy of the pretrained DLF.
pub struct Anchor {
    pretrained: DlfNet,
    radius: f32,
    weight: f64,
}

impl ParticleTerm for Anchor {
    fn name(&self) -> &'static str {
        "anchor"
    }

    fn loss(&self, step: &Transition) -> Tensor<1> {
        let (x, v) = (
            step.before.0.clone().detach(),
            step.before.1.clone().detach(),
        );
        // the pretrained weights with the scalars the step used: the anchor holds the weights,
        // and leaves the physical scalars to the images
        let target = match step.physics {
            Some(values) => {
                let pretrained = self.pretrained.clone().with_physics(Some(values.clone()));
                pretrained.step(x, v, step.walls)
            }
            None => self.pretrained.step(x, v, step.walls),
        };
        let target = target.pos.detach();
        mean_square_distance(step.after.0.clone(), target, self.radius).mul_scalar(self.weight)
    }
}

/// The mean over particles of the squared distance between `pred` and `target` (`[N, 3]` each),
/// in particle radii² (`radius`).
pub fn mean_square_distance(pred: Tensor<2>, target: Tensor<2>, radius: f32) -> Tensor<1> {
    let n = pred.dims()[0].max(1) as f64;
    let r2 = f64::from(radius) * f64::from(radius);
    sum_all((pred - target).powi_scalar(2)).mul_scalar(1.0 / (n * r2))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stages::views::{points_tensor, scalar, tensor_points};

    fn rows(v: &[[f32; 3]]) -> Tensor<2> {
        points_tensor(v, &neurofluid_core::device::cpu().autodiff())
    }

    /// One particle of two moved by one radius: half a radius² on average; its gradient is the
    /// derivative of the definition by hand, 2 (x − x̂) / (N r²).
    #[test]
    fn the_distance_is_in_radii_and_its_gradient_the_definitions() {
        let target = [[0.0, 0.0, -2.0], [0.0, 0.0, -3.0]];
        let moved = [[0.0, 0.5, -2.0], [0.0, 0.0, -3.0]];
        let pred = rows(&moved).require_grad();
        let loss = mean_square_distance(pred.clone(), rows(&target), 0.5);
        assert!((scalar(&loss) - 0.5).abs() < 1e-6, "{}", scalar(&loss));
        let g = tensor_points(&pred.grad(&loss.backward()).unwrap());
        // 2 · 0.5 / (2 · 0.25) = 2 along y for the moved particle, nothing else
        assert!((g[0][1] - 2.0).abs() < 1e-5, "{g:?}");
        assert!(g[0][0].abs() + g[0][2].abs() + g[1].iter().map(|c| c.abs()).sum::<f32>() < 1e-6);
    }
}
