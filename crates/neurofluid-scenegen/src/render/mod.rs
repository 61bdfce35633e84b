//! CPU surface renderer: density-field iso-surface ([`field`]) ray-traced with rayon
//! ([`trace`]) against a procedural environment ([`env`]).

pub mod env;
pub mod field;
pub mod trace;
