//! The shape every training stage shares.
//!
//! A stage is a [`Trainer`]: it owns its models, optimisers, schedules and random stream, takes
//! one step at a time and reports [`StepStats`], can look at itself on held-out data
//! ([`Evaluation`]) and save or restore its state. The [`Driver`] owns everything around the
//! steps: where to start (resume from a checkpoint, guarded by the settings), where to stop,
//! when to log, evaluate and checkpoint, and what counts as divergence. It tells the outside
//! world through [`Event`]s; progress bars, the metrics log and preview pictures are
//! [`EventSink`]s, never code inside a loop.

pub mod checkpoint;
mod driver;
mod events;
pub mod guard;
pub mod sinks;

use std::path::Path;

pub use driver::Driver;
pub use events::{Event, EventSink};

/// A stage's own small state (e.g. its random stream), stored in its checkpoint's `state.json`.
pub type StageState = serde_json::Map<String, serde_json::Value>;

/// What one step did, as named scalars for the log ([`StepStats::named`]): a new parameter
/// group or diagnostic is a new name here, in the stage that reports it, and nowhere else.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StepStats {
    /// The loss of the step (of the whole window when several transitions share one update).
    pub loss: f64,
    /// PSNR (dB) of the step's image batch, where there is one.
    pub psnr: Option<f64>,
    /// Rays rendered in the step.
    pub rays: usize,
    /// The learning rate of each parameter group the update stepped (`lr/<group>`).
    pub lrs: Vec<(&'static str, f64)>,
    /// The L2 norm of each parameter group's gradients in the update (`grad_norm/<group>`),
    /// 0 for a group the loss did not depend on.
    pub grad_norms: Vec<(&'static str, f64)>,
    /// The value of each particle term over the window (`loss/<term>`; the joint stage's
    /// `[joint.terms]`).
    pub losses: Vec<(&'static str, f64)>,
    /// Further named scalars of the step, logged under their names.
    pub scalars: Vec<(&'static str, f64)>,
    /// Whether the step ended with an optimiser update. A step inside a window of several
    /// transitions (multi-step BPTT) does not: its loss waits for the window's end, and the
    /// driver logs, evaluates and checkpoints only after updates.
    pub updated: bool,
}

impl StepStats {
    /// The step's scalars as the metrics log names them: `psnr`, `lr/<group>`,
    /// `grad_norm/<group>`, `loss/<term>`, then the further ones.
    pub fn named(&self) -> Vec<(String, f64)> {
        let psnr = self.psnr.map(|p| ("psnr".to_string(), p));
        let family = |family: &str, of: &[(&str, f64)]| -> Vec<(String, f64)> {
            of.iter()
                .map(|(g, v)| (format!("{family}/{g}"), *v))
                .collect()
        };
        psnr.into_iter()
            .chain(family("lr", &self.lrs))
            .chain(family("grad_norm", &self.grad_norms))
            .chain(family("loss", &self.losses))
            .chain(self.scalars.iter().map(|(n, v)| (n.to_string(), *v)))
            .collect()
    }
}

/// A picture: `[render | truth]` side by side (the outputs crate draws and writes it).
pub use neurofluid_outputs::pictures::Picture;

/// A look at the model on data it does not train on.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Evaluation {
    /// PSNR (dB) of the render, where there is one.
    pub psnr: Option<f64>,
    /// The render beside the truth.
    pub picture: Option<Picture>,
    /// Further named scores (e.g. DLF's validation errors).
    pub scores: Vec<(&'static str, f64)>,
}

/// A training stage.
pub trait Trainer {
    /// The stage's name: its folder in the run folder and its rows in the metrics log.
    fn stage(&self) -> &'static str;

    /// The number of steps of the whole stage.
    fn total_steps(&self) -> u64;

    /// Runs step `step` (0-based).
    fn step(&mut self, step: u64) -> anyhow::Result<StepStats>;

    /// Checks the trainer's own state after a step (e.g. that carried particles stay finite and
    /// near the box): `Err` names what is wrong, and the run stops before it is checkpointed.
    fn check_state(&self) -> Result<(), String> {
        Ok(())
    }

    /// Evaluates the model after `done` steps (`None` when the stage has nothing to show).
    fn evaluate(&mut self, done: u64) -> anyhow::Result<Option<Evaluation>>;

    /// Writes the models, optimisers and any carried state into the folder `dir`; returns the
    /// stage's own small state (e.g. its random stream) for `state.json`.
    fn save(&self, dir: &Path) -> anyhow::Result<StageState>;

    /// Restores what [`Trainer::save`] wrote after `done` steps.
    fn load(&mut self, dir: &Path, done: u64, state: StageState) -> anyhow::Result<()>;
}
