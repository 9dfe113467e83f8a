//! `bake`: scene in, versioned memory-mappable basis file out.
//!
//! - [`cli`]: the command line (the bake's parameters are [`mlt_bake::BakeOptions`]);
//! - [`help`]: `--help-advanced`, the help with the tuning and diagnostic options;
//! - [`progress`]: the progress reporter;
//! - [`commands`]: the bake and the subcommands `merge`, `batch`, `stats` and `info`.

mod cli;
mod commands;
mod help;
mod progress;

use anyhow::Result;
use clap::CommandFactory;

use cli::{Cli, Command};

fn main() -> Result<()> {
    let cli: Cli = help::parse(help::command(Cli::command()), std::env::args_os().collect());
    match cli.command {
        Some(Command::Merge(args)) => commands::merge::run(&args),
        Some(Command::Batch(args)) => commands::batch::run(&args),
        Some(Command::Info(args)) => commands::info::run(&args),
        Some(Command::Stats(args)) => commands::stats::run(&args),
        None => commands::bake::run(cli.bake),
    }
}
