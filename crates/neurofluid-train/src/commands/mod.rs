//! One module per subcommand; each exposes `Args` and `run`.

pub mod devices;
pub mod experiment_args;
pub mod generate;
pub mod info;
pub mod mesh;
pub mod nerf_cmds;
pub mod pretrain_dlf;
pub mod rollout;
pub mod run;
pub mod stage_cmds;
pub mod sweep;

use crate::cli::Command;

/// Runs the chosen subcommand.
pub fn dispatch(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Run(args) => run::run(args),
        Command::Warmup(args) => stage_cmds::run_warmup(args),
        Command::Joint(args) => stage_cmds::run_joint(args),
        Command::Refit(args) => stage_cmds::run_refit(args),
        Command::Eval(args) => stage_cmds::run_eval(args),
        Command::Generate(args) => generate::run(args),
        Command::Info(args) => info::run(args),
        Command::Sweep(args) => sweep::run(args),
        Command::PretrainDlf(args) => pretrain_dlf::run(args),
        Command::Rollout(args) => rollout::run(args),
        Command::Devices(args) => devices::run(args),
        Command::Mesh(args) => mesh::run(args),
        Command::InitParticles(args) => nerf_cmds::run_init(args),
        Command::Baseline(args) => nerf_cmds::run_baseline(args),
    }
}
