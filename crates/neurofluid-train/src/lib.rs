//! The NeuroFluid-rs trainer: experiment files, the training and evaluation stages, checkpoints,
//! metrics, reports and sweeps. The `neurofluid-train` binary is a thin CLI over this library.

pub mod cli;
pub mod commands;
pub mod config;
pub mod density_prior;
pub mod energy_prior;
pub mod focus;
pub mod formats;
pub mod geometry;
pub mod metrics_log;
pub mod optim;
pub mod pictures;
pub mod report;
pub mod rest_density;
pub mod sampler;
pub mod silhouette;
pub mod stage;
pub mod stages;
pub mod sweep;
pub mod trainer;
