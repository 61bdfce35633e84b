//! One module per subcommand; each exposes `Args` and `run`.

pub mod devices;
pub mod experiment_args;
pub mod run;
pub mod stage_cmds;

use crate::cli::Command;

/// Runs the chosen subcommand.
pub fn dispatch(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Run(args) => run::run(args),
        Command::Warmup(args) => stage_cmds::run_warmup(args),
        Command::Joint(args) => stage_cmds::run_joint(args),
        Command::Eval(args) => stage_cmds::run_eval(args),
        Command::Devices(args) => devices::run(args),
    }
}
