//! Command-line surface: the stages of the pipeline as subcommands.

use clap::Subcommand;
use neurofluid_core::program::{Identity, Program};

use crate::commands;

/// The command line of `neurofluid-train`.
pub type Cli = Program<Command>;

/// What `--help` and `--version` say the program is: its package's name, version and description.
const IDENTITY: Identity = neurofluid_core::package_identity!();

/// The process's arguments, read as `neurofluid-train`'s.
pub fn parse() -> Cli {
    Cli::parse_named(IDENTITY)
}

/// The stages of the pipeline; each can run alone.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// The whole pipeline of an experiment: scene (generated if missing), warm-up, joint, refit
    /// (with `refit.enabled`), eval.
    Run(commands::run::Args),
    /// Warm up the renderer on frame 0 from the warm-up views.
    Warmup(commands::stage_cmds::Args),
    /// Ground DLF and PhysNeRF jointly on the training view.
    Joint(commands::stage_cmds::Args),
    /// Fit a second renderer to the grounded rollout for the novel views (`refit.enabled`).
    Refit(commands::stage_cmds::Args),
    /// Evaluate a grounded model: particle distance, PSNR/SSIM, renders, PLY.
    Eval(commands::stage_cmds::Args),
    /// Generate a built-in scene (SPH simulation + renders) in NeuroFluid's layout.
    Generate(commands::generate::Args),
    /// Summarise a scene directory (generated or released layout).
    Info(commands::info::Args),
    /// Run every variant of a sweep file (in this process, one run alone, or as a Slurm job
    /// array) and write a Table-5-shaped table.
    Sweep(commands::sweep::Args),
    /// Supervised (pre)training or fine-tuning of DLF on `.msgpack.zst` records.
    PretrainDlf(commands::pretrain_dlf::Args),
    /// Roll one DLF out under the experiment's `[dlf]` rules from the first test frame and score
    /// it by d and d′ (nothing trained, nothing written).
    Rollout(commands::rollout::Args),
    /// Print the compiled-in backends and the devices they offer.
    Devices(commands::devices::Args),
    /// Fluid surfaces (OBJ/PLY) of particle files: a scene's ground truth or an evaluation's
    /// rollouts, one mesh per frame.
    Mesh(commands::mesh::Args),
    /// Recover the particles at t = 0 from the warm-up images of frame 0 (NeRF, marching cubes,
    /// lattice fill); `scene.initial = "from_images"` makes `run` start from them.
    InitParticles(commands::nerf_cmds::InitArgs),
    /// Train and score a novel-view baseline (NeRF or NeRF-T) on NeuroFluid's test views.
    Baseline(commands::nerf_cmds::BaselineArgs),
}

impl Command {
    /// Runs the chosen subcommand.
    pub fn run(self) -> anyhow::Result<()> {
        match self {
            Command::Run(args) => commands::run::run(args),
            Command::Warmup(args) => commands::stage_cmds::run_warmup(args),
            Command::Joint(args) => commands::stage_cmds::run_joint(args),
            Command::Refit(args) => commands::stage_cmds::run_refit(args),
            Command::Eval(args) => commands::stage_cmds::run_eval(args),
            Command::Generate(args) => commands::generate::run(args),
            Command::Info(args) => commands::info::run(args),
            Command::Sweep(args) => commands::sweep::run(args),
            Command::PretrainDlf(args) => commands::pretrain_dlf::run(args),
            Command::Rollout(args) => commands::rollout::run(args),
            Command::Devices(args) => commands::devices::run(args),
            Command::Mesh(args) => commands::mesh::run(args),
            Command::InitParticles(args) => commands::nerf_cmds::run_init(args),
            Command::Baseline(args) => commands::nerf_cmds::run_baseline(args),
        }
    }

    /// Whether the command trains: SIGTERM and SIGINT then stop it between steps with a
    /// checkpoint (and exit status 75) instead of killing it.
    pub fn trains(&self) -> bool {
        match self {
            Self::Run(_)
            | Self::Warmup(_)
            | Self::Joint(_)
            | Self::Refit(_)
            | Self::PretrainDlf(_)
            | Self::InitParticles(_)
            | Self::Baseline(_) => true,
            Self::Sweep(args) => args.trains(),
            Self::Eval(_)
            | Self::Rollout(_)
            | Self::Generate(_)
            | Self::Info(_)
            | Self::Devices(_)
            | Self::Mesh(_) => false,
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
