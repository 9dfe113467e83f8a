//! `bake stats`: the paper's Table-1 columns of bakes, side by side, optionally against the
//! paper's row or another bake.

use std::path::Path;

use anyhow::{Context, Result};
use mlt_bake::table1::{compare_json, compare_text, our_row, paper_row, Table1Row};
use mlt_format::BakedFile;

use crate::cli::StatsArgs;

pub fn run(args: &StatsArgs) -> Result<()> {
    let mut rows = args
        .files
        .iter()
        .map(|f| load_row(f))
        .collect::<Result<Vec<_>>>()?;
    if let Some(a) = &args.against {
        let other = match a.strip_prefix("paper:") {
            Some(name) => {
                let mut r = paper_row(name).with_context(|| {
                    format!("no paper row '{name}' (known: sponza, greathall, jadepalace)")
                })?;
                r.title = format!("paper: {}", r.title);
                r
            }
            None => load_row(Path::new(a))?,
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

/// A Table-1 row from a baked file or a `--stats-json` output.
fn load_row(path: &Path) -> Result<Table1Row> {
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
    let mut row = our_row(&meta, transport.as_ref(), Some(f.file_len()), None, None);
    row.title = path.display().to_string();
    Ok(row)
}

/// A Table-1 row from a `--stats-json` output.
fn load_json_row(path: &Path) -> Result<Table1Row> {
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
    let mut row = our_row(
        &meta,
        transport.as_ref(),
        v["file_bytes"].as_u64(),
        timings.as_ref(),
        None,
    );
    row.title = path.display().to_string();
    Ok(row)
}
