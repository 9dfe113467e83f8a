//! Batch baking (`bake batch`): every job of the given manifests, one file and one statistics
//! JSON per job, a summary in JSON and Markdown; incremental by input key.
//!
//! A manifest is either a scene manifest (one job, named after the file) or a batch manifest
//! listing jobs:
//!
//! ```toml
//! [[job]]
//! name = "cornell-eps-0.01"      # unique; the output is NAME.mlt and NAME.json
//! scene = "cornell.toml"         # a manifest, mesh or builtin: name; paths relative to this file
//! receiver_levels = 4            # any key of a manifest's [bake] table (BakeOptions)
//! epsilon = 0.01
//! ```

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use mlt_format::{BakedFile, WriteOptions};
use serde::Serialize;

use crate::error::BakeError;
use crate::observer::Observer;
use crate::params::BakeOptions;
use crate::pipeline::{bake_scene, input_key, BakeOutput};
use crate::table1::{our_row, Table1Row};

/// One job of a batch manifest: its name, its scene and its bake options (any key of
/// [`BakeOptions`] that a manifest's `[bake]` table takes).
#[derive(Clone, Debug, Default)]
pub struct JobSpec {
    pub name: String,
    pub scene: String,
    pub options: BakeOptions,
}

/// Reads the jobs of `manifest`, with scene paths made relative to the current directory.
pub fn read_jobs(manifest: &Path) -> Result<Vec<JobSpec>, BakeError> {
    let bad = |message: String| BakeError::Batch {
        path: manifest.to_path_buf(),
        message,
    };
    let text = std::fs::read_to_string(manifest).map_err(|e| bad(e.to_string()))?;
    let mut value: toml::Table = toml::from_str(&text).map_err(|e| bad(e.to_string()))?;
    let dir = manifest.parent().unwrap_or(Path::new(""));
    let Some(jobs) = value.remove("job") else {
        // A scene manifest: one job named after the file.
        let name = manifest
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .ok_or_else(|| bad("no file name".into()))?;
        return Ok(vec![JobSpec {
            name,
            scene: manifest.display().to_string(),
            ..Default::default()
        }]);
    };
    if let Some(key) = value.keys().next() {
        return Err(bad(format!(
            "unknown key `{key}`: a batch manifest holds [[job]] tables only"
        )));
    }
    let toml::Value::Array(jobs) = jobs else {
        return Err(bad("`job` must be [[job]] tables".into()));
    };
    let mut out = Vec::with_capacity(jobs.len());
    for (k, job) in jobs.into_iter().enumerate() {
        let toml::Value::Table(mut table) = job else {
            return Err(bad(format!("job {}: not a table", k + 1)));
        };
        let mut text_key = |key: &str| match table.remove(key) {
            Some(toml::Value::String(s)) => Ok(s),
            Some(_) => Err(bad(format!("job {}: `{key}` must be a string", k + 1))),
            None => Err(bad(format!("job {}: missing `{key}`", k + 1))),
        };
        let name = text_key("name")?;
        let mut scene = text_key("scene")?;
        if name.is_empty()
            || !name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
        {
            return Err(bad(format!(
                "job name '{name}' must be non-empty letters, digits, '-', '_' or '.'"
            )));
        }
        if !scene.starts_with("builtin:") && Path::new(&scene).is_relative() {
            scene = dir.join(&scene).display().to_string();
        }
        let options = BakeOptions::from_table(table, manifest, &format!("job '{name}'"))?;
        out.push(JobSpec {
            name,
            scene,
            options,
        });
    }
    Ok(out)
}

/// What happened to one job.
#[derive(Clone, Debug, Serialize)]
pub struct JobResult {
    pub name: String,
    pub scene: String,
    /// `baked`, `skipped` (output up to date) or `failed`.
    pub status: String,
    pub error: Option<String>,
    pub input_key: Option<String>,
    pub file: String,
    pub file_bytes: Option<u64>,
    pub seconds: f64,
    pub table1: Option<Table1Row>,
    pub warnings: Vec<String>,
}

