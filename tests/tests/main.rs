//! The end-to-end tests across the crates, a module per file, in one test binary: one build and one
//! link instead of one per file (experiment_files.rs alone: it changes the working directory; see
//! Cargo.toml).
mod bad_inputs;
mod camera_files;
mod config_reference;
mod fuzz_inputs;
mod grounding_grounds;
mod held_out_view;
mod joint_diagnostics;
mod learning;
mod loading_draws;
mod lpips_parity;
mod nerf_baselines;
mod physics_fit;
mod pipeline_resume;
mod pretrain_on_scene;
mod refit;
mod released_box;
mod resting_pool;
mod scene_configs;
mod scene_generation;
mod scene_layout;
mod sweep_and_bptt;
mod test_files;
mod transfers;
mod validation_views;
mod warmup_passes;
