//! `view`: the viewer of baked files (Lehtinen et al. 2008, sections 3.3 and 4.1).
//!
//! - `view open FILE` (or `view FILE`): a window (winit + wgpu) with a free camera and a
//!   movable light;
//! - `view render FILE --out DIR`: the same rendering without a window, writing direct.exr,
//!   indirect.exr, final.exr (linear radiance), final.png (tone mapped) and timings.json;
//!   `--frames N` moves the light along a fixed path and reports medians, `--reference SPP`
//!   adds the path-traced reference;
//! - `view probe FILE --probe IN.csv --probe-out OUT.csv`: irradiance at given surface points;
//! - `view timings FILE --frames N`: CPU relighting timings only;
//! - `view reference INPUT --out DIR`: the brute-force path-traced reference of a file or scene;
//! - `view compare REF TEST`: the error of a rendering (or probes) against the reference;
//! - `view flat FILE`: the flat basis in one view (functions per pixel, error against the
//!   exact evaluation).

mod cmd;

use std::ffi::OsString;
use std::process::ExitCode;

use clap::{CommandFactory, Parser, Subcommand};

use mlt_help as help;

use cmd::compare::CompareArgs;
use cmd::flat::FlatArgs;
use cmd::open::OpenArgs;
use cmd::probe::ProbeCmdArgs;
use cmd::reference::ReferenceArgs;
use cmd::render::RenderArgs;
use cmd::timings::TimingsArgs;

/// Views a baked light-transport file: window, headless images, probes, timings, and the
/// path-traced reference to compare them with.
#[derive(Parser)]
#[command(
    name = "view",
    version,
    after_help = "`view FILE` is short for `view open FILE`."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Open a window with a free camera and a movable light.
    Open(OpenArgs),
    /// Render images without a window into --out.
    Render(RenderArgs),
    /// Write the relit irradiance at probe points.
    Probe(ProbeCmdArgs),
    /// Time the CPU relighting over frames with a moving light (no GPU).
    Timings(TimingsArgs),
    /// Render the brute-force path-traced reference of a file or scene.
    Reference(ReferenceArgs),
    /// Compare a rendering (or probes) against the reference.
    Compare(CompareArgs),
    /// Measure the flat basis in one view: coverage per pixel, error against the exact image.
    Flat(FlatArgs),
}

/// The arguments with `open` inserted when the first one is neither a subcommand nor an
/// option, so that `view FILE` opens the window.
fn with_default_command(args: Vec<OsString>) -> Vec<OsString> {
    let known = Cli::command();
    let shorthand = match args.get(1).map(|a| a.to_str()) {
        None => false,
        // Not UTF-8: a path, not a subcommand.
        Some(None) => true,
        Some(Some(a)) => {
            !a.starts_with('-') && a != "help" && known.get_subcommands().all(|c| c.get_name() != a)
        }
    };
    if !shorthand {
        return args;
    }
    let mut out = Vec::with_capacity(args.len() + 1);
    out.push(args[0].clone());
    out.push("open".into());
    out.extend(args.into_iter().skip(1));
    out
}

/// Whether to turn Mesa's Vulkan device-selection layer off, given the environment `var`.
///
/// The layer is an implicit Vulkan layer, active wherever Mesa's Vulkan drivers are installed.
/// When an instance enables the Wayland surface extension, as wgpu's does, it connects to the
/// Wayland display to find the display's GPU; without `XDG_RUNTIME_DIR` (a headless machine,
/// CI, a container) libwayland then prints "error: XDG_RUNTIME_DIR is invalid or not set in
/// the environment." for every instance, although nothing is wrong. There is no display to
/// choose a GPU for then, so the layer goes off by its own switch (`NODEVICE_SELECT=1`),
/// unless the user chose a device through it (`MESA_VK_DEVICE_SELECT`) or set the switch.
fn device_select_off(var: impl Fn(&str) -> Option<OsString>) -> bool {
    let unset = |k: &str| var(k).is_none_or(|v| v.is_empty());
    unset("XDG_RUNTIME_DIR") && unset("MESA_VK_DEVICE_SELECT") && var("NODEVICE_SELECT").is_none()
}

fn main() -> ExitCode {
    if device_select_off(|k| std::env::var_os(k)) {
        // Sound: the first statement of `main`, before any other thread exists that could
        // read the environment while it changes.
        std::env::set_var("NODEVICE_SELECT", "1");
    }
    let cli: Cli = help::parse(
        help::command(Cli::command()),
        with_default_command(std::env::args_os().collect()),
    );
    help::exit_status(match &cli.command {
        Command::Open(a) => cmd::open::run(a),
        Command::Render(a) => cmd::render::run(a),
        Command::Probe(a) => cmd::probe::run(a),
        Command::Timings(a) => cmd::timings::run(a),
        Command::Reference(a) => cmd::reference::run(a),
        Command::Compare(a) => cmd::compare::run(a),
        Command::Flat(a) => cmd::flat::run(a),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(v: &[&str]) -> Vec<OsString> {
        v.iter().map(OsString::from).collect()
    }

    #[test]
    fn a_bare_file_opens_the_window_and_subcommands_pass_through() {
        assert_eq!(
            with_default_command(args(&["view", "a.mlt", "--width", "8"])),
            args(&["view", "open", "a.mlt", "--width", "8"])
        );
        for given in [
            &["view", "render", "a.mlt", "--out", "d"][..],
            &["view", "--help"],
            &["view", "help"],
            &["view"],
        ] {
            assert_eq!(with_default_command(args(given)), args(given));
        }
        let cli = Cli::try_parse_from(with_default_command(args(&["view", "a.mlt"]))).unwrap();
        assert!(matches!(cli.command, Command::Open(ref o) if o.baked.file.as_os_str() == "a.mlt"));
    }

    #[test]
    fn the_device_selection_layer_goes_off_only_without_a_runtime_dir_or_a_choice() {
        let env = |vars: &'static [(&'static str, &'static str)]| {
            move |k: &str| {
                vars.iter()
                    .find(|(name, _)| *name == k)
                    .map(|(_, v)| OsString::from(v))
            }
        };
        assert!(device_select_off(env(&[])));
        assert!(device_select_off(env(&[("XDG_RUNTIME_DIR", "")])));
        assert!(device_select_off(env(&[("DISPLAY", ":99")])));
        assert!(!device_select_off(env(&[(
            "XDG_RUNTIME_DIR",
            "/run/user/1000"
        )])));
        assert!(!device_select_off(env(&[(
            "MESA_VK_DEVICE_SELECT",
            "10de:2684"
        )])));
        assert!(!device_select_off(env(&[("NODEVICE_SELECT", "0")])));
    }

    #[test]
    fn the_command_line_is_consistent() {
        help::command(Cli::command()).debug_assert();
    }
}
