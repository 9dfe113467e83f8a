//! The printed help of `bake` and `view` (clap's `--help` and `--help-advanced`), read back
//! entry by entry, so that their tests can hold each option's help to two lines.

use std::collections::BTreeSet;
use std::ffi::OsStr;
use std::process::{Command, Stdio};

pub use mlt_help::ADVANCED;

/// The width the help is printed at in the tests, the commands' widest.
pub const WIDTH: usize = mlt_help::MAX_WIDTH;

/// One entry of a help: an argument, option or subcommand.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Entry {
    /// The heading it is listed under (`Options`, `Arguments`, `Commands`, ...).
    pub heading: String,
    /// What names it: `-o, --output <FILE>`, `[SCENE]`, `merge`.
    pub spec: String,
    /// The lines its help takes.
    pub lines: usize,
}

impl Entry {
    /// Its long flag (`--output`), or for an argument or subcommand its spec.
    pub fn name(&self) -> &str {
        self.spec
            .split([' ', ','])
            .find(|w| w.starts_with("--"))
            .unwrap_or(&self.spec)
    }
}

/// The standard output of `program args`, as a user's 100-column terminal shows it (the
/// help is wrapped at `COLUMNS` when it is no terminal); panics unless it succeeds.
pub fn help_of(program: impl AsRef<OsStr>, args: &[&str]) -> String {
    let out = Command::new(program)
        .args(args)
        .env("COLUMNS", WIDTH.to_string())
        .stdin(Stdio::null())
        .output()
        .expect("runs");
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("UTF-8")
}

/// The entries of a printed help: under each heading (a line `Name:` at the margin), the lines
/// indented up to 6 columns start an entry, deeper ones continue its help.
pub fn entries(help: &str) -> Vec<Entry> {
    let mut out: Vec<Entry> = Vec::new();
    let mut heading: Option<String> = None;
    let mut open = false;
    for line in help.lines() {
        let indent = line.len() - line.trim_start().len();
        let text = line.trim();
        if text.is_empty() {
            open = false;
        } else if indent == 0 {
            open = false;
            heading = text.strip_suffix(':').map(str::to_owned);
        } else if let Some(h) = &heading {
            if indent <= 6 {
                // The spec, then (two spaces on) the help's first line, if on the same line.
                let (spec, rest) = text.split_once("  ").unwrap_or((text, ""));
                out.push(Entry {
                    heading: h.clone(),
                    spec: spec.to_owned(),
                    lines: usize::from(!rest.trim().is_empty()),
                });
                open = true;
            } else if open {
                out.last_mut().expect("an entry").lines += 1;
            }
        }
    }
    out
}

/// What is wrong with a printed help: a line over [`WIDTH`] columns, or an entry whose help
/// takes over two lines.
pub fn too_long(help: &str) -> Vec<String> {
    let wide = help
        .lines()
        .filter(|l| l.chars().count() > WIDTH)
        .map(|l| format!("over {WIDTH} columns: {l}"));
    let long = entries(help)
        .into_iter()
        .filter(|e| e.lines > 2)
        .map(|e| format!("{} lines of help: {}", e.lines, e.spec));
    wide.chain(long).collect()
}

/// The names of a help's entries under `heading` (`under`), or under every other heading.
pub fn names(help: &str, heading: &str, under: bool) -> BTreeSet<String> {
    entries(help)
        .into_iter()
        .filter(|e| (e.heading == heading) == under)
        .map(|e| e.name().to_owned())
        .collect()
}

/// One command's help, as [`every_command`] read it.
#[derive(Clone, Debug)]
pub struct CommandHelp {
    /// The subcommand, or `None` for the program itself.
    pub sub: Option<String>,
    /// The entries `--help` lists.
    pub shown: BTreeSet<String>,
    /// The entries only `--help-advanced` lists, under [`ADVANCED`].
    pub hidden: BTreeSet<String>,
}

/// The root `--help` of `program` and the help of it and of each of its subcommands, after
/// asserting what every command's help holds to: `-h` is `--help`; neither help nor the
/// advanced help has a line over [`WIDTH`] columns or an entry over two lines, and each ends
/// with [`mlt_help::MORE`]; `--help-advanced` lists `--help`'s entries and, under
/// [`ADVANCED`] only, the hidden ones.
pub fn every_command(program: impl AsRef<OsStr>) -> (String, Vec<CommandHelp>) {
    let program = program.as_ref();
    let root = help_of(program, &["--help"]);
    let subcommands = names(&root, "Commands", true);
    let commands =
        std::iter::once(None).chain(subcommands.into_iter().filter(|s| s != "help").map(Some));
    let helps = commands
        .map(|sub| {
            let with = |flag| {
                let args: Vec<&str> = sub.as_deref().into_iter().chain([flag]).collect();
                help_of(program, &args)
            };
            let (short, advanced) = (with("--help"), with("--help-advanced"));
            assert_eq!(short, with("-h"), "{sub:?}: -h and --help differ");
            for text in [&short, &advanced] {
                let bad = too_long(text);
                assert!(bad.is_empty(), "{sub:?}:\n{}\n\n{text}", bad.join("\n"));
                assert!(text.trim_end().ends_with(mlt_help::MORE), "{text}");
            }
            let hidden = names(&advanced, ADVANCED, true);
            let shown = names(&short, ADVANCED, false);
            assert_eq!(names(&advanced, ADVANCED, false), shown, "{sub:?}");
            assert!(hidden.is_disjoint(&shown), "{sub:?}: {hidden:?}");
            CommandHelp { sub, shown, hidden }
        })
        .collect();
    (root, helps)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entries_are_read_in_both_layouts() {
        let help = "About it\n\nUsage: x [OPTIONS] [SCENE]\n\nCommands:\n  merge  Merges\n\n\
                    Arguments:\n  [SCENE]  A scene\n           (default: a box)\n\nOptions:\n  \
                    -o, --output <FILE>  Output\n      --long <N>\n          One\n          Two\n\
                    \x20         Three\n\nMore: there\n";
        let e = entries(help);
        let got: Vec<_> = e
            .iter()
            .map(|e| (e.heading.as_str(), e.name(), e.lines))
            .collect();
        assert_eq!(
            got,
            [
                ("Commands", "merge", 1),
                ("Arguments", "[SCENE]", 2),
                ("Options", "--output", 1),
                ("Options", "--long", 3),
            ]
        );
        assert_eq!(too_long(help), ["3 lines of help: --long <N>"]);
    }
}
