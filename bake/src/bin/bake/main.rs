//! `bake`: scene in, versioned memory-mappable basis file out.
//!
//! - [`cli`]: the command line (the bake's parameters are [`mlt_bake::BakeOptions`]);
//! - [`progress`]: the progress reporter;
//! - [`commands`]: the bake and the subcommands `merge`, `batch`, `stats` and `info`.

mod cli;
mod commands;
mod progress;

use anyhow::Result;
use clap::Parser;

use cli::{Cli, Command};

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Merge(args)) => commands::merge::run(&args),
        Some(Command::Batch(args)) => commands::batch::run(&args),
        Some(Command::Info(args)) => commands::info::run(&args),
        Some(Command::Stats(args)) => commands::stats::run(&args),
        None => commands::bake::run(cli.bake),
    }
}
