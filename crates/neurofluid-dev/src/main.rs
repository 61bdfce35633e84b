//! `neurofluid-dev`: the reference-case runners of NeuroFluid-rs.

use neurofluid_dev::cli;

fn main() -> std::process::ExitCode {
    neurofluid_core::malloc::keep_freed_memory();
    let cli = cli::parse();
    if let Err(err) = cli.start(&[]) {
        eprintln!("error: {err}");
        return std::process::ExitCode::FAILURE;
    }
    match cli.command.run() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
