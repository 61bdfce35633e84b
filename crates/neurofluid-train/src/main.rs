//! `neurofluid-train`: one binary for every stage of NeuroFluid-rs.

use neurofluid_train::trainer::stop;
use neurofluid_train::{cli, commands};

fn main() -> std::process::ExitCode {
    neurofluid_core::malloc::keep_freed_memory();
    let cli = cli::parse();
    // splashsurf narrates every reconstruction at `info`
    cli.log.init(&["splashsurf_lib"]);
    tracing::debug!(
        "allocator: {}",
        neurofluid_core::malloc::allocator_setting()
    );
    if cli.command.trains()
        && let Err(err) = stop::install_signal_handlers()
    {
        eprintln!("error: {err:#}");
        return std::process::ExitCode::FAILURE;
    }
    match commands::dispatch(cli.command) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) if stop::stopped(&err).is_some() => {
            eprintln!("stopped: {err:#}");
            std::process::ExitCode::from(stop::REQUEUE_EXIT_CODE)
        }
        Err(err) => {
            eprintln!("error: {err:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
