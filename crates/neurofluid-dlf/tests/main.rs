//! The DLF crate's integration tests, a module per file, in one test binary: one build and one link
//! instead of one per file (device_geometry.rs alone: it sets the process's neighbour search; see
//! Cargo.toml).
mod common;
mod containment;
mod conv_geometry;
mod energy_cap;
mod free_fall;
mod fused_conv;
mod parity_backward;
mod parity_forward;
mod parity_rollout;
mod physics;
mod validation;
mod weights;
