//! The command-line help of `bake` and `view`: `--help` in a user's words, and
//! `--help-advanced`, the same help with the tuning and diagnostic options shown as well.
//!
//! Those options are hidden (`#[arg(hide = true)]`), so that `--help` lists what a user needs;
//! `--help-advanced`, on the command and on each subcommand, prints the same help with the
//! hidden options shown under [`ADVANCED`]. Both binaries build their clap command through
//! [`command`], parse with [`parse`] and end with [`exit_status`], which prints an error as one
//! line.

use std::ffi::OsString;
use std::fmt::Display;
use std::process::ExitCode;

use clap::{Arg, ArgAction, Command, FromArgMatches};

/// The heading of the hidden options in `--help-advanced`.
pub const ADVANCED: &str = "Advanced (tuning and diagnostics)";
/// The last line of every command's help: where each option is explained at length.
pub const MORE: &str = "More on each option: docs/design.md#options-explained";
/// The help is wrapped at the terminal's width, at most this many columns.
pub const MAX_WIDTH: usize = 100;

/// The exit status of a command that returned `result`: success, or 1 after printing the error
/// and its causes on one line (`error: what: why`, with `{:#}`, the alternate form that anyhow
/// and most error types give their chain in). A `main` returning `Result` would print the error's
/// `Debug` form instead, which for anyhow adds a backtrace when `RUST_BACKTRACE` is set, as it
/// often is on build farms: a shard's log should say what failed and where in one readable line.
/// A panic keeps Rust's own message (and its backtrace where asked for).
pub fn exit_status<E: Display>(result: Result<(), E>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// `command` with `--help-advanced` on it and on every subcommand, and [`MORE`] at the end of
/// each one's help, wrapped at most at [`MAX_WIDTH`].
pub fn command(command: Command) -> Command {
    with_pointer(command).arg(
        Arg::new("help_advanced")
            .long("help-advanced")
            .global(true)
            .action(ArgAction::SetTrue)
            .display_order(999)
            .help("Print help with the tuning and diagnostic options too"),
    )
}

/// `command` and its subcommands with [`MORE`] after their help, wrapped at [`MAX_WIDTH`].
fn with_pointer(command: Command) -> Command {
    let after = match command.get_after_help() {
        Some(text) => format!("{text}\n{MORE}"),
        None => MORE.to_owned(),
    };
    let command = command.max_term_width(MAX_WIDTH).after_help(after);
    each_subcommand(command, with_pointer)
}

/// The command line `args` parsed as `T` by `command` (from [`command`]): help, the advanced
/// help and errors are printed, and the process exits.
pub fn parse<T: FromArgMatches>(command: Command, args: Vec<OsString>) -> T {
    if asks_advanced(&args) {
        // Best effort, as clap's own help: a closed standard output is no error here.
        let _ = advanced(command, &args).print_help();
        std::process::exit(0);
    }
    let mut matches = command.clone().get_matches_from(args);
    T::from_arg_matches_mut(&mut matches).unwrap_or_else(|e| e.format(&mut command.clone()).exit())
}

/// Whether the command line (program name first) asks for the advanced help.
pub fn asks_advanced(args: &[OsString]) -> bool {
    args.iter()
        .skip(1)
        .take_while(|a| *a != "--")
        .any(|a| a == "--help-advanced")
}

/// The (sub)command that `args` names (each leading word that names a subcommand of the one
/// before), built, with every hidden option shown under [`ADVANCED`]; its `print_help` or
/// `render_help` is the advanced help.
pub fn advanced(command: Command, args: &[OsString]) -> Command {
    let mut command = show_hidden(command);
    command.build();
    for a in args.iter().skip(1) {
        let Some(a) = a.to_str() else { break };
        if a == "--" {
            break;
        }
        if a.starts_with('-') {
            continue;
        }
        match command.find_subcommand(a).cloned() {
            Some(sub) => command = sub,
            None => break,
        }
    }
    command
}

/// `command` and its subcommands with the hidden options shown under [`ADVANCED`].
fn show_hidden(command: Command) -> Command {
    let command = command.mut_args(|a| match a.is_hide_set() {
        true => a.hide(false).help_heading(ADVANCED),
        false => a,
    });
    each_subcommand(command, show_hidden)
}

/// `command` with `f` applied to each of its subcommands.
fn each_subcommand(command: Command, f: fn(Command) -> Command) -> Command {
    let names: Vec<String> = command
        .get_subcommands()
        .map(|s| s.get_name().to_owned())
        .collect();
    names
        .iter()
        .fold(command, |c, name| c.mut_subcommand(name, f))
}
