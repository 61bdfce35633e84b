//! What a NeuroFluid-rs run writes for people, below the trainer: the evaluation report
//! ([`report`]) with what it measures of the rollouts ([`sequences`]) and of renders and particle
//! sets against the truth ([`scoring`]), a sweep's table ([`sweep_table`]), the metrics log
//! ([`metrics_log`]), plots, pictures and the viewer ([`pictures`]), PLY point clouds and CSV
//! text ([`formats`]), and the geometry of particles and fields ([`geometry`]: fluid surfaces,
//! particles from a density field). The trainer hands it rollouts, metrics and pictures as plain
//! data; it never reaches back.

pub mod formats;
pub mod geometry;
pub mod metrics_log;
pub mod pictures;
pub mod reference;
pub mod report;
pub mod scoring;
pub mod sequences;
pub mod sweep_table;