/// The summary of a batch.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub tool: String,
    pub jobs: Vec<JobResult>,
    pub baked: usize,
    pub skipped: usize,
    pub failed: usize,
}

/// Settings of a batch run.
pub struct BatchSettings {
    pub out_dir: PathBuf,
    /// Jobs baked at once.
    pub jobs: usize,
    /// Worker threads in all (shared out among the concurrent jobs).
    pub threads: usize,
    pub record_timings: bool,
    pub compress: bool,
    /// Bake even when the output is up to date.
    pub force: bool,
}

/// Statistics JSON of one bake (the same as `bake --stats-json`).
pub fn stats_json(file: &Path, file_bytes: u64, out: &BakeOutput) -> serde_json::Value {
    serde_json::json!({
        "file": file.display().to_string(),
        "file_bytes": file_bytes,
        "input_key": format!("{:016x}", out.contents.input_key),
        "meta": &out.contents.meta,
        "timings": &out.timings,
        "transport": out.contents.transport.as_ref().map(|t| {
            let mut m = t.meta.clone();
            m.timings = out.transport_timings.clone();
            m
        }),
        "report": out.contents.transport.as_ref().and_then(|t| t.report.as_ref()),
        "refinement_drop": out.contents.transport.as_ref().and_then(|t| t.drop.as_ref()),
        "bounce_method": out.contents.transport.as_ref().and_then(|t| t.bounces.as_ref()),
        "camera_check": out.contents.transport.as_ref().and_then(|t| t.camera_check.as_ref()),
        "camera_blocks": out.contents.transport.as_ref().and_then(|t| t.camera_blocks.as_ref()),
        "error_estimate_total": out.contents.transport.as_ref().and_then(|t| {
            t.report
                .as_ref()
                .map(|r| crate::report::estimate_total(r, t.drop.as_ref(), t.camera_check.as_ref()))
        }),
        "warnings": &out.warnings,
    })
}

