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
