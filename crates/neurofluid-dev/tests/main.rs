//! The developer crate's integration tests (the parity checks), a module per file, in one test
//! binary: one build and one link instead of one per file (device_search_render.rs alone: it sets
//! the process's neighbour search; see Cargo.toml).
mod common;
mod gradcheck_particles;
mod options_and_weights;
mod parity_e2e_f32;
mod parity_e2e_f64;
mod parity_stages;
mod render_view;
