//! `preset`: a named set of training rules laid over an experiment file's values, so that the
//! reference's behaviour stays one line away from any experiment.
//!
//! `preset = "paper"` (or `--set preset=paper`) resets every rule in which this project departs
//! from NeuroFluid's code (spec §4) to the reference's value, whatever the file says: constant
//! DLF geometry, open walls, no energy cap, the published gravity and no viscosity, the
//! lowest-index neighbour rule, ReLU density, world positions and the paper's encoding
//! frequencies, the warm-up's and the joint stage's optimisers and schedules, one-step
//! truncated BPTT with DLF stepping every transition, uniform rays, one view, no particle terms
//! (`[joint.terms]`), no physical scalars fitted or searched (`[joint.physics]`), the boundary
//! weight 1, the grounded DLF evaluated as trained and the novel views
//! rendered by the jointly trained PhysNeRF (no refit). Budgets
//! (iterations, epochs, rays, samples, network widths) stay the file's: they are the scale of
//! the experiment, not its rules. Each value the preset changes is logged.

use serde::{Deserialize, Serialize};

use super::settings::Change;
use super::{
    DiagnosticsSection, DlfSection, Experiment, JointSection, RefitSection, Settings, WarmupSection,
};
use neurofluid_physnerf::PhysNerfConfig;

/// A named set of training rules.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Preset {
    /// The file's values as they are.
    #[default]
    None,
    /// NeuroFluid's reference rules (see the module's documentation).
    Paper,
}

impl Preset {
    /// True for [`Preset::None`] (the key is then left out of resolved files).
    pub fn is_none(&self) -> bool {
        *self == Preset::None
    }
}

/// Lays `exp.preset` over `exp`; returns the settings it changed.
pub fn apply(exp: &mut Experiment) -> Vec<Change> {
    if exp.preset == Preset::None {
        return Vec::new();
    }
    let before = Settings::all(exp);
    let paper_nerf = PhysNerfConfig::default();
    let p = &mut exp.physnerf;
    p.selection = paper_nerf.selection;
    p.density = paper_nerf.density;
    p.frequencies = paper_nerf.frequencies;
    p.positions = paper_nerf.positions;
    exp.dlf = DlfSection {
        weights: exp.dlf.weights.clone(),
        ..DlfSection::default()
    };
    exp.warmup.optim = WarmupSection::default().optim;
    let paper = JointSection::default();
    let j = &mut exp.joint;
    j.bptt_steps = paper.bptt_steps;
    j.dlf_every = paper.dlf_every;
    j.physnerf_optim = paper.physnerf_optim;
    j.dlf_optim = paper.dlf_optim;
    j.boundary_weight = paper.boundary_weight;
    j.foreground_rays = paper.foreground_rays;
    j.input_noise = paper.input_noise;
    j.terms = paper.terms;
    j.extra_views = paper.extra_views;
    j.physics = paper.physics;
    exp.diagnostics.weight_interpolation = DiagnosticsSection::default().weight_interpolation;
    exp.refit = RefitSection::default();
    Settings::all(exp).changes_since(&before)
}
