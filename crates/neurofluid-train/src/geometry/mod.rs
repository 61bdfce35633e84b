//! Geometry of particles and fields: fluid surfaces from particles ([`mesh`]) and particles from
//! a density field ([`volume_fill`]).

pub mod mesh;
pub mod volume_fill;
