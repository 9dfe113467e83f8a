//! `bake batch`: every job of the given manifests, with a summary.

use std::time::Instant;

use anyhow::{Context, Result};
use mlt_bake::batch::{read_jobs, run_batch, summary_markdown, BatchSettings};
use mlt_bake::Observer;

use super::watch_for_interrupts;
use crate::cli::BatchArgs;
use crate::progress::Reporter;

pub fn run(args: &BatchArgs) -> Result<()> {
    let mut all = Vec::new();
    for m in &args.manifests {
        all.extend(read_jobs(m).with_context(|| format!("reading {}", m.display()))?);
    }
    watch_for_interrupts(&args.out_dir);
    let settings = BatchSettings {
        out_dir: args.out_dir.clone(),
        jobs: args.jobs,
        threads: args.threads.unwrap_or_else(|| {
            std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1)
        }),
        record_timings: args.record_timings,
        compress: args.compress,
        force: args.force,
    };
    let start = Instant::now();
    let quiet = args.quiet;
    let observer = |name: &str| -> Box<dyn Observer> {
        let mut r = Reporter::new(quiet);
        r.start = start;
        r.prefix = format!("{name}: ");
        Box::new(r)
    };
    let summary = run_batch(&all, &settings, &observer).context("running the batch")?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        print!("{}", summary_markdown(&summary));
    }
    if summary.failed > 0 {
        let names: Vec<&str> = summary
            .jobs
            .iter()
            .filter(|j| j.status == "failed")
            .map(|j| j.name.as_str())
            .collect();
        eprintln!(
            "error: {} of {} jobs failed: {}",
            summary.failed,
            summary.jobs.len(),
            names.join(", ")
        );
        std::process::exit(1);
    }
    Ok(())
}
