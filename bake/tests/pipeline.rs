//! `bake` in build pipelines: batch mode, incremental skips, determinism, shards and merge,
//! interrupts.

use std::path::{Path, PathBuf};
use std::process::Command;

use mlt_test_support::TempDir;

fn bake() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bake"))
}

fn temp(name: &str) -> TempDir {
    TempDir::new(&format!("pipe-{name}"))
}

fn run(cmd: &mut Command) -> std::process::Output {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

const SMALL: [&str; 6] = [
    "--receiver-levels",
    "3",
    "--coarse-count",
    "30",
    "--gather-rays",
    "64",
];

#[test]
fn batch_bakes_reports_failures_and_skips_what_is_up_to_date() {
    let d = temp("batch");
    let manifest = d.join("jobs.toml");
    std::fs::write(
        &manifest,
        r#"
[[job]]
name = "box"
scene = "builtin:box?albedo=0.7"
receiver_levels = 2
coarse_count = 20
gather_rays = 64

[[job]]
name = "divergent"
scene = "builtin:sphere?albedo=1.5"
receiver_levels = 2
coarse_count = 10
epsilon = 0.00001

[[job]]
name = "cornell"
scene = "builtin:cornell"
receiver_levels = 2
coarse_count = 20
gather_rays = 64
"#,
    )
    .unwrap();
    let out_dir = d.join("out");
    let r = bake()
        .arg("batch")
        .arg(&manifest)
        .arg("--out-dir")
        .arg(&out_dir)
        .args(["--jobs", "2", "--json"])
        .output()
        .unwrap();
    // One job failed: non-zero exit, after the others finished.
    assert_eq!(
        r.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&r.stderr)
    );
    let summary: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    assert_eq!(
        (summary["baked"].as_u64(), summary["failed"].as_u64()),
        (Some(2), Some(1))
    );
    let jobs = summary["jobs"].as_array().unwrap();
    let failed = jobs.iter().find(|j| j["status"] == "failed").unwrap();
    assert_eq!(failed["name"], "divergent");
    // Refused before any work, naming the albedo.
    let error = failed["error"].as_str().unwrap();
    assert!(
        error.contains("albedo [1.5, 1.5, 1.5], not below 1"),
        "{error}"
    );
    for name in ["box", "cornell"] {
        assert!(out_dir.join(format!("{name}.mlt")).is_file());
        let stats: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out_dir.join(format!("{name}.json"))).unwrap(),
        )
        .unwrap();
        assert!(stats["transport"]["stats"]["links"].as_u64().is_some());
    }
    assert!(!out_dir.join("divergent.mlt").exists());
    let md = std::fs::read_to_string(out_dir.join("summary.md")).unwrap();
    assert!(
        md.contains("| divergent | failed |") && md.contains("| box | baked |"),
        "{md}"
    );

    // Again: the two good outputs are up to date and skipped, untouched.
    let before = std::fs::metadata(out_dir.join("box.mlt"))
        .unwrap()
        .modified()
        .unwrap();
    let r = bake()
        .arg("batch")
        .arg(&manifest)
        .arg("--out-dir")
        .arg(&out_dir)
        .args(["--json", "-q"])
        .output()
        .unwrap();
    let summary: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    assert_eq!(summary["skipped"].as_u64(), Some(2));
    assert_eq!(
        std::fs::metadata(out_dir.join("box.mlt"))
            .unwrap()
            .modified()
            .unwrap(),
        before
    );
    // The key in the header is the one the summary reports.
    let info = run(bake()
        .arg("info")
        .arg(out_dir.join("box.mlt"))
        .arg("--json"));
    let info: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    let job = summary["jobs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|j| j["name"] == "box")
        .unwrap();
    assert_eq!(info["input_key"], job["input_key"]);

    // A changed parameter changes the key: that job is baked again, the other skipped.
    let text = std::fs::read_to_string(&manifest).unwrap().replacen(
        "gather_rays = 64",
        "gather_rays = 32",
        1,
    );
    std::fs::write(&manifest, text).unwrap();
    let r = bake()
        .arg("batch")
        .arg(&manifest)
        .arg("--out-dir")
        .arg(&out_dir)
        .args(["--json", "-q"])
        .output()
        .unwrap();
    let summary: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let status = |n: &str| {
        summary["jobs"]
            .as_array()
            .unwrap()
            .iter()
            .find(|j| j["name"] == n)
            .unwrap()["status"]
            .clone()
    };
    assert_eq!(
        (status("box"), status("cornell")),
        ("baked".into(), "skipped".into())
    );
}

