//! `bake --help` in a user's words: the everyday options, each in at most two lines at 100
//! columns; the tuning and diagnostic ones only under `--help-advanced`.

use mlt_test_support::help::{every_command, names};

#[test]
fn every_help_is_short_and_hides_the_advanced_options_until_asked() {
    let (root, helps) = every_command(env!("CARGO_BIN_EXE_bake"));
    let subcommands = names(&root, "Commands", true);
    assert!(
        subcommands.contains("merge") && subcommands.contains("batch"),
        "{root}"
    );
    assert_eq!(helps.len(), subcommands.len(), "{root}");
    let bake = helps
        .iter()
        .find(|h| h.sub.is_none())
        .expect("bake's own help");
    for everyday in [
        "--preset",
        "--epsilon",
        "--bounces",
        "--coarse-count",
        "--seed",
    ] {
        assert!(
            bake.shown.contains(everyday),
            "{everyday}: {:?}",
            bake.shown
        );
    }
    for tuning in [
        "--gather-rays",
        "--sender-levels",
        "--level0-paths",
        "--max-misses",
    ] {
        assert!(bake.hidden.contains(tuning), "{tuning}: {:?}", bake.hidden);
    }
}
