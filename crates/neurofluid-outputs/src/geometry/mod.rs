//! Geometry of particles and fields: fluid surfaces from particles ([`mesh`]), particles from
//! a density field ([`volume_fill`]) and the density at which the field's body matches the
//! images' silhouettes ([`silhouette_iso`]).

pub mod mesh;
pub mod silhouette_iso;
pub mod volume_fill;
