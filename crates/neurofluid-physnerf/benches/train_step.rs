//! One PhysNeRF training step (placeholder).

fn main() {}
