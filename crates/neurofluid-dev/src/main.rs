//! `neurofluid-dev`: the reference-case runners of NeuroFluid-rs.

use neurofluid_dev::{cli, commands};

fn main() -> std::process::ExitCode {
    neurofluid_core::malloc::keep_freed_memory();
    let cli = cli::parse();
    cli.log.init(&[]);
    match commands::dispatch(cli.command) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