/// Runs every job; a failed job does not stop the others. `observer(name)` gives each job its
/// progress reporter.
pub fn run_batch(
    jobs: &[JobSpec],
    settings: &BatchSettings,
    observer: &(dyn Fn(&str) -> Box<dyn Observer> + Sync),
) -> Result<Summary, BakeError> {
    std::fs::create_dir_all(&settings.out_dir).map_err(|e| BakeError::Batch {
        path: settings.out_dir.clone(),
        message: format!("cannot create the output directory: {e}"),
    })?;
    crate::output_check::directory(&settings.out_dir).map_err(|e| BakeError::Batch {
        path: e.path,
        message: e.reason,
    })?;
    let mut seen = std::collections::BTreeSet::new();
    for j in jobs {
        if !seen.insert(j.name.as_str()) {
            return Err(BakeError::Batch {
                path: settings.out_dir.clone(),
                message: format!("two jobs are named '{}'", j.name),
            });
        }
    }
    let concurrent = settings.jobs.clamp(1, jobs.len().max(1));
    let per_job = (settings.threads / concurrent).max(1);
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<JobResult>>> = Mutex::new(vec![None; jobs.len()]);
    std::thread::scope(|s| {
        for _ in 0..concurrent {
            s.spawn(|| loop {
                let k = next.fetch_add(1, Ordering::SeqCst);
                if k >= jobs.len() {
                    break;
                }
                let r = run_job(
                    &jobs[k],
                    settings,
                    per_job,
                    observer(&jobs[k].name).as_ref(),
                );
                if let Ok(mut v) = results.lock() {
                    v[k] = Some(r);
                }
            });
        }
    });
    let jobs: Vec<JobResult> = results
        .into_inner()
        .unwrap_or_default()
        .into_iter()
        .flatten()
        .collect();
    let count = |s: &str| jobs.iter().filter(|j| j.status == s).count();
    let summary = Summary {
        tool: crate::pipeline::tool_version(),
        baked: count("baked"),
        skipped: count("skipped"),
        failed: count("failed"),
        jobs,
    };
    let io = |path: &Path, e: mlt_format::FormatError| BakeError::Batch {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let json_path = settings.out_dir.join("summary.json");
    let text = serde_json::to_string_pretty(&summary).unwrap_or_default();
    mlt_format::file::write_atomic(&json_path, text.as_bytes()).map_err(|e| io(&json_path, e))?;
    let md_path = settings.out_dir.join("summary.md");
    mlt_format::file::write_atomic(&md_path, summary_markdown(&summary).as_bytes())
        .map_err(|e| io(&md_path, e))?;
    Ok(summary)
}

fn run_job(
    job: &JobSpec,
    settings: &BatchSettings,
    threads: usize,
    obs: &dyn Observer,
) -> JobResult {
    let start = Instant::now();
    let file = settings.out_dir.join(format!("{}.mlt", job.name));
    let stats = settings.out_dir.join(format!("{}.json", job.name));
    let mut result = JobResult {
        name: job.name.clone(),
        scene: job.scene.clone(),
        status: "failed".into(),
        error: None,
        input_key: None,
        file: file.display().to_string(),
        file_bytes: None,
        seconds: 0.0,
        table1: None,
        warnings: Vec::new(),
    };
    let outcome = (|| -> Result<(), BakeError> {
        let scene = mlt_scenes::load_scene(&job.scene)?;
        // The batch's command line over the job (and, in `bake_scene`, over the manifest).
        let command_line = BakeOptions {
            record_timings: settings.record_timings,
            compress: settings.compress,
            ..Default::default()
        };
        let opts = command_line.or(&job.options);
        let key = input_key(&scene, &opts)?;
        result.input_key = Some(format!("{key:016x}"));
        if !settings.force && stats.exists() {
            if let Ok(f) = BakedFile::open(&file) {
                if f.header().input_key == key {
                    obs.done(
                        "up to date",
                        0.0,
                        &format!("{} has input key {key:016x}", file.display()),
                    );
                    let meta = f.meta()?;
                    let tm = f.transport_meta()?;
                    result.table1 =
                        Some(our_row(&meta, tm.as_ref(), Some(f.file_len()), None, None));
                    result.file_bytes = Some(f.file_len());
                    result.status = "skipped".into();
                    return Ok(());
                }
            }
        }
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .map_err(|e| BakeError::InvalidParameter(format!("thread pool: {e}")))?;
        let out = pool.install(|| bake_scene(&scene, &opts, obs))?;
        let size = mlt_format::file::write(
            &file,
            &out.contents,
            WriteOptions {
                compress: opts.compress,
            },
        )?;
        let json = serde_json::to_string_pretty(&stats_json(&file, size, &out)).unwrap_or_default();
        mlt_format::file::write_atomic(&stats, json.as_bytes())?;
        let mut row = our_row(
            &out.contents.meta,
            out.contents.transport.as_ref().map(|t| &t.meta),
            Some(size),
            Some(&out.timings),
            out.transport_timings.as_ref(),
        );
        row.title = job.name.clone();
        result.table1 = Some(row);
        result.file_bytes = Some(size);
        result.warnings = out.warnings;
        result.status = "baked".into();
        Ok(())
    })();
    if let Err(e) = outcome {
        obs.warn(&e.to_string());
        result.error = Some(e.to_string());
    }
    result.seconds = start.elapsed().as_secs_f64();
    result
}

/// The summary as a Markdown table.
pub fn summary_markdown(s: &Summary) -> String {
    let mut o = format!(
        "# Batch summary ({})\n\n{} baked, {} skipped (up to date), {} failed.\n\n",
        s.tool, s.baked, s.skipped, s.failed
    );
    o.push_str("| job | status | triangles | points (level 0 / total) | links | links / potential | visibility rays | time (s) | file (MB) | error |\n");
    o.push_str("|---|---|---:|---:|---:|---:|---:|---:|---:|---|\n");
    for j in &s.jobs {
        let (tri, pts, links, share, rays) = match &j.table1 {
            Some(r) => (
                r.triangles.to_string(),
                format!("{} / {}", r.level0_points, r.total_points),
                r.links.to_string(),
                format!("{:.4} %", r.link_share_percent),
                r.visibility_rays.to_string(),
            ),
            None => ("-".into(), "-".into(), "-".into(), "-".into(), "-".into()),
        };
        o.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {:.1} | {} | {} |\n",
            j.name,
            j.status,
            tri,
            pts,
            links,
            share,
            rays,
            j.seconds,
            j.file_bytes
                .map(|b| format!("{:.2}", b as f64 / 1e6))
                .unwrap_or_else(|| "-".into()),
            j.error
                .as_deref()
                .unwrap_or("")
                .replace('|', "\\|")
                .replace('\n', " ")
        ));
    }
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fresh directory, removed with its contents when dropped.
    fn temp(name: &str) -> mlt_test_support::TempDir {
        mlt_test_support::TempDir::new(&format!("batch-{name}"))
    }

    const MANIFEST: &str =
        "[scene]\nsource = \"builtin:cornell\"\n\n[bake]\nreceiver_levels = 4\nseed = 7\nepsilon = 0.1\n";

    #[test]
    fn the_command_line_beats_the_job_which_beats_the_manifest() {
        let d = temp("layers");
        std::fs::write(d.join("room.toml"), MANIFEST).unwrap();
        let jobs = d.join("jobs.toml");
        std::fs::write(
            &jobs,
            "[[job]]\nname = \"a\"\nscene = \"room.toml\"\nreceiver_levels = 3\nseed = 8\n",
        )
        .unwrap();
        let job = read_jobs(&jobs).unwrap().remove(0);
        let scene = mlt_scenes::load_scene(&job.scene).unwrap();
        let key = |o: &BakeOptions| input_key(&scene, o).unwrap();
        let explicit = |levels, seed| BakeOptions {
            receiver_levels: Some(levels),
            seed: Some(seed),
            epsilon: Some(0.1),
            ..Default::default()
        };
        assert_eq!(key(&BakeOptions::default()), key(&explicit(4, 7)));
        assert_eq!(key(&job.options), key(&explicit(3, 8)));
        let command_line = BakeOptions {
            seed: Some(9),
            ..Default::default()
        };
        assert_eq!(key(&command_line.or(&job.options)), key(&explicit(3, 9)));
        assert_ne!(key(&job.options), key(&BakeOptions::default()));
    }

    #[test]
    fn unknown_keys_of_jobs_and_manifests_are_errors_naming_the_file() {
        let d = temp("unknown");
        let jobs = d.join("jobs.toml");
        std::fs::write(
            &jobs,
            "[[job]]\nname = \"a\"\nscene = \"builtin:cornell\"\nbounce = 3\n",
        )
        .unwrap();
        let e = read_jobs(&jobs).unwrap_err().to_string();
        assert!(e.contains("jobs.toml") && e.contains("bounce"), "{e}");

        let manifest = d.join("room.toml");
        std::fs::write(&manifest, MANIFEST.replace("seed = 7", "sead = 7")).unwrap();
        let scene = mlt_scenes::load_scene(&manifest.to_string_lossy()).unwrap();
        let e = input_key(&scene, &BakeOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("room.toml") && e.contains("sead"), "{e}");
        // A scene manifest given to the batch is one job; its [bake] table fails that job.
        let job = read_jobs(&manifest).unwrap().remove(0);
        assert_eq!(job.name, "room");
    }
}
