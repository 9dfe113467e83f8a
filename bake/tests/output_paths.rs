//! Outputs are checked before any work: a bake, a shard, a batch or a merge aimed at a
//! directory that does not exist (or is a file) fails at once, naming the path.

use std::path::Path;
use std::process::Command;

/// A fresh directory, removed with its contents when dropped.
fn temp(name: &str) -> mlt_test_support::TempDir {
    mlt_test_support::TempDir::new(&format!("outpath-{name}"))
}

/// Runs `bake` with `args`; asserts it fails before its first stage (no `[  time] stage`
/// line: not even the scene was loaded) naming `path` on stderr.
fn fails_fast_naming(args: &[&std::ffi::OsStr], path: &Path) -> String {
    let r = Command::new(env!("CARGO_BIN_EXE_bake"))
        .args(args)
        .env_remove("RUST_BACKTRACE")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&r.stderr).into_owned();
    assert!(!r.status.success(), "{err}");
    assert!(
        !err.lines().any(|l| l.trim_start().starts_with('[')),
        "a stage ran before the output was checked: {err}"
    );
    assert!(err.contains(&path.display().to_string()), "{err}");
    err
}

#[test]
fn a_bake_into_a_missing_directory_fails_at_once() {
    let d = temp("bake");
    let out = d.join("missing").join("x.mlt");
    let err = fails_fast_naming(
        &["builtin:sphere".as_ref(), "-o".as_ref(), out.as_os_str()],
        &out,
    );
    assert!(err.contains("does not exist"), "{err}");
}

#[test]
fn statistics_into_a_directory_below_a_file_fail_at_once() {
    let d = temp("stats");
    let file = d.join("plain");
    std::fs::write(&file, b"x").unwrap();
    let stats = file.join("s.json");
    let out = d.join("x.mlt");
    let err = fails_fast_naming(
        &[
            "builtin:sphere".as_ref(),
            "-o".as_ref(),
            out.as_os_str(),
            "--stats-json".as_ref(),
            stats.as_os_str(),
        ],
        &stats,
    );
    assert!(err.contains("not a directory"), "{err}");
    assert!(!out.exists());
}

#[test]
fn a_shard_into_a_missing_directory_fails_at_once() {
    let d = temp("shard");
    let out = d.join("missing").join("s0.mlt");
    fails_fast_naming(
        &[
            "builtin:cornell".as_ref(),
            "--shard".as_ref(),
            "0/2".as_ref(),
            "-o".as_ref(),
            out.as_os_str(),
        ],
        &out,
    );
}

#[test]
fn a_merge_into_a_missing_directory_fails_before_reading_the_shards() {
    let d = temp("merge");
    let out = d.join("missing").join("m.mlt");
    let shard = d.join("no-such-shard.mlt");
    fails_fast_naming(
        &[
            "merge".as_ref(),
            shard.as_os_str(),
            "-o".as_ref(),
            out.as_os_str(),
        ],
        &out,
    );
}

#[test]
fn a_batch_whose_output_directory_cannot_be_made_fails_at_once() {
    let d = temp("batch");
    let manifest = d.join("job.toml");
    std::fs::write(
        &manifest,
        "[[job]]\nname = \"s\"\nscene = \"builtin:sphere\"\n",
    )
    .unwrap();
    let file = d.join("plain");
    std::fs::write(&file, b"x").unwrap();
    let out_dir = file.join("out");
    fails_fast_naming(
        &[
            "batch".as_ref(),
            manifest.as_os_str(),
            "--out-dir".as_ref(),
            out_dir.as_os_str(),
        ],
        &out_dir,
    );
    // A file given as the output directory.
    fails_fast_naming(
        &[
            "batch".as_ref(),
            manifest.as_os_str(),
            "--out-dir".as_ref(),
            file.as_os_str(),
        ],
        &file,
    );
}
