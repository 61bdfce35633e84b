//! The scene generator's integration tests, a module per file, in one test binary: one build and
//! one link instead of one per file.
mod common;
mod gravity;
mod validation_views;
mod warmup_frames;
