//! The trainer's integration tests, a module per file, in one test binary: one build and one link
//! instead of one per file.
mod cli_allocator;
mod cli_limits;
mod cli_lock;
mod cli_mesh;
mod common;
mod experiments;
mod slurm_submission;
mod slurm_sweep;
mod supervised_dlf;
mod sweep_signals;
