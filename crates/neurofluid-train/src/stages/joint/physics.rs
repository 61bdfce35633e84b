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

/// The metrics column of the epochs after which the fit was held (`[joint.physics] settle`).
pub const HELD_AFTER: &str = "physics/held_after_epoch";

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

    /// These values after an update: the fitted dampings shrunk toward 0 by `fit`'s `shrink`,
    /// then all clamped into their bounds; and the values (one read of the device).
    pub fn clamped(self, fit: &PhysicsFit) -> (Self, [f64; 3]) {
        let v = self.to_array();
        let shrunk = fit.shrunk(v);
        let clamped: Vec<f32> = PhysicalScalar::ALL
            .iter()
            .map(|s| {
                let (lo, hi) = s.bounds();
                shrunk[s.index()].clamp(lo, hi) as f32
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
        let fit = PhysicsFit {
            fit: vec![PhysicalScalar::Viscosity],
            optim: Default::default(),
            hold_dlf_epochs: 0,
            settle: None,
            shrink: None,
        };
        let inside = p.clone().clamped(&fit).1;
        assert!((inside[0] - 1.7).abs() < 1e-6 && (inside[1] - 0.2).abs() < 1e-6);
        let wild = Physics {
            values: Param::from_tensor(upload(
                TensorData::new(vec![9.0f32, -0.5, 0.7], [3]),
                &device,
            )),
        };
        let (wild, values) = wild.clamped(&fit);
        assert_eq!(values, [4.0, 0.0, 0.5]);
        assert_eq!(wild.to_array(), values);
        let back = p.into_rules(StepRules::default());
        assert!((back.gravity_scale - 1.7).abs() < 1e-6);
        let v = p.step_values(&fit).to_array();
        assert!((v[1] - 0.2).abs() < 1e-6, "{v:?}");
    }

    /// The fit has settled when every fitted scalar moved by at most the share of its range;
    /// the scalars not fitted do not count, and without `settle` it never settles.
    #[test]
    fn the_fit_settles_by_each_fitted_scalars_range() {
        let fit = |settle| PhysicsFit {
            fit: vec![PhysicalScalar::GravityScale, PhysicalScalar::Dissipation],
            optim: Default::default(),
            hold_dlf_epochs: 6,
            settle,
            shrink: None,
        };
        let before = [1.5, 0.3, 0.10];
        // 1 % of the ranges: gravity scale 0.0375, dissipation 0.005
        let one = fit(Some(0.01));
        assert!(one.has_settled(before, [1.53, 0.9, 0.104]));
        assert!(!one.has_settled(before, [1.54, 0.3, 0.10]));
        assert!(!one.has_settled(before, [1.5, 0.3, 0.094]));
        assert!(!fit(None).has_settled(before, before));
    }

    /// `shrink` moves each fitted damping toward 0 by its step and not past it, and leaves the
    /// gravity scale and a damping not fitted (a rule's constant) alone.
    #[test]
    fn the_fitted_dampings_shrink_toward_no_damping() {
        let fit = |fit: Vec<PhysicalScalar>, shrink| PhysicsFit {
            fit,
            optim: Default::default(),
            hold_dlf_epochs: 0,
            settle: None,
            shrink,
        };
        let all = PhysicalScalar::ALL.to_vec();
        let v = [1.5, 0.3, 0.004];
        let got = fit(all.clone(), Some(0.01)).shrunk(v);
        assert_eq!(got[0], 1.5);
        assert!((got[1] - 0.29).abs() < 1e-12, "{got:?}");
        assert_eq!(got[2].to_bits(), 0.0f64.to_bits());
        let below = fit(all.clone(), Some(0.01)).shrunk([1.0, -0.004, -0.3]);
        assert_eq!(below[1].to_bits(), 0.0f64.to_bits(), "{below:?}");
        assert!((below[2] + 0.29).abs() < 1e-12, "{below:?}");
        let no_viscosity = vec![PhysicalScalar::GravityScale, PhysicalScalar::Dissipation];
        assert_eq!(fit(no_viscosity, Some(0.01)).shrunk(v)[1], 0.3);
        assert_eq!(fit(all, None).shrunk(v), v);
        // after an update the module's values are shrunk, then clamped
        let device = neurofluid_core::device::cpu();
        let p = Physics::of_rules(
            &StepRules {
                gravity_scale: 1.5,
                viscosity: 0.3,
                dissipation: 0.004,
                ..StepRules::default()
            },
            &device,
        );
        let dissipation = fit(vec![PhysicalScalar::Dissipation], Some(0.01));
        let (p, values) = p.clamped(&dissipation);
        assert_eq!(values[2], 0.0);
        assert_eq!(p.to_array(), values);
    }
}
