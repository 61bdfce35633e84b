//! Command-line surface: one subcommand per reference-case runner.

use clap::Subcommand;
use neurofluid_core::program::{Identity, Program};

use crate::commands;

/// The command line of `neurofluid-dev`.
pub type Cli = Program<Command>;

/// What `--help` and `--version` say the program is: its package's name, version and description.
const IDENTITY: Identity = neurofluid_core::package_identity!();

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

impl Command {
    /// Runs the chosen subcommand.
    pub fn run(self) -> anyhow::Result<()> {
        match self {
            Command::PhysnerfCase(args) => commands::physnerf_case::run(args),
            Command::Render(args) => commands::render::run(args),
            Command::DlfRollout(args) => commands::dlf_rollout::run(args),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cli_is_consistent() {
        Cli::named(IDENTITY).debug_assert();
    }
}
