//! One module per subcommand; each exposes `Args` and `run`.

pub mod dlf_rollout;
pub mod physnerf_case;
pub mod render;
