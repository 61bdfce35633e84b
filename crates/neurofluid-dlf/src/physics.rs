//! The physical scalars of a step as tensors, so that an optimiser can fit them: the pre-step's
//! gravity scale, the XSPH viscosity's strength and a dissipation (the share of each particle's
//! velocity a step takes away). A DLF without values ([`crate::DlfNet::physics`] `None`) steps
//! with the constants of its rules ([`crate::StepRules`]: `gravity_scale`, `viscosity`,
//! `dissipation`), bit for bit as before; one given values ([`crate::DlfNet::with_physics`])
//! steps with those, and gradients reach them. A fitted value goes back into the rules for every
//! later rollout ([`PhysicsValues::into_rules`]).

use burn::prelude::*;

use crate::rules::StepRules;

/// The three scalars, each a tensor of shape `[1]`.
#[derive(Debug, Clone)]
pub struct PhysicsValues {
    /// Scale of the pre-step's gravity (`dlf.gravity_scale`).
    pub gravity_scale: Tensor<1>,
    /// Strength of the XSPH viscosity, in [0, 1] (`dlf.viscosity`).
    pub viscosity: Tensor<1>,
    /// Share of each particle's velocity a step takes away, in [0, 1) (`dlf.dissipation`).
    pub dissipation: Tensor<1>,
}

/// The names of the scalars, in the order [`PhysicsValues::to_array`] gives them.
pub const PHYSICS_NAMES: [&str; 3] = ["gravity_scale", "viscosity", "dissipation"];

impl PhysicsValues {
    /// The rules' constants as tensors on `device`.
    pub fn of_rules(rules: &StepRules, device: &Device) -> Self {
        let [gravity_scale, viscosity, dissipation] = values_of(rules).map(|v| -> Tensor<1> {
            neurofluid_core::transfer::upload(TensorData::new(vec![v as f32], [1]), device)
        });
        Self {
            gravity_scale,
            viscosity,
            dissipation,
        }
    }

    /// The same values, out of the graph (gradients stop here).
    pub fn detached(&self) -> Self {
        Self {
            gravity_scale: self.gravity_scale.clone().detach(),
            viscosity: self.viscosity.clone().detach(),
            dissipation: self.dissipation.clone().detach(),
        }
    }

    /// The values, in the order of [`PHYSICS_NAMES`].
    pub fn to_array(&self) -> [f64; 3] {
        let value = |t: &Tensor<1>| neurofluid_core::transfer::read_scalar(t.clone());
        [
            value(&self.gravity_scale),
            value(&self.viscosity),
            value(&self.dissipation),
        ]
    }

    /// `rules` with these values in place of its constants.
    pub fn into_rules(&self, rules: StepRules) -> StepRules {
        rules_with(rules, self.to_array())
    }
}

/// The gravity scale, viscosity and dissipation of `rules`, in the order of [`PHYSICS_NAMES`].
pub fn values_of(rules: &StepRules) -> [f64; 3] {
    [rules.gravity_scale, rules.viscosity, rules.dissipation]
}

/// `rules` with `values` (in the order of [`PHYSICS_NAMES`]) in place of its gravity scale,
/// viscosity and dissipation.
pub fn rules_with(rules: StepRules, values: [f64; 3]) -> StepRules {
    let [gravity_scale, viscosity, dissipation] = values;
    StepRules {
        gravity_scale,
        viscosity,
        dissipation,
        ..rules
    }
}
