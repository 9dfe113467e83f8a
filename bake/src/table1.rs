//! The columns of the paper's Table 1, for our bakes and for the paper's rows (kept as data in
//! `bake/data/paper_table1.json`), and side-by-side comparisons with ratios.

use std::fmt::Write;

use mlt_format::meta::{Meta, Timings, TransportMeta, TransportTimings};
use serde::{Deserialize, Serialize};

/// One row of Table 1 (times and memory may be unknown).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Table1Row {
    pub scene: String,
    #[serde(default)]
    pub title: String,
    pub triangles: u64,
    pub links: u64,
    pub link_share_percent: f64,
    pub visibility_rays: u64,
    pub receiver_levels: u32,
    pub sender_levels: u32,
    pub level0_points: u64,
    pub total_points: u64,
    pub refine_s: Option<f64>,
    pub bounces_s: Option<f64>,
    pub total_s: Option<f64>,
    /// Basis plus links, MB (10^6 bytes), as the paper's "memory consumption".
    pub memory_mb: Option<f64>,
    #[serde(default)]
    pub file_mb: Option<f64>,
    #[serde(default)]
    pub peak_rss_mb: Option<f64>,
}

#[derive(Deserialize)]
struct PaperTable {
    rows: Vec<Table1Row>,
}

/// The paper's rows.
pub fn paper_rows() -> Vec<Table1Row> {
    serde_json::from_str::<PaperTable>(include_str!("../data/paper_table1.json"))
        .map(|t| t.rows)
        .unwrap_or_default()
}

/// The paper's row for `name` (sponza, greathall, jadepalace).
pub fn paper_row(name: &str) -> Option<Table1Row> {
    paper_rows().into_iter().find(|r| r.scene == name)
}

/// Our row from a file's metadata (and timings, when known).
pub fn our_row(
    meta: &Meta,
    transport: Option<&TransportMeta>,
    file_bytes: Option<u64>,
    basis_timings: Option<&Timings>,
    transport_timings: Option<&TransportTimings>,
) -> Table1Row {
    let s = &meta.stats;
    let tt = transport_timings.or(transport.and_then(|t| t.timings.as_ref()));
    let bt = basis_timings.or(meta.timings.as_ref());
    let mut row = Table1Row {
        scene: meta.scene.source.clone(),
        title: meta.scene.source.clone(),
        triangles: meta.scene.triangles,
        receiver_levels: meta.params.levels,
        level0_points: s.levels.first().map(|l| l.points).unwrap_or(0),
        total_points: s.points,
        file_mb: file_bytes.map(|b| b as f64 / 1e6),
        total_s: bt.map(|t| t.total_s),
        ..Default::default()
    };
    if let Some(t) = transport {
        let ts = &t.stats;
        row.links = ts.links;
        row.link_share_percent = 100.0 * ts.links as f64 / ts.potential_links.max(1) as f64;
        row.visibility_rays = ts.visibility_rays;
        row.sender_levels = t.params.sender_levels;
        row.memory_mb = Some((ts.basis_bytes + ts.links_bytes) as f64 / 1e6);
    }
    if let Some(t) = tt {
        row.refine_s = Some(t.refine_s);
        row.bounces_s = Some(t.bounces_s);
        row.peak_rss_mb = Some(t.peak_rss_bytes as f64 / 1e6);
    }
    row
}

fn mins(s: Option<f64>) -> String {
    match s {
        Some(s) => format!("{}:{:04.1}", (s / 60.0).floor() as u64, s % 60.0),
        None => "-".into(),
    }
}

fn opt(v: Option<f64>, prec: usize) -> String {
    v.map(|x| format!("{x:.prec$}"))
        .unwrap_or_else(|| "-".into())
}

fn ratio(a: Option<f64>, b: Option<f64>) -> String {
    match (a, b) {
        (Some(a), Some(b)) if b != 0.0 => format!("{:.3}", a / b),
        _ => "-".into(),
    }
}

