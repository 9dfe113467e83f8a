//! The `bake` command line: exit codes, messages, files.

use std::process::Command;

use mlt_test_support::TempDir;

fn bake() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bake"))
}

fn temp(name: &str) -> TempDir {
    TempDir::new(&format!("cli-{name}"))
}

#[test]
fn bakes_a_builtin_writes_stats_and_reports_info() {
    let d = temp("ok");
    let out = d.join("c.mlt");
    let stats = d.join("c.json");
    let r = bake()
        .args([
            "builtin:cornell",
            "--receiver-levels",
            "2",
            "--coarse-count",
            "20",
            "--threads",
            "2",
            "--sender-levels",
            "1",
            "--gather-rays",
            "64",
            "--epsilon",
            "0.01",
            "--bounces",
            "3",
            "-o",
        ])
        .arg(&out)
        .arg("--stats-json")
        .arg(&stats)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let err = String::from_utf8_lossy(&r.stderr);
    // Not a terminal: plain log lines per stage, then the table.
    assert!(err.contains("poisson disk:"), "{err}");
    assert!(err.contains("level   points"), "{err}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    let levels = json["meta"]["stats"]["levels"].as_array().unwrap();
    assert_eq!(levels.len(), 2);
    let t = &json["transport"];
    assert_eq!(t["params"]["epsilon"].as_f64().unwrap() as f32, 0.01);
    assert_eq!(t["params"]["sender_levels"], 1);
    assert_eq!(t["params"]["gather_rays"], 64);
    assert!(t["stats"]["links"].as_u64().unwrap() > 0);
    assert!(t["timings"]["refine_s"].as_f64().is_some());
    assert!(err.contains("links "), "{err}");
    assert_eq!(
        json["file_bytes"].as_u64().unwrap(),
        std::fs::metadata(&out).unwrap().len()
    );

    let r = bake().arg("info").arg(&out).arg("--json").output().unwrap();
    assert!(r.status.success());
    let info: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let version = format!(
        "{}.{}",
        mlt_format::container::VERSION_MAJOR,
        mlt_format::container::VERSION_MINOR
    );
    assert_eq!(info["format_version"], version.as_str());
    assert_eq!(info["meta"]["scene"]["source"], "builtin:cornell");
    let total: u64 = info["levels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| l["points"].as_u64().unwrap())
        .sum();
    assert_eq!(total, info["points"].as_u64().unwrap());
    let r = bake().arg("info").arg(&out).output().unwrap();
    let text = String::from_utf8_lossy(&r.stdout);
    assert!(
        text.contains("R_coarse") && text.contains("links"),
        "{text}"
    );

    // Table 1 next to the paper's Sponza row, from the file and from the statistics JSON.
    for input in [&out, &stats] {
        let r = bake()
            .arg("stats")
            .arg(input)
            .args(["--against", "paper:sponza"])
            .output()
            .unwrap();
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        let text = String::from_utf8_lossy(&r.stdout);
        assert!(
            text.contains("ratio") && text.contains("paper: Sponza"),
            "{text}"
        );
        assert!(
            text.lines().any(|l| l.starts_with("visibility rays")),
            "{text}"
        );
        // This small bake is not the paper's: the parameters that differ are named.
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(
            err.contains("not baked at the paper's settings")
                && err.contains("levels 2 (paper: 6)")
                && err.contains("bounces 3 (paper: 4)"),
            "{err}"
        );
        assert!(!err.contains("bounce mode"), "a fixed count: {err}");
    }
    // Against another bake, no warning.
    let r = bake()
        .arg("stats")
        .arg(&out)
        .arg("--against")
        .arg(&stats)
        .output()
        .unwrap();
    assert!(
        r.status.success() && r.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&r.stderr)
    );
    let r = bake()
        .arg("stats")
        .arg(&out)
        .args(["--against", "paper:sponza", "--json"])
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let links = v["columns"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["column"] == "links")
        .unwrap();
    let ours = links["numbers"][0].as_f64().unwrap();
    assert!((links["ratio"].as_f64().unwrap() - ours / 973000.0).abs() < 1e-9);
    let r = bake()
        .arg("stats")
        .arg(&out)
        .args(["--against", "paper:nowhere"])
        .output()
        .unwrap();
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("nowhere"));
}

