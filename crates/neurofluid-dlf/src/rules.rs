//! The rules of a DLF step beyond the published model's: walls that hold every particle, an
//! energy cap per particle, a scale of the pre-step's gravity, an XSPH viscosity and a
//! dissipation. They apply
//! in every rollout (training, diagnostics, evaluation, the baseline DLF's too); an experiment's
//! `[dlf]` table holds them under these names.

use neurofluid_core::scene::Aabb;
use serde::{Deserialize, Serialize};

/// Whether the walls of the box are enforced on DLF's predictions (`containment`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Containment {
    /// The reference: particles may cross the walls where DLF's box convolution lets them.
    #[default]
    None,
    /// Every prediction kept inside the scene's box interior, its velocity the move it made
    /// ([`crate::net`]'s `contain`).
    Box,
}

/// Whether DLF's steps may raise a particle's mechanical energy (`energy_cap`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EnergyCap {
    /// The reference: DLF's step as it is.
    #[default]
    None,
    /// No step raises a particle's ½|v|² − g·x; a step that would is shortened
    /// ([`crate::energy_cap`]).
    Particle,
}

/// The frame in which the dissipation takes its share of each velocity (`dissipation_frame`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DissipationFrame {
    /// The box's: a drag on every velocity, a body's fall and throw included.
    #[default]
    Box,
    /// Each particle's body's ([`crate::bodies`]): only the motion within a body is damped; its
    /// motion as a whole and its momentum are kept.
    Body,
}

/// The rules of a step. The default is the published model's step.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct StepRules {
    /// `none` (the reference: the walls act only through DLF's box convolution) or `box` (every
    /// predicted particle kept inside the scene's box interior).
    pub containment: Containment,
    /// `none` (the reference) or `particle` (each particle's step shortened where it would
    /// raise that particle's mechanical energy, as no particle of a viscous fluid's truth does).
    pub energy_cap: EnergyCap,
    /// Scale of the gravity in the pre-step only; the energy cap and the scene keep the true
    /// gravity. `1.0` (the reference). The published weights let a falling clump accelerate at
    /// about 6.3 m/s² of 9.81; 1.7 makes it 9.8 (`tests/free_fall.rs`).
    pub gravity_scale: f64,
    /// Strength in [0, 1] of an XSPH viscosity on each step's velocities (each moves this share
    /// of the way toward its neighbours'; [`crate::viscosity`]). `0.0` (the reference): none.
    pub viscosity: f64,
    /// Share in [0, 1) of each particle's velocity a step takes away, after the viscosity (its
    /// move shortened to match, so v is still the move over dt). `0.0` (the reference): none.
    pub dissipation: f64,
    /// `box` (the default: the share of each velocity) or `body` (the share of each velocity
    /// relative to the mean velocity of the particle's body, the connected group of particles it
    /// belongs to; [`crate::bodies`]).
    pub dissipation_frame: DissipationFrame,
}

impl Default for StepRules {
    fn default() -> Self {
        Self {
            containment: Containment::None,
            energy_cap: EnergyCap::None,
            gravity_scale: 1.0,
            viscosity: 0.0,
            dissipation: 0.0,
            dissipation_frame: DissipationFrame::Box,
        }
    }
}

/// Why a [`StepRules`] cannot run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("dlf.{field}: {expected}")]
pub struct RulesError {
    /// The rule's name.
    pub field: &'static str,
    /// What was expected.
    pub expected: String,
}

impl StepRules {
    /// The first rule whose value a step cannot run with.
    pub fn problem(&self) -> Option<RulesError> {
        let error = |field, expected: &str| {
            Some(RulesError {
                field,
                expected: expected.to_string(),
            })
        };
        if !(self.gravity_scale.is_finite()
            && self.gravity_scale > 0.0
            && self.gravity_scale <= 4.0)
        {
            return error("gravity_scale", "expected a scale in (0, 4]");
        }
        if !(0.0..=1.0).contains(&self.viscosity) {
            return error("viscosity", "expected a strength in [0, 1]");
        }
        if !(0.0..1.0).contains(&self.dissipation) {
            return error("dissipation", "expected a share in [0, 1)");
        }
        None
    }

    /// Whether a step needs the fluid's pairs on the host (the viscosity's and the bodies'), given
    /// whether the scalars come as fitted values (which may turn either on).
    pub fn needs_host_pairs(&self, fitted: bool) -> bool {
        fitted
            || self.viscosity > 0.0
            || (self.dissipation_frame == DissipationFrame::Body && self.dissipation > 0.0)
    }

    /// The box the walls keep the particles in: `box_interior` under `containment = "box"`,
    /// refused where no box is known (DLF's records have none); `None` without walls.
    pub fn container(&self, box_interior: Option<Aabb>) -> Result<Option<Aabb>, RulesError> {
        match self.containment {
            Containment::None => Ok(None),
            Containment::Box => box_interior.map(Some).ok_or_else(|| RulesError {
                field: "containment",
                expected: "\"box\" needs a scene's box; DLF records have none".into(),
            }),
        }
    }

    /// The rules beyond the reference's, as a report names them (in the order a step applies
    /// them).
    pub fn describe(&self) -> Vec<String> {
        let mut rules = Vec::new();
        if self.containment == Containment::Box {
            rules.push("the walls (`dlf.containment = \"box\"`)".to_string());
        }
        if self.energy_cap == EnergyCap::Particle {
            rules.push("the energy cap (`dlf.energy_cap = \"particle\"`)".to_string());
        }
        if self.gravity_scale != 1.0 {
            rules.push(format!(
                "the pre-step's gravity scaled by {} (`dlf.gravity_scale`)",
                self.gravity_scale
            ));
        }
        if self.viscosity != 0.0 {
            rules.push(format!(
                "an XSPH viscosity of strength {} (`dlf.viscosity`)",
                self.viscosity
            ));
        }
        if self.dissipation != 0.0 {
            rules.push(match self.dissipation_frame {
                DissipationFrame::Box => format!(
                    "a dissipation of {} of each velocity a step (`dlf.dissipation`)",
                    self.dissipation
                ),
                DissipationFrame::Body => format!(
                    "a dissipation of {} of each velocity relative to its body's mean a step \
                     (`dlf.dissipation`, `dlf.dissipation_frame = \"body\"`)",
                    self.dissipation
                ),
            });
        }
        rules
    }
}
