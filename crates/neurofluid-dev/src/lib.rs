//! Developer tools of NeuroFluid-rs, apart from the researcher's CLI (`neurofluid-train`): the
//! runners of the reference cases that the parity checks hold the ports to
//! (`tests/data/*/README.md`). The `neurofluid-dev` binary is a thin CLI over this library.

pub mod cli;
pub mod commands;
pub mod physnerf_case;
