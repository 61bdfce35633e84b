//! The training and evaluation stages that `run` chains: warm-up, joint grounding, evaluation.

pub mod checkpoint;
pub mod context;
pub mod eval;
pub mod joint;
pub mod preview;
pub mod progress;
pub mod scene_source;
pub mod warmup;

pub use context::Run;