#[test]
fn a_failed_bake_names_the_problem_and_leaves_the_old_output_alone() {
    let d = temp("fail");
    let out = d.join("keep.mlt");
    std::fs::write(&out, b"previous contents").unwrap();
    let bad = d.join("broken.obj");
    std::fs::write(&bad, "v 0 0 0\nv 1 0 0\nv 0 nan 1\nf 1 2 3\n").unwrap();
    let r = bake().arg(&bad).arg("-o").arg(&out).output().unwrap();
    assert!(!r.status.success());
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("broken.obj"), "{err}");
    assert_eq!(std::fs::read(&out).unwrap(), b"previous contents");

    let r = bake()
        .args(["builtin:sphere?albedo=0.5&colour=3"])
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("colour"));

    let r = bake()
        .args(["builtin:cornell", "--receiver-levels", "0"])
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("levels"));
}

#[test]
fn info_on_a_damaged_file_fails_with_its_name() {
    let d = temp("damaged");
    let f = d.join("trunc.mlt");
    let r = bake()
        .args([
            "builtin:cornell",
            "--receiver-levels",
            "1",
            "--coarse-count",
            "10",
            "-q",
            "-o",
        ])
        .arg(&f)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let bytes = std::fs::read(&f).unwrap();
    std::fs::write(&f, &bytes[..bytes.len() - 7]).unwrap();
    let r = bake().arg("info").arg(&f).output().unwrap();
    assert!(!r.status.success());
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        err.contains("trunc.mlt") && err.contains("truncated"),
        "{err}"
    );
}

#[test]
fn non_finite_numbers_and_bad_bounce_counts_on_the_command_line_are_named() {
    let d = temp("nan");
    let out = d.join("x.mlt");
    for (args, needle) in [
        (vec!["--epsilon", "NaN"], "epsilon"),
        (vec!["--bounce-epsilon", "inf"], "bounce epsilon"),
        (vec!["--coarse-radius=-inf"], "coarse radius"),
        (vec!["--bounce-tolerance", "nan"], "bounce tolerance"),
        (vec!["--bounces", "autox"], "auto"),
        (vec!["--bounces", "auto:0x"], "bounce count"),
        (vec!["--bounces", "0"], "bounces must be at least 1"),
    ] {
        let coarse: &[&str] = if args[0].starts_with("--coarse-radius") {
            &[]
        } else {
            &["--coarse-count", "12"]
        };
        let r = bake()
            .arg("builtin:sphere")
            .args(["--receiver-levels", "2"])
            .args(coarse)
            .args(&args)
            .arg("-o")
            .arg(&out)
            .output()
            .unwrap();
        assert!(!r.status.success(), "{args:?} accepted");
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(err.contains(needle), "{args:?}: {err}");
        assert!(!out.exists(), "{args:?} wrote a file");
    }
    // `auto` and `auto:N` parse, and the file records the choice (of the series: the chained
    // level-0 bounces, which the cap stops; traced ones would go deeper).
    let r = bake()
        .args([
            "builtin:sphere?albedo=0.8",
            "--level0-paths",
            "0",
            "--receiver-levels",
            "2",
            "--coarse-count",
            "12",
            "--sender-levels",
            "1",
            "--gather-rays",
            "32",
            "--epsilon",
            "1e-4",
            "--bounces",
            "auto:9",
            "--json",
            "-o",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let v: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    assert_eq!(v["report"]["bounce_mode"], "auto");
    assert_eq!(v["report"]["bounce_cap"], 9);
    // 0.8^9 = 13 % > 1 %: the cap stops the series, and the bake says so.
    assert_eq!(v["transport"]["stats"]["bounces"], 9);
    assert_eq!(v["report"]["error"]["series_converged"], false);
    assert!(String::from_utf8_lossy(&r.stderr).contains("cap of 9 bounces"));
}
