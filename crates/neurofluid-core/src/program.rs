//! The command line every program of the workspace shares: the log options and one subcommand.

use clap::{Args, FromArgMatches, Subcommand};

use crate::logging::LogArgs;

/// A program's command line: `-v` and the subcommand `C`. It has no name of its own: a program
/// gives its name, version and description to [`Program::named`] (so no other crate's can leak
/// into `--help`).
#[derive(Debug, Args)]
pub struct Program<C: Subcommand> {
    /// The log's verbosity.
    #[command(flatten)]
    pub log: LogArgs,
    /// Load checkpoints that have no `checksums.json` (written before checkpoints were sealed,
    /// or with the seal removed) without checking their files; they are refused otherwise.
    #[arg(long, global = true)]
    pub trust_unsealed: bool,
    /// What to run.
    #[command(subcommand)]
    pub command: C,
}

/// What `--help` and `--version` say a program is.
#[derive(Debug, Clone, Copy)]
pub struct Identity {
    /// The binary's name.
    pub name: &'static str,
    /// Its version (the caller's `env!("CARGO_PKG_VERSION")`).
    pub version: &'static str,
    /// One line on what it does (the caller's `env!("CARGO_PKG_DESCRIPTION")`).
    pub about: &'static str,
}

/// The [`Identity`] of the calling package's binary: its package's name, version and description
/// (the caller's `CARGO_PKG_*`).
#[macro_export]
macro_rules! package_identity {
    () => {
        $crate::program::Identity {
            name: env!("CARGO_PKG_NAME"),
            version: env!("CARGO_PKG_VERSION"),
            about: env!("CARGO_PKG_DESCRIPTION"),
        }
    };
}

impl<C: Subcommand> Program<C> {
    /// The command line of the program `id`.
    pub fn named(id: Identity) -> clap::Command {
        Self::augment_args(clap::Command::new(id.name))
            .version(id.version)
            .about(id.about)
            .subcommand_required(true)
            .arg_required_else_help(true)
    }

    /// Applies what the command line and the environment set for the whole process: the limits'
    /// variables are checked (a bad value is the error to print before anything runs),
    /// unsealed checkpoints trusted or not, and the log started (`quiet`: crates kept quiet).
    pub fn start(&self, quiet: &[&str]) -> Result<(), String> {
        crate::limits::check_environment()?;
        crate::checksums::set_trust_unsealed(self.trust_unsealed);
        self.log.init(quiet);
        Ok(())
    }

    /// The process's arguments as the program `id` reads them; on bad arguments or `--help`
    /// clap prints the message and exits.
    pub fn parse_named(id: Identity) -> Self {
        let matches = Self::named(id).get_matches();
        Self::from_arg_matches(&matches).unwrap_or_else(|err| err.exit())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, Subcommand, PartialEq)]
    enum Tool {
        /// One tool.
        One {
            /// A value.
            #[arg(long)]
            value: u32,
        },
    }

    const TOOL: Identity = Identity {
        name: "tool",
        version: "9.8.7",
        about: "a test program",
    };

    #[test]
    fn the_log_flag_is_global_and_counted() {
        let cmd = Program::<Tool>::named(TOOL);
        cmd.clone().debug_assert();
        let m = cmd
            .try_get_matches_from(["tool", "one", "--value", "3", "-vv"])
            .unwrap();
        let p = Program::<Tool>::from_arg_matches(&m).unwrap();
        assert_eq!(p.log.verbose, 2);
        assert_eq!(p.command, Tool::One { value: 3 });
    }

    #[test]
    fn help_and_version_are_the_callers() {
        let mut cmd = Program::<Tool>::named(TOOL);
        assert_eq!(cmd.render_version().trim(), "tool 9.8.7");
        let help = cmd.render_help().to_string();
        assert!(
            help.contains("a test program") && help.contains("Usage: tool"),
            "{help}"
        );
        // a subcommand is required: no arguments is an error that shows the help
        let err = Program::<Tool>::named(TOOL)
            .try_get_matches_from(["tool"])
            .unwrap_err();
        assert!(err.to_string().contains("Usage: tool"), "{err}");
    }
}
