//! `bake --help` in a user's words: the everyday options, each in at most two lines at 100
//! columns; the tuning and diagnostic ones only under `--help-advanced`.

use std::collections::BTreeSet;

use mlt_test_support::help::{entries, help_of, too_long, ADVANCED};

fn help(args: &[&str]) -> String {
    help_of(env!("CARGO_BIN_EXE_bake"), args)
}

/// The names of a help's entries under `heading` (`under`), or under every other heading.
fn names(help: &str, heading: &str, under: bool) -> BTreeSet<String> {
    entries(help)
        .into_iter()
        .filter(|e| (e.heading == heading) == under)
        .map(|e| e.name().to_owned())
        .collect()
}

#[test]
fn every_help_is_short_and_hides_the_advanced_options_until_asked() {
    let root = help(&["--help"]);
    let subcommands = names(&root, "Commands", true);
    assert!(
        subcommands.contains("merge") && subcommands.contains("batch"),
        "{root}"
    );
    let commands = std::iter::once(None).chain(
        subcommands
            .iter()
            .filter(|s| *s != "help")
            .map(|s| Some(s.as_str())),
    );
    for sub in commands {
        let with = |flag| help(&sub.into_iter().chain([flag]).collect::<Vec<_>>());
        let (short, advanced) = (with("--help"), with("--help-advanced"));
        assert_eq!(short, with("-h"), "{sub:?}: -h and --help differ");
        for text in [&short, &advanced] {
            let bad = too_long(text);
            assert!(bad.is_empty(), "{sub:?}:\n{}\n\n{text}", bad.join("\n"));
            assert!(text.contains("docs/design.md#options-explained"), "{text}");
        }
        // --help-advanced lists --help's entries and the hidden ones, under their own heading.
        let hidden = names(&advanced, ADVANCED, true);
        let shown = names(&short, ADVANCED, false);
        assert_eq!(names(&advanced, ADVANCED, false), shown, "{sub:?}");
        assert!(hidden.is_disjoint(&shown), "{sub:?}: {hidden:?}");
        if sub.is_none() {
            for everyday in [
                "--preset",
                "--epsilon",
                "--bounces",
                "--coarse-count",
                "--seed",
            ] {
                assert!(shown.contains(everyday), "{everyday}: {shown:?}");
            }
            for tuning in [
                "--gather-rays",
                "--sender-levels",
                "--level0-paths",
                "--max-misses",
            ] {
                assert!(hidden.contains(tuning), "{tuning}: {hidden:?}");
            }
        }
    }
}
