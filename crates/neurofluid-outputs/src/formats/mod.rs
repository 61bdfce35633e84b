//! File formats the trainer writes and reads: particle point clouds ([`ply`]), CSV text
//! ([`csv_text`]) and names made safe for HTML and Markdown ([`markup`]).

pub mod csv_text;
pub mod markup;
pub mod ply;
