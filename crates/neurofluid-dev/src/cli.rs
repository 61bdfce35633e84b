//! Command-line surface: one subcommand per reference-case runner.

use clap::{Parser, Subcommand};

use crate::commands;

/// NeuroFluid-rs developer tools: run the reference cases of the DLF and PhysNeRF parity checks.
#[derive(Debug, Parser)]
#[command(name = "neurofluid-dev", version, about, long_about = None)]
pub struct Cli {
    /// More log output (-v debug, -vv trace). `RUST_LOG` overrides it.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    pub verbose: u8,
    /// The tool to run.
    #[command(subcommand)]
    pub command: Command,
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
    use clap::CommandFactory;

    #[test]
    fn the_cli_is_consistent() {
        Cli::command().debug_assert();
    }
}
