//! `bake [SCENE]`: loads a scene, bakes it and writes the file, with statistics.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use mlt_bake::batch::stats_json;
use mlt_bake::report::{bake_table, estimate_table, transport_table};
use mlt_bake::{bake_scene, BakeOutput, Observer};
use mlt_format::WriteOptions;

use super::watch_for_interrupts;
use crate::cli::BakeArgs;
use crate::progress::Reporter;

pub fn run(args: BakeArgs) -> Result<()> {
    let spec = args
        .scene
        .clone()
        .unwrap_or_else(|| "builtin:cornell".into());
    let output = args.output.clone().unwrap_or_else(|| default_output(&spec));
    mlt_bake::output_check::files(std::iter::once(&output).chain(&args.stats_json))?;
    let mut builder = rayon::ThreadPoolBuilder::new();
    if let Some(t) = args.threads {
        anyhow::ensure!(t >= 1, "--threads must be at least 1");
        builder = builder.num_threads(t);
    }
    let pool = builder.build().context("starting the worker threads")?;
    let reporter = Reporter::new(args.quiet);
    let out_dir = match output.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    watch_for_interrupts(&out_dir);

    let t = Instant::now();
    let scene = mlt_scenes::load_scene(&spec).with_context(|| format!("loading scene {spec}"))?;
    let load_s = t.elapsed().as_secs_f64();
    reporter.line(&format!(
        "loaded {spec}: {} triangles ({load_s:.2} s)",
        scene.triangle_count()
    ));
    for w in &scene.warnings {
        reporter.warn(w);
    }

    let mut out = pool
        .install(|| bake_scene(&scene, &args.options, &reporter))
        .with_context(|| format!("baking {spec}"))?;
    out.timings.load_s = load_s;
    out.timings.total_s += load_s;
    if let Some(t) = out.contents.meta.timings.as_mut() {
        t.load_s = load_s;
        t.total_s = out.timings.total_s;
    }

    let t = Instant::now();
    let size = mlt_format::file::write(
        &output,
        &out.contents,
        WriteOptions {
            compress: args.options.compress,
        },
    )
    .with_context(|| format!("writing {}", output.display()))?;
    out.timings.write_s = t.elapsed().as_secs_f64();
    out.timings.total_s += out.timings.write_s;
    report(&args, &output, size, &out)
}

/// The statistics: tables on standard error (unless quiet), the JSON to `--stats-json`, and
/// the output path (or with `--json`, the JSON) on standard output.
fn report(args: &BakeArgs, output: &Path, size: u64, out: &BakeOutput) -> Result<()> {
    if !args.quiet {
        eprint!("{}", bake_table(&out.contents.meta, &out.timings, size));
        if let Some(t) = &out.contents.transport {
            eprint!(
                "{}",
                transport_table(&t.meta, out.transport_timings.as_ref())
            );
            if let Some(r) = &t.report {
                eprint!(
                    "{}",
                    estimate_table(r, t.drop.as_ref(), t.camera_check.as_ref())
                );
            }
        }
    }
    let json = stats_json(output, size, out);
    let text = serde_json::to_string_pretty(&json).context("formatting statistics")?;
    if let Some(path) = &args.stats_json {
        mlt_format::file::write_atomic(path, text.as_bytes())
            .with_context(|| format!("writing statistics to {}", path.display()))?;
    }
    if let (false, Some(s)) = (args.quiet, &out.contents.shard) {
        eprintln!(
            "shard {}/{}: {} receivers, {} links of T (combine all shards with `bake merge`)",
            s.index,
            s.count,
            s.rows.len(),
            s.senders.len()
        );
    }
    if args.json {
        println!("{text}");
    } else {
        println!("{}", output.display());
    }
    Ok(())
}

/// The scene's name with extension `.mlt`, in the current directory.
fn default_output(spec: &str) -> PathBuf {
    let stem = match spec.strip_prefix("builtin:") {
        Some(rest) => rest.split('?').next().unwrap_or("builtin").to_string(),
        None => Path::new(spec)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "scene".into()),
    };
    PathBuf::from(format!("{stem}.mlt"))
}
