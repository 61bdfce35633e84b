//! `neurofluid-train`: one binary for every stage of NeuroFluid-rs.

use neurofluid_core::stop_request;
use neurofluid_train::cli;

fn main() -> std::process::ExitCode {
    neurofluid_core::malloc::keep_freed_memory();
    let cli = cli::parse();
    // splashsurf narrates every reconstruction at `info`
    if let Err(err) = cli.start(&["splashsurf_lib"]) {
        eprintln!("error: {err}");
        return std::process::ExitCode::FAILURE;
    }
    tracing::debug!(
        "allocator: {}",
        neurofluid_core::malloc::allocator_setting()
    );
    if cli.command.trains()
        && let Err(err) = stop_request::install_signal_handlers()
    {
        eprintln!("error: {:#}", anyhow::Error::from(err));
        return std::process::ExitCode::FAILURE;
    }
    match cli.command.run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) if stop_request::stopped(err.as_ref()).is_some() => {
            eprintln!("stopped: {err:#}");
            std::process::ExitCode::from(stop_request::REQUEUE_EXIT_CODE)
        }
        Err(err) => {
            eprintln!("error: {err:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
