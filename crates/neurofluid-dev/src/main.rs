//! `neurofluid-dev`: the reference-case runners of NeuroFluid-rs.

use clap::Parser;
use neurofluid_dev::{cli, commands};

fn main() -> std::process::ExitCode {
    neurofluid_core::malloc::keep_freed_memory();
    let cli = cli::Cli::parse();
    neurofluid_core::logging::init(cli.verbose, &[]);
    match commands::dispatch(cli.command) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
