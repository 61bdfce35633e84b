//! Command-line surface: one subcommand per reference-case runner.

use clap::Subcommand;
use neurofluid_core::program::{Identity, Program};

use crate::commands;

/// The command line of `neurofluid-dev`.
pub type Cli = Program<Command>;

/// What `--help` and `--version` say the program is: its package's name, version and description.
const IDENTITY: Identity = Identity {
    name: "neurofluid-dev",
    version: env!("CARGO_PKG_VERSION"),
    about: env!("CARGO_PKG_DESCRIPTION"),
};

/// The process's arguments, read as `neurofluid-dev`'s.
pub fn parse() -> Cli {
    Cli::parse_named(IDENTITY)
}

/// The developer tools.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Render a PhysNeRF reference case file and write the reference's keys (parity check).
    PhysnerfCase(commands::physnerf_case::Args),
    /// Render a whole view of a PhysNeRF case in ray chunks and save a PNG.
    Render(commands::render::Args),
    /// Run the DLF model on a scene `.npz` (the DLF reference harness's keys).
    DlfRollout(commands::dlf_rollout::Args),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cli_is_consistent() {
        Cli::named(IDENTITY).debug_assert();
    }
}
