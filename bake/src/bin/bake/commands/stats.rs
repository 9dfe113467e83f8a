//! `bake stats`: the paper's Table-1 columns of bakes, side by side, optionally against the
//! paper's row or another bake. Against a paper row, each bake not made at the paper's
//! settings (`--preset paper`) is warned about on stderr, with the parameters that differ.

use std::path::Path;

use anyhow::{Context, Result};
use mlt_bake::params::paper_preset_differences;
use mlt_bake::table1::{compare_json, compare_text, our_row, paper_row, Table1Row};
use mlt_format::meta::{BounceMethod, TransportMeta, TransportReport};
use mlt_format::{BakedFile, Meta};

use crate::cli::StatsArgs;

pub fn run(args: &StatsArgs) -> Result<()> {
    let loaded = args
        .files
        .iter()
        .map(|f| load_row(f))
        .collect::<Result<Vec<_>>>()?;
    let against_paper = args
        .against
        .as_ref()
        .is_some_and(|a| a.starts_with("paper:"));
    let mut rows = Vec::with_capacity(loaded.len() + 1);
    for (row, differences) in loaded {
        if against_paper && !differences.is_empty() {
            eprintln!(
                "warning: {} was not baked at the paper's settings (--preset paper): {}",
                row.title,
                differences.join(", ")
            );
        }
        rows.push(row);
    }
    if let Some(a) = &args.against {
        let other = match a.strip_prefix("paper:") {
            Some(name) => {
                let mut r = paper_row(name).with_context(|| {
                    format!("no paper row '{name}' (known: sponza, greathall, jadepalace)")
                })?;
                r.title = format!("paper: {}", r.title);
                r
            }
            None => load_row(Path::new(a))?.0,
        };
        rows.push(other);
    }
    let refs: Vec<&Table1Row> = rows.iter().collect();
    if args.json {
        println!("{}", serde_json::to_string_pretty(&compare_json(&refs))?);
    } else {
        print!("{}", compare_text(&refs));
    }
    Ok(())
}

/// A Table-1 row from a baked file or a `--stats-json` output, and how its parameters
/// differ from the paper's.
fn load_row(path: &Path) -> Result<(Table1Row, Vec<String>)> {
    if path.extension().is_some_and(|e| e == "json") {
        return load_json_row(path);
    }
    let f = BakedFile::open(path).with_context(|| format!("opening {}", path.display()))?;
    let meta = f
        .meta()
        .with_context(|| format!("reading {}", path.display()))?;
    let transport = f
        .transport_meta()
        .with_context(|| format!("reading {}", path.display()))?;
    let report = f
        .transport_report()
        .with_context(|| format!("reading {}", path.display()))?;
    let bounces = f
        .bounce_method()
        .with_context(|| format!("reading {}", path.display()))?;
    let mut row = our_row(&meta, transport.as_ref(), Some(f.file_len()), None, None);
    row.title = path.display().to_string();
    Ok((row, differences(&meta, &transport, &report, bounces)))
}

/// [`paper_preset_differences`] of a bake's metadata.
fn differences(
    meta: &Meta,
    transport: &Option<TransportMeta>,
    report: &Option<TransportReport>,
    bounces: Option<BounceMethod>,
) -> Vec<String> {
    paper_preset_differences(
        &meta.params,
        transport.as_ref().map(|t| &t.params),
        report.as_ref().map(|r| r.bounce_mode.as_str()),
        bounces.map_or(0, |b| b.level0_paths),
    )
}

/// A Table-1 row from a `--stats-json` output, and how its parameters differ from the
/// paper's.
fn load_json_row(path: &Path) -> Result<(Table1Row, Vec<String>)> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let v: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))?;
    let meta: mlt_format::Meta = serde_json::from_value(v["meta"].clone())
        .with_context(|| format!("{}: no bake statistics in it", path.display()))?;
    let transport: Option<mlt_format::meta::TransportMeta> =
        serde_json::from_value(v["transport"].clone()).unwrap_or(None);
    let timings: Option<mlt_format::meta::Timings> =
        serde_json::from_value(v["timings"].clone()).ok();
    let report: Option<TransportReport> =
        serde_json::from_value(v["report"].clone()).unwrap_or(None);
    let mut row = our_row(
        &meta,
        transport.as_ref(),
        v["file_bytes"].as_u64(),
        timings.as_ref(),
        None,
    );
    let bounces: Option<BounceMethod> =
        serde_json::from_value(v["bounce_method"].clone()).unwrap_or(None);
    row.title = path.display().to_string();
    Ok((row, differences(&meta, &transport, &report, bounces)))
}
