//! The joint stage's particle terms: losses on each predicted step besides the paper's image
//! and boundary losses, each one implementation of [`ParticleTerm`] in a file of its own,
//! configured under its own table (`[joint.terms.<name>]`) and logged under its own name
//! (`loss/<name>` in `metrics.jsonl`, `loss_<name>` in the CSV).
//!
//! A term is on when its table is present with a weight above zero; `preset = "paper"` clears
//! them all. The terms run in the order of the list below (which fixes the order their sums are
//! added in, and so the bits of a run).
//!
//! To add a term: a file beside these with its settings (serde, a `weight`) implementing
//! [`TermSettings`] and its term implementing [`ParticleTerm`], and one line in the list.

use burn::prelude::*;
use neurofluid_dlf::{Boundary, DlfNet, PhysicsValues};
use serde::{Deserialize, Serialize};

pub mod anchor;
pub mod energy;
pub mod truth;

/// One transition of the joint stage as a term sees it.
pub struct Transition<'a> {
    /// The state (x_t, v_t) the step started from, as DLF was given it (`joint.input_noise`
    /// added to the carried velocities).
    pub before: &'a (Tensor<2>, Tensor<2>),
    /// The grounded DLF's prediction (x_{t+1}, v_{t+1}), differentiable through DLF.
    pub after: &'a (Tensor<2>, Tensor<2>),
    /// The index of the predicted frame among the training frames (t + 1).
    pub frame: usize,
    /// DLF's walls of the scene.
    pub walls: &'a Boundary,
    /// The physical scalars the step used, out of the graph, where `[joint.physics]` fits them.
    pub physics: Option<&'a PhysicsValues>,
}

/// A loss on the predicted particles of one transition.
pub trait ParticleTerm {
    /// Its name in the metrics and the configuration (`[joint.terms.<name>]`).
    fn name(&self) -> &'static str;

    /// The weighted term of `step` (`[1]`), differentiable through `step.after`.
    fn loss(&self, step: &Transition) -> Tensor<1>;
}

/// What a term may take when it is built: the scene's data that does not change while training.
pub struct TermContext<'a> {
    /// DLF as the joint stage starts from it (the pretrained weights).
    pub pretrained: &'a DlfNet,
    /// The particle radius.
    pub radius: f32,
    /// The true positions of every training frame, when the scene has them.
    pub truth: Option<&'a [Vec<[f32; 3]>]>,
    /// The number of transitions per epoch.
    pub transitions: u64,
    /// The particles the joint stage predicts.
    pub particles: usize,
}

/// A term's table: builds the term and checks its own values.
pub trait TermSettings {
    /// The term, or `None` when its weight turns it off.
    fn build(&self, ctx: &TermContext) -> anyhow::Result<Option<Box<dyn ParticleTerm>>>;

    /// The first field (relative to the term's table) that the term cannot run with, and what
    /// was expected.
    fn problem(&self) -> Option<(&'static str, String)>;
}

/// A term's weight: finite and ≥ 0 (0 turns the term off).
pub fn weight_problem(weight: f64) -> Option<(&'static str, String)> {
    (!(weight.is_finite() && weight >= 0.0))
        .then(|| ("weight", "expected a finite weight ≥ 0".to_string()))
}

macro_rules! terms {
    ($($name:ident: $settings:ty),* $(,)?) => {
        /// `[joint.terms]`: the particle terms, each under its own table; none = the paper's
        /// loss.
        #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
        #[serde(deny_unknown_fields)]
        pub struct TermsSection {
            $(
                #[allow(missing_docs)]
                #[serde(default, skip_serializing_if = "Option::is_none")]
                pub $name: Option<$settings>,
            )*
        }

        impl TermsSection {
            /// The names of the terms, in the order they run.
            pub const NAMES: &[&str] = &[$(stringify!($name)),*];

            /// The terms that are on, in the order of the list.
            pub fn build(&self, ctx: &TermContext) -> anyhow::Result<Vec<Box<dyn ParticleTerm>>> {
                let mut terms = Vec::new();
                $(
                    if let Some(settings) = &self.$name {
                        terms.extend(settings.build(ctx)?);
                    }
                )*
                Ok(terms)
            }

            /// The first problem of a term's table: the field (relative to `[joint.terms]`) and
            /// what was expected.
            pub fn problem(&self) -> Option<(String, String)> {
                $(
                    if let Some((field, msg)) = self.$name.as_ref().and_then(|s| s.problem()) {
                        return Some((format!("{}.{field}", stringify!($name)), msg));
                    }
                )*
                None
            }
        }
    };
}

// The list of terms, in the order they run.
terms! {
    anchor: anchor::AnchorSettings,
    truth: truth::TruthSettings,
    energy: energy::EnergySettings,
}
