//! One module per subcommand; each exposes `Args` and `run`.

pub mod devices;

use crate::cli::Command;

/// Runs the chosen subcommand.
pub fn dispatch(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Devices(args) => devices::run(args),
    }
}