fn bytes_of(d: &Path, scene: &str, threads: &str, name: &str) -> Vec<u8> {
    let f = d.join(name);
    run(bake()
        .arg(scene)
        .args(SMALL)
        .args(["--threads", threads, "-q", "-o"])
        .arg(&f));
    std::fs::read(&f).unwrap()
}

#[test]
fn outputs_are_byte_identical_across_runs_and_thread_counts() {
    let d = temp("determinism");
    for scene in ["builtin:cornell", "builtin:box?albedo=0.6"] {
        let a = bytes_of(&d, scene, "1", "a.mlt");
        let b = bytes_of(&d, scene, "2", "b.mlt");
        let c = bytes_of(&d, scene, "2", "c.mlt");
        assert!(a == b && b == c, "{scene}: outputs differ");
    }
}

/// Bakes the small Cornell box with `extra` arguments as `n` shards (`{tag}s{i}of{n}.mlt` in
/// `d`) and merges them with the scene (the default bake's traced level-0 bounces need it),
/// given last first (any order is allowed); returns the shard files in index order and the
/// merged file.
fn shards_merged(d: &Path, extra: &[&str], n: u32, tag: &str) -> (Vec<PathBuf>, PathBuf) {
    let mut files = Vec::new();
    for i in 0..n {
        let f = d.join(format!("{tag}s{i}of{n}.mlt"));
        run(bake()
            .arg("builtin:cornell")
            .args(SMALL)
            .args(extra)
            .args(["--shard", &format!("{i}/{n}"), "-q", "-o"])
            .arg(&f));
        files.push(f);
    }
    let merged = d.join(format!("{tag}merged{n}.mlt"));
    run(bake()
        .arg("merge")
        .args(files.iter().rev())
        .args(["--scene", "builtin:cornell"])
        .arg("-o")
        .arg(&merged)
        .arg("-q"));
    (files, merged)
}

