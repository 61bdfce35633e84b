//! File formats the trainer writes and reads: particle point clouds ([`ply`]) and CSV text
//! ([`csv_text`]).

pub mod csv_text;
pub mod ply;
