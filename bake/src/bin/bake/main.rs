//! `bake`: scene in, versioned memory-mappable basis file out.
//!
//! - [`cli`]: the command line (the bake's parameters are [`mlt_bake::BakeOptions`]; the help
//!   and `--help-advanced` are [`mlt_help`]'s);
//! - [`progress`]: the progress reporter;
//! - [`commands`]: the bake and the subcommands `merge`, `batch`, `stats` and `info`.

mod cli;
mod commands;
mod progress;

use std::process::ExitCode;

use clap::CommandFactory;

use cli::{Cli, Command};

fn main() -> ExitCode {
    let cli: Cli = mlt_help::parse(
        mlt_help::command(Cli::command()),
        std::env::args_os().collect(),
    );
    mlt_help::exit_status(match cli.command {
        Some(Command::Merge(args)) => commands::merge::run(&args),
        Some(Command::Batch(args)) => commands::batch::run(&args),
        Some(Command::Info(args)) => commands::info::run(&args),
        Some(Command::Stats(args)) => commands::stats::run(&args),
        None => commands::bake::run(cli.bake),
    })
}