/// `--level0-paths` changes the file and says so (`TBNC`, the statistics). Its paths end in
/// the whole of T, so the merge traces them with the scene: the single bake's file, byte for
/// byte; without the scene, or with another, the merge refuses. A shard without paths does not
/// merge with one with.
#[test]
fn merged_shards_with_path_traced_bounces_equal_the_single_bake() {
    let d = temp("shards-paths");
    let paths = ["--level0-paths", "64"];
    let single = |extra: &[&str], name: &str| {
        let f = d.join(name);
        run(bake()
            .arg("builtin:cornell")
            .args(SMALL)
            .args(extra)
            .args(["-q", "-o"])
            .arg(&f));
        std::fs::read(&f).unwrap()
    };
    let full = single(&paths, "full.mlt");
    let chained = single(&["--level0-paths", "0"], "chained.mlt");
    assert!(full != chained, "--level0-paths changed nothing");
    // The default traces them too, and the paper's preset chains them.
    let method_of = |extra: &[&str], name: &str| {
        single(extra, name);
        mlt_format::BakedFile::open(&d.join(name))
            .unwrap()
            .bounce_method()
            .unwrap()
            .map(|b| b.level0_paths)
    };
    assert_eq!(
        method_of(&[], "default.mlt"),
        Some(mlt_bake::params::DEFAULT_LEVEL0_PATHS)
    );
    assert_eq!(method_of(&["--preset", "paper"], "paper.mlt"), None);
    // The file says how its level-0 bounces were computed (`TBNC`), a chained one does not.
    let method = |name: &str| {
        mlt_format::BakedFile::open(&d.join(name))
            .unwrap()
            .bounce_method()
            .unwrap()
    };
    let traced = method("full.mlt").expect("no TBNC section");
    assert_eq!(
        (traced.level0_paths, traced.max_vertex),
        (64, mlt_bake::params::DEFAULT_AUTO_BOUNCE_CAP)
    );
    assert_eq!(method("chained.mlt"), None);
    // So do the bake's statistics.
    let json = d.join("full.json");
    run(bake()
        .arg("builtin:cornell")
        .args(SMALL)
        .args(paths)
        .args(["-q", "-o"])
        .arg(d.join("full2.mlt"))
        .arg("--stats-json")
        .arg(&json));
    let stats: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(stats["bounce_method"]["level0_paths"], 64);
    let (files, merged) = shards_merged(&d, &paths, 3, "paths");
    assert!(
        std::fs::read(&merged).unwrap() == full,
        "the merge differs from the single bake"
    );
    let merge_fails = |extra: &[&str], what: &str| {
        let out = d.join("refused.mlt");
        let r = bake()
            .arg("merge")
            .args(&files)
            .args(extra)
            .args(["-q", "-o"])
            .arg(&out)
            .output()
            .unwrap();
        assert!(!r.status.success());
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(err.contains(what), "{err}");
        assert!(!out.exists());
    };
    merge_fails(&[], "--scene");
    merge_fails(&["--scene", "builtin:sphere"], "not the shards' scene");
    let other = d.join("chained1.mlt");
    run(bake()
        .arg("builtin:cornell")
        .args(SMALL)
        .args(["--level0-paths", "0", "--shard", "1/3", "-q", "-o"])
        .arg(&other));
    merge_refused_as_another_bake(&d, &[&files[0], &other, &files[2]]);
    // The option and the bounces of every receiver exclude each other.
    let r = bake()
        .arg("builtin:cornell")
        .args(SMALL)
        .args(paths)
        .args(["--bounces-on-all-receivers", "-q", "-o"])
        .arg(d.join("y.mlt"))
        .output()
        .unwrap();
    assert!(!r.status.success());
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("--bounces-on-all-receivers"), "{err}");
}

/// With `--bounces auto` the shards carry the policy and the merge chooses the same count.
#[test]
fn merged_shards_with_auto_bounces_equal_the_single_bake() {
    let d = temp("shards-auto");
    let auto = ["--bounces", "auto:40", "--bounce-tolerance", "0.02"];
    let full = d.join("full.mlt");
    run(bake()
        .arg("builtin:cornell")
        .args(SMALL)
        .args(auto)
        .args(["-q", "-o"])
        .arg(&full));
    let (files, merged) = shards_merged(&d, &auto, 2, "auto");
    assert!(
        std::fs::read(&merged).unwrap() == std::fs::read(&full).unwrap(),
        "the merge differs from the single bake"
    );
    let report = mlt_format::BakedFile::open(&merged)
        .unwrap()
        .transport_report()
        .unwrap()
        .unwrap();
    assert_eq!(report.bounce_mode, "auto");
    assert_eq!(report.bounce_cap, 40);
    assert_eq!(report.bounce_tolerance, 0.02);
    // A shard of a fixed-count bake does not merge with one of an automatic bake.
    let fixed = d.join("fixed1.mlt");
    run(bake()
        .arg("builtin:cornell")
        .args(SMALL)
        .args(["--shard", "1/2", "-q", "-o"])
        .arg(&fixed));
    merge_refused_as_another_bake(&d, &[&files[0], &fixed]);
}

/// `bake merge` of `files` into `d/x.mlt` fails, saying a shard belongs to another bake.
fn merge_refused_as_another_bake(d: &Path, files: &[&PathBuf]) {
    let r = bake()
        .arg("merge")
        .args(files)
        .arg("-o")
        .arg(d.join("x.mlt"))
        .output()
        .unwrap();
    assert!(!r.status.success());
    assert!(
        String::from_utf8_lossy(&r.stderr).contains("another bake"),
        "{}",
        String::from_utf8_lossy(&r.stderr)
    );
}

