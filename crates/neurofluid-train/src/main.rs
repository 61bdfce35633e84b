//! `neurofluid-train`: one binary for every stage of NeuroFluid-rs.

use clap::Parser;
use neurofluid_train::{cli, commands};

fn main() -> std::process::ExitCode {
    neurofluid_core::malloc::keep_freed_memory();
    let cli = cli::Cli::parse();
    cli::init_logging(cli.verbose);
    tracing::debug!(
        "allocator: {}",
        neurofluid_core::malloc::allocator_setting()
    );
    match commands::dispatch(cli.command) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
