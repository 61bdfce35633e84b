//! One module per subcommand; each exposes `Args` and `run`.

pub mod dlf_rollout;
pub mod physnerf_case;
pub mod render;

use crate::cli::Command;

/// Runs the chosen subcommand.
pub fn dispatch(command: Command) -> anyhow::Result<()> {
    match command {
        Command::PhysnerfCase(args) => physnerf_case::run(args),
        Command::Render(args) => render::run(args),
        Command::DlfRollout(args) => dlf_rollout::run(args),
    }
}
