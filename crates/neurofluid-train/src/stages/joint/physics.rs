//! The physical scalars the joint stage fits (`[joint.physics]`): DLF's gravity scale, XSPH
//! viscosity and dissipation as one parameter of three values, starting from the `[dlf]`
//! rules', updated by their own Adam from the images' loss (through every DLF step of the
//! window: [`neurofluid_dlf::physics`]) and kept within each one's bounds. The scalars not fitted
//! enter the step as the rules' constants (detached), so they receive no update.

use burn::module::{Module, Param};
use burn::prelude::*;
use neurofluid_core::transfer::{read_together, upload};
use neurofluid_dlf::{PhysicsValues, StepRules};

use crate::config::{PhysicalScalar, PhysicsFit};

/// The metrics columns of the three values, in the order of [`PhysicalScalar::ALL`].
pub const COLUMNS: [&str; 3] = [
    "physics/gravity_scale",
    "physics/viscosity",
    "physics/dissipation",
];

/// The three scalars as one trainable parameter `[3]`.
#[derive(Module, Debug)]
pub struct Physics {
    /// Gravity scale, viscosity, dissipation.
    pub values: Param<Tensor<1>>,
}

impl Physics {
    /// The rules' values on `device`.
    pub fn of_rules(rules: &StepRules, device: &Device) -> Self {
        let v = neurofluid_dlf::physics::values_of(rules).map(|x| x as f32);
        Self {
            values: Param::from_tensor(upload(TensorData::new(v.to_vec(), [3]), device)),
        }
    }

    /// The values for a step: the fitted ones in the graph, the others detached.
    pub fn step_values(&self, fit: &PhysicsFit) -> PhysicsValues {
        let all = self.values.val();
        let one = |scalar: PhysicalScalar| {
            let k = scalar.index();
            let v = all.clone().narrow(0, k, 1);
            if fit.fits(scalar) { v } else { v.detach() }
        };
        PhysicsValues {
            gravity_scale: one(PhysicalScalar::GravityScale),
            viscosity: one(PhysicalScalar::Viscosity),
            dissipation: one(PhysicalScalar::Dissipation),
        }
    }

    /// The values on the host, in the order of [`PhysicalScalar::ALL`].
    pub fn to_array(&self) -> [f64; 3] {
        let s = read_together(vec![self.values.val()]).unwrap_or_default();
        [0, 1, 2].map(|k| s.get(k).copied().unwrap_or(f64::NAN))
    }

    /// These values clamped into their bounds (after an update), and the values clamped (one
    /// read of the device).
    pub fn clamped(self) -> (Self, [f64; 3]) {
        let v = self.to_array();
        let clamped: Vec<f32> = PhysicalScalar::ALL
            .iter()
            .map(|s| {
                let (lo, hi) = s.bounds();
                v[s.index()].clamp(lo, hi) as f32
            })
            .collect();
        let read = [0, 1, 2].map(|k| f64::from(clamped[k]));
        if read == v {
            return (self, v);
        }
        let device = self.values.val().device();
        // the same parameter (its id keys its Adam state), its value clamped
        let mut values = Param::from_tensor(upload(TensorData::new(clamped, [3]), &device));
        values.id = self.values.id;
        (Self { values }, read)
    }

    /// `rules` with these values in place of its gravity scale, viscosity and dissipation.
    pub fn into_rules(&self, rules: StepRules) -> StepRules {
        neurofluid_dlf::physics::rules_with(rules, self.to_array())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Values outside the bounds are brought back to them; values inside are left.
    #[test]
    fn values_are_kept_within_their_bounds() {
        let device = neurofluid_core::device::cpu();
        let rules = StepRules {
            gravity_scale: 1.7,
            viscosity: 0.2,
            ..StepRules::default()
        };
        let p = Physics::of_rules(&rules, &device);
        let inside = p.clone().clamped().1;
        assert!((inside[0] - 1.7).abs() < 1e-6 && (inside[1] - 0.2).abs() < 1e-6);
        let wild = Physics {
            values: Param::from_tensor(upload(
                TensorData::new(vec![9.0f32, -0.5, 0.7], [3]),
                &device,
            )),
        };
        let (wild, values) = wild.clamped();
        assert_eq!(values, [4.0, 0.0, 0.5]);
        assert_eq!(wild.to_array(), values);
        let fit = PhysicsFit {
            fit: vec![PhysicalScalar::Viscosity],
            optim: Default::default(),
            hold_dlf_epochs: 0,
            search: None,
        };
        let back = p.into_rules(StepRules::default());
        assert!((back.gravity_scale - 1.7).abs() < 1e-6);
        let v = p.step_values(&fit).to_array();
        assert!((v[1] - 0.2).abs() < 1e-6, "{v:?}");
    }
}