/// The Table-1 columns of `rows` as (name, formatted values, numeric values).
/// A column: its name, formatted values, and numeric values (for ratios).
type Column = (&'static str, Vec<String>, Vec<Option<f64>>);

fn columns(rows: &[&Table1Row]) -> Vec<Column> {
    let col = |name, f: &dyn Fn(&Table1Row) -> (String, Option<f64>)| {
        let (s, v): (Vec<String>, Vec<Option<f64>>) = rows.iter().map(|r| f(r)).unzip();
        (name, s, v)
    };
    vec![
        col("triangles", &|r| {
            (r.triangles.to_string(), Some(r.triangles as f64))
        }),
        col("links", &|r| (r.links.to_string(), Some(r.links as f64))),
        col("links / potential (%)", &|r| {
            (
                format!("{:.4}", r.link_share_percent),
                Some(r.link_share_percent),
            )
        }),
        col("visibility rays", &|r| {
            (
                r.visibility_rays.to_string(),
                Some(r.visibility_rays as f64),
            )
        }),
        col("levels (rcvr/sndr)", &|r| {
            (format!("{}/{}", r.receiver_levels, r.sender_levels), None)
        }),
        col("basis functions, level 0", &|r| {
            (r.level0_points.to_string(), Some(r.level0_points as f64))
        }),
        col("basis functions, total", &|r| {
            (r.total_points.to_string(), Some(r.total_points as f64))
        }),
        col("adaptive refinement (m:s)", &|r| {
            (mins(r.refine_s), r.refine_s)
        }),
        col("indirect bounces (m:s)", &|r| {
            (mins(r.bounces_s), r.bounces_s)
        }),
        col("total time (m:s)", &|r| (mins(r.total_s), r.total_s)),
        col("memory, basis + links (MB)", &|r| {
            (opt(r.memory_mb, 1), r.memory_mb)
        }),
        col("file (MB)", &|r| (opt(r.file_mb, 1), r.file_mb)),
        col("peak memory (MB)", &|r| {
            (opt(r.peak_rss_mb, 1), r.peak_rss_mb)
        }),
    ]
}

/// A table of rows side by side; with exactly two rows, a third column of ratios (first over
/// second).
pub fn compare_text(rows: &[&Table1Row]) -> String {
    let mut o = String::new();
    let _ = write!(o, "{:<28}", "");
    for r in rows {
        let t = if r.title.is_empty() {
            &r.scene
        } else {
            &r.title
        };
        let _ = write!(o, " {:>22}", truncate(t, 22));
    }
    if rows.len() == 2 {
        let _ = write!(o, " {:>10}", "ratio");
    }
    o.push('\n');
    for (name, vals, nums) in columns(rows) {
        let _ = write!(o, "{name:<28}");
        for v in &vals {
            let _ = write!(o, " {v:>22}");
        }
        if rows.len() == 2 {
            let _ = write!(o, " {:>10}", ratio(nums[0], nums[1]));
        }
        o.push('\n');
    }
    o
}

/// The same comparison as JSON: per column, the values and (for two rows) the ratio.
pub fn compare_json(rows: &[&Table1Row]) -> serde_json::Value {
    let cols: Vec<serde_json::Value> = columns(rows)
        .into_iter()
        .map(|(name, vals, nums)| {
            let mut v = serde_json::json!({ "column": name, "values": vals, "numbers": nums });
            if rows.len() == 2 {
                v["ratio"] = match (nums[0], nums[1]) {
                    (Some(a), Some(b)) if b != 0.0 => serde_json::json!(a / b),
                    _ => serde_json::Value::Null,
                };
            }
            v
        })
        .collect();
    serde_json::json!({ "rows": rows, "columns": cols })
}

fn truncate(s: &str, n: usize) -> String {
    if s.chars().count() <= n {
        s.to_string()
    } else {
        let tail: String = s
            .chars()
            .rev()
            .take(n - 1)
            .collect::<Vec<_>>()
            .into_iter()
            .rev()
            .collect();
        format!("…{tail}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_papers_rows_are_consistent_with_their_own_shares() {
        let rows = paper_rows();
        assert_eq!(rows.len(), 3);
        let sponza = paper_row("sponza").unwrap();
        assert_eq!((sponza.links, sponza.level0_points), (973_000, 339));
        for r in &rows {
            // The share is links / (senders x receivers), with receivers = total points; it
            // implies a sender count between level 0 and the total.
            let senders = r.links as f64 / (r.link_share_percent / 100.0) / r.total_points as f64;
            assert!(
                senders > r.level0_points as f64 && senders < r.total_points as f64,
                "{}: {senders}",
                r.scene
            );
            // Refinement plus bounces is the total, to the second.
            let (a, b, t) = (
                r.refine_s.unwrap(),
                r.bounces_s.unwrap(),
                r.total_s.unwrap(),
            );
            assert!((a + b - t).abs() <= 1.0, "{}", r.scene);
        }
    }

    #[test]
    fn comparison_has_ratios_for_two_rows() {
        let p = paper_row("sponza").unwrap();
        let mut ours = p.clone();
        ours.title = "ours".into();
        ours.links = p.links / 2;
        let text = compare_text(&[&ours, &p]);
        assert!(text.contains("ratio"));
        let line = text.lines().find(|l| l.starts_with("links ")).unwrap();
        assert!(line.trim_end().ends_with("0.500"), "{line}");
        let json = compare_json(&[&ours, &p]);
        assert_eq!(json["columns"][1]["ratio"], 0.5);
    }
}
