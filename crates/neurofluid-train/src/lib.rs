//! The NeuroFluid-rs trainer: experiment files, the training and evaluation stages, checkpoints
//! and sweeps. What a run writes for people (the metrics log, the report, pictures, the viewer,
//! PLY and meshes) is `neurofluid-outputs`, which this crate hands rollouts and metrics. The
//! `neurofluid-train` binary is a thin CLI over this library.

pub mod cli;
pub mod commands;
pub mod config;
pub mod optim;
pub mod stage;
pub mod stages;
pub mod sweep;
pub mod trainer;
