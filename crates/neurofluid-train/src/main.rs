//! `neurofluid-train`: one binary for every stage of NeuroFluid-rs.

use clap::Parser;
use neurofluid_train::{cli, commands};

fn main() -> std::process::ExitCode {
    neurofluid_core::malloc::keep_freed_memory();
    let cli = cli::Cli::parse();
    cli::init_logging(cli.verbose);
    tracing::debug!(
        "allocator: GLIBC_TUNABLES={}",
        std::env::var("GLIBC_TUNABLES").unwrap_or_else(|_| "(glibc defaults)".into())
    );
    match commands::dispatch(cli.command) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
