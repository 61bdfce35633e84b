//! The programs' log: `tracing` on stderr at the level `-v` asks for (or `RUST_LOG`).

/// The log options every program of the workspace takes (flattened into its command line).
#[derive(Debug, Clone, Copy, Default, clap::Args)]
pub struct LogArgs {
    /// More log output (-v debug, -vv trace). `RUST_LOG` overrides it.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    pub verbose: u8,
}

impl LogArgs {
    /// Sets up the log at this verbosity ([`init`]).
    pub fn init(&self, quiet: &[&str]) {
        init(self.verbose, quiet);
    }
}

/// Sets up `tracing` on stderr: `info`, `debug` (`verbose` = 1) or `trace` (2 and more), with
/// the crates in `quiet` at `warn` (libraries that narrate at `info`); `RUST_LOG` overrides it.
/// Colours only on a terminal. A second call does nothing.
pub fn init(verbose: u8, quiet: &[&str]) {
    let level = ["info", "debug", "trace"][usize::from(verbose.min(2))];
    let directives = std::iter::once(level.to_string())
        .chain(quiet.iter().map(|c| format!("{c}=warn")))
        .collect::<Vec<_>>()
        .join(",");
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(directives));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        .try_init();
}
