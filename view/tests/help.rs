//! `view SUBCOMMAND --help` in a user's words: the everyday options, each in at most two lines
//! at 100 columns; the tuning and diagnostic ones only under `--help-advanced`.

use mlt_test_support::help::{every_command, help_of};

fn help(args: &[&str]) -> String {
    help_of(env!("CARGO_BIN_EXE_view"), args)
}

#[test]
fn every_help_is_short_and_hides_the_advanced_options_until_asked() {
    let (root, helps) = every_command(env!("CARGO_BIN_EXE_view"));
    // scripts/check_identical.sh looks for the subcommand so.
    assert!(root.lines().any(|l| l.starts_with("  render ")), "{root}");
    assert!(helps.len() >= 8, "{root}");
    for h in &helps {
        match h.sub.as_deref() {
            Some("render") => {
                for everyday in ["--out", "--spp", "--frames", "--reference", "--light-pos"] {
                    assert!(h.shown.contains(everyday), "{everyday}: {:?}", h.shown);
                }
                for tuning in [
                    "--bounce-feedback",
                    "--flat-rule",
                    "--shadow-rays",
                    "--oracle",
                ] {
                    assert!(h.hidden.contains(tuning), "{tuning}: {:?}", h.hidden);
                }
            }
            Some("timings") => assert!(h.shown.contains("--feedback-lag"), "{:?}", h.shown),
            _ => {}
        }
    }
    // `view FILE` is `view open FILE`, for the advanced help too.
    assert_eq!(
        help(&["f.mlt", "--help-advanced"]),
        help(&["open", "--help-advanced"])
    );
}