#[test]
fn merged_shards_equal_the_single_bake_for_one_two_and_three_shards() {
    let d = temp("shards");
    let full = d.join("full.mlt");
    run(bake()
        .arg("builtin:cornell")
        .args(SMALL)
        .args(["-q", "-o"])
        .arg(&full));
    let expected = std::fs::read(&full).unwrap();
    // The single bake stores the flat basis (`FLT2`); so, byte for byte, does every merge.
    let f = mlt_format::BakedFile::open(&full).unwrap();
    assert!(f.flat_section().unwrap().is_some(), "no FLT2 section");
    for n in 1..=3u32 {
        let (_, merged) = shards_merged(&d, &[], n, "");
        assert!(
            std::fs::read(&merged).unwrap() == expected,
            "{n} shards: the merge differs from the single bake"
        );
    }
    // Incomplete or mixed sets are refused.
    let r = bake()
        .arg("merge")
        .arg(d.join("s0of2.mlt"))
        .arg("-o")
        .arg(d.join("x.mlt"))
        .output()
        .unwrap();
    assert!(!r.status.success());
    // One line that names the missing shard, also where a farm sets RUST_BACKTRACE.
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("shard 1/2 missing"), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    let r = bake()
        .env("RUST_BACKTRACE", "1")
        .arg("merge")
        .arg(d.join("s0of2.mlt"))
        .arg(d.join("s0of2.mlt"))
        .arg("-o")
        .arg(d.join("x.mlt"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        err.contains("shard 0/2 is given twice") && err.contains("s0of2.mlt"),
        "{err}"
    );
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(!d.join("x.mlt").exists());
    let r = bake()
        .args(["builtin:cornell", "--shard", "3/3", "-o"])
        .arg(d.join("x.mlt"))
        .output()
        .unwrap();
    assert!(!r.status.success());
}

#[test]
fn an_interrupt_leaves_no_partial_or_temporary_file() {
    let d = temp("interrupt");
    let out = d.join("cornell.mlt");
    std::fs::write(&out, b"previous").unwrap();
    // A bake long enough to be interrupted mid-way.
    let mut child = bake()
        .args(["builtin:cornell", "--receiver-levels", "6", "-q", "-o"])
        .arg(&out)
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(1500));
    let pid = child.id().to_string();
    let killed = Command::new("kill").args(["-INT", &pid]).status().unwrap();
    assert!(killed.success());
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130));
    assert_eq!(std::fs::read(&out).unwrap(), b"previous");
    let leftovers: Vec<_> = std::fs::read_dir(&d)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name() != "cornell.mlt")
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

/// A scene whose shading normals lean from their faces (untextured Sponza: about 10k such
/// vertices) gives its receivers different numbers of gather rays (those below the face are
/// not cast): the merged file's statistics must count each shard's own rays, so that it is
/// the single bake's, byte for byte. (Counting a nominal number per refined receiver made
/// the ray count, and so the file, differ.)
#[test]
fn merged_shards_of_a_scene_with_leaning_normals_equal_the_single_bake() {
    let d = temp("shards-leaning");
    let obj = mlt_test_support::shared_scene("sponza_dabrovic/sponza_with_materials.obj");
    let tiny = [
        "--receiver-levels",
        "2",
        "--coarse-count",
        "30",
        "--gather-rays",
        "16",
        "--level0-paths",
        "0",
    ];
    let mut files = Vec::new();
    for i in 0..2 {
        let f = d.join(format!("s{i}.mlt"));
        run(bake()
            .arg(&obj)
            .args(tiny)
            .args(["--shard", &format!("{i}/2"), "-q", "-o"])
            .arg(&f));
        files.push(f);
    }
    let merged = d.join("merged.mlt");
    // With the scene, so that the merge checks the light at the camera as the single bake does.
    run(bake()
        .arg("merge")
        .args(&files)
        .arg("--scene")
        .arg(&obj)
        .arg("-q")
        .arg("-o")
        .arg(&merged));
    let single = d.join("single.mlt");
    run(bake().arg(&obj).args(tiny).arg("-q").arg("-o").arg(&single));
    assert!(
        std::fs::read(&merged).unwrap() == std::fs::read(&single).unwrap(),
        "the merged file differs from the single bake"
    );
}
