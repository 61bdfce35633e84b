//! The command line every program of the workspace shares: the log options and one subcommand.

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

use crate::logging::LogArgs;

/// A program's command line: `-v` and the subcommand `C`.
#[derive(Debug, Parser)]
pub struct Program<C: Subcommand> {
    /// The log's verbosity.
    #[command(flatten)]
    pub log: LogArgs,
    /// What to run.
    #[command(subcommand)]
    pub command: C,
}

impl<C: Subcommand> Program<C> {
    /// The command line of the program `name`, described by `about`.
    pub fn named(name: &'static str, about: &'static str) -> clap::Command {
        Self::command()
            .name(name)
            .bin_name(name)
            .about(about)
            .version(env!("CARGO_PKG_VERSION"))
    }

    /// The process's arguments as the program `name` reads them; on bad arguments or `--help`
    /// clap prints the message and exits.
    pub fn parse_named(name: &'static str, about: &'static str) -> Self {
        let matches = Self::named(name, about).get_matches();
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

    #[test]
    fn the_log_flag_is_global_and_counted() {
        let cmd = Program::<Tool>::named("tool", "a test program");
        cmd.clone().debug_assert();
        let m = cmd
            .try_get_matches_from(["tool", "one", "--value", "3", "-vv"])
            .unwrap();
        let p = Program::<Tool>::from_arg_matches(&m).unwrap();
        assert_eq!(p.log.verbose, 2);
        assert_eq!(p.command, Tool::One { value: 3 });
    }
}
