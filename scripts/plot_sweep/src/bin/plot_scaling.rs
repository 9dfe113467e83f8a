//! `plot_scaling SCALING.csv --out PLOT.png`: the plot of `scripts/bench_scaling.sh`'s CSV, four
//! panels with logarithmic value axes: bake time (CPU time per phase: placement, refinement of
//! T, bounces; the total's CPU and wall-clock time) and peak memory and file size against the
//! triangle count (log axis; one line per scene and receiver levels), and the same against the
//! receiver levels (one line per scene and subdivision). Lines of one case only are left out,
//! except for a scene baked once (drawn as single markers).
//!
//! Text is drawn with ab_glyph from a TrueType font file (`--font`, default DejaVu Sans from
//! the usual system path); no fontconfig or freetype is needed.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context, Result};
use clap::Parser;
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

use mlt_plot::axes::{range, short};
use mlt_plot::table::Table;

/// Plots bake cost against triangles and receiver levels from a scaling CSV.
#[derive(Parser)]
#[command(name = "plot_scaling", version)]
struct Cli {
    /// The scaling CSV (header row; columns scene, subdivide, triangles, levels,
    /// placement_cpu_s, refine_cpu_s, bounces_cpu_s (empty where not measured), wall_s, cpu_s,
    /// peak_mb, file_mb).
    csv: PathBuf,
    /// The PNG to write.
    #[arg(long)]
    out: PathBuf,
    /// TrueType font for the text.
    #[arg(
        long,
        default_value = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf"
    )]
    font: PathBuf,
}

/// One bake of the CSV.
struct Row {
    scene: String,
    subdivide: u32,
    triangles: f64,
    levels: u32,
    /// CPU seconds of the phases, NaN where not measured.
    placement_cpu_s: f64,
    refine_cpu_s: f64,
    bounces_cpu_s: f64,
    wall_s: f64,
    cpu_s: f64,
    peak_mb: f64,
    file_mb: f64,
}

fn read_rows(path: &Path) -> Result<Vec<Row>> {
    let t = Table::read(path)?;
    (0..t.rows.len())
        .map(|r| {
            Ok(Row {
                scene: t.get(r, "scene")?.to_string(),
                subdivide: t.num(r, "subdivide")? as u32,
                triangles: t.num(r, "triangles")?,
                levels: t.num(r, "levels")? as u32,
                placement_cpu_s: t.optional(r, "placement_cpu_s")?,
                refine_cpu_s: t.optional(r, "refine_cpu_s")?,
                bounces_cpu_s: t.optional(r, "bounces_cpu_s")?,
                wall_s: t.num(r, "wall_s")?,
                cpu_s: t.num(r, "cpu_s")?,
                peak_mb: t.num(r, "peak_mb")?,
                file_mb: t.num(r, "file_mb")?,
            })
        })
        .collect()
}

/// One quantity drawn in a panel: its name, colour and value.
struct Quantity {
    name: &'static str,
    colour: RGBColor,
    value: fn(&Row) -> f64,
}

const TIMES: [Quantity; 5] = [
    Quantity {
        name: "total, wall clock",
        colour: RGBColor(150, 150, 150),
        value: |r| r.wall_s,
    },
    Quantity {
        name: "total, CPU",
        colour: RGBColor(20, 20, 20),
        value: |r| r.cpu_s,
    },
    Quantity {
        name: "refinement of T, CPU",
        colour: RGBColor(30, 90, 200),
        value: |r| r.refine_cpu_s,
    },
    Quantity {
        name: "placement, CPU",
        colour: RGBColor(30, 150, 60),
        value: |r| r.placement_cpu_s,
    },
    Quantity {
        name: "bounces, CPU",
        colour: RGBColor(220, 120, 20),
        value: |r| r.bounces_cpu_s,
    },
];

const SIZES: [Quantity; 2] = [
    Quantity {
        name: "peak memory",
        colour: RGBColor(200, 20, 20),
        value: |r| r.peak_mb,
    },
    Quantity {
        name: "file",
        colour: RGBColor(120, 60, 160),
        value: |r| r.file_mb,
    },
];

/// What one panel shows: the rows grouped into lines by scene, x of a row (on a linear axis:
/// the triangle panels plot log10 of the count, labelled as counts) and the quantities.
struct Panel<'a> {
    title: String,
    x_label: &'static str,
    y_label: &'static str,
    x: fn(&Row) -> f64,
    x_format: fn(f64) -> String,
    lines: Vec<(String, Vec<&'a Row>)>,
    quantities: &'a [Quantity],
}

/// Rows grouped into lines by `key` (in order of first appearance), each sorted by `x`; lines
/// of one row are dropped unless their scene has only that row.
fn lines(
    rows: &[Row],
    key: impl Fn(&Row) -> String,
    x: fn(&Row) -> f64,
) -> Vec<(String, Vec<&Row>)> {
    let mut groups: Vec<(String, Vec<&Row>)> = Vec::new();
    for r in rows {
        let k = key(r);
        match groups.iter_mut().find(|(s, _)| *s == k) {
            Some((_, g)) => g.push(r),
            None => groups.push((k, vec![r])),
        }
    }
    let alone = |r: &Row| rows.iter().filter(|o| o.scene == r.scene).count() == 1;
    groups.retain(|(_, g)| g.len() > 1 || alone(g[0]));
    for (_, g) in &mut groups {
        g.sort_by(|a, b| x(a).total_cmp(&x(b)));
    }
    groups
}

/// A triangle count as text: 66k, 1.06M.
fn count(v: f64) -> String {
    if v >= 1e6 {
        format!("{}M", short(v / 1e6))
    } else if v >= 1e3 {
        format!("{}k", short(v / 1e3))
    } else {
        short(v)
    }
}

/// An integer tick as text; other ticks unlabelled.
fn integer(v: f64) -> String {
    if (v - v.round()).abs() < 1e-6 {
        format!("{v:.0}")
    } else {
        String::new()
    }
}

/// Linear x range around the values, padded by a tenth of their span (at least 0.5).
fn linear_range(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = v.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
        (lo.min(x), hi.max(x))
    });
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.1).max(0.5);
    (lo - pad, hi + pad)
}

/// The chart of one panel: linear x, logarithmic y.
type Chart<'a> = ChartContext<'a, BitMapBackend<'a>, Cartesian2d<RangedCoordf64, LogCoord<f64>>>;

/// How the lines of a panel differ: solid with circles, dashed with triangles, dotted with
/// crosses.
const LINE_STYLES: [&str; 3] = ["solid, circles", "dashed, triangles", "dotted, crosses"];

/// Draws one line of `points` in `colour` in the style of line `line`.
fn draw_line(
    chart: &mut Chart,
    line: usize,
    points: &[(f64, f64)],
    colour: RGBColor,
) -> Result<()> {
    let style = colour.stroke_width(2);
    let pts = points.iter().copied();
    match line % 3 {
        0 => {
            chart.draw_series(LineSeries::new(pts, style))?;
            chart.draw_series(points.iter().map(|&p| Circle::new(p, 5, colour.filled())))?;
        }
        1 => {
            chart.draw_series(DashedLineSeries::new(pts, 8, 5, style))?;
            chart.draw_series(
                points
                    .iter()
                    .map(|&p| TriangleMarker::new(p, 7, colour.filled())),
            )?;
        }
        _ => {
            chart.draw_series(DashedLineSeries::new(pts, 2, 4, style))?;
            chart.draw_series(
                points
                    .iter()
                    .map(|&p| Cross::new(p, 6, colour.stroke_width(3))),
            )?;
        }
    }
    Ok(())
}

/// The legend: one entry per quantity (its colour) and one per line (its style).
fn draw_legend<'a>(chart: &mut Chart<'a>, panel: &Panel) -> Result<()> {
    let none = || std::iter::empty::<PathElement<(f64, f64)>>();
    for q in panel.quantities {
        let style = q.colour.stroke_width(3);
        chart
            .draw_series(none())?
            .label(q.name)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], style));
    }
    for (line, (name, _)) in panel.lines.iter().enumerate() {
        let series = chart.draw_series(none())?;
        series.label(format!("{name}: {}", LINE_STYLES[line % 3]));
        match line % 3 {
            0 => series.legend(|(x, y)| Circle::new((x + 10, y), 5, BLACK.filled())),
            1 => series.legend(|(x, y)| TriangleMarker::new((x + 10, y), 7, BLACK.filled())),
            _ => series.legend(|(x, y)| Cross::new((x + 10, y), 6, BLACK.stroke_width(3))),
        };
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .label_font(("sans-serif", 13))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

fn draw_panel(area: &DrawingArea<BitMapBackend, Shift>, panel: &Panel) -> Result<()> {
    let all = || panel.lines.iter().flat_map(|(_, g)| g.iter().copied());
    let (x0, x1) = linear_range(all().map(panel.x));
    let (y0, y1) = range(all().flat_map(|r| panel.quantities.iter().map(move |q| (q.value)(r))));
    // Room above the data for the legend.
    let y1 = y1 * (y1 / y0).powf(0.6);
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, ("sans-serif", 20))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1, (y0..y1).log_scale())?;
    chart
        .configure_mesh()
        .x_desc(panel.x_label)
        .y_desc(panel.y_label)
        .x_labels(6)
        .x_label_formatter(&|v| (panel.x_format)(*v))
        .y_label_formatter(&|v| short(*v))
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 15))
        .draw()?;
    for (line, (_, group)) in panel.lines.iter().enumerate() {
        for q in panel.quantities {
            let points: Vec<(f64, f64)> = group
                .iter()
                .map(|r| ((panel.x)(r), (q.value)(r)))
                .filter(|p| p.1 > 0.0 && p.1.is_finite())
                .collect();
            draw_line(&mut chart, line, &points, q.colour)?;
        }
    }
    draw_legend(&mut chart, panel)
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    let font = std::fs::read(&cli.font)
        .with_context(|| format!("reading the font {} (give --font)", cli.font.display()))?;
    let font: &'static [u8] = Box::leak(font.into_boxed_slice());
    plotters::style::register_font("sans-serif", FontStyle::Normal, font)
        .map_err(|_| anyhow!("{}: not a usable TrueType font", cli.font.display()))?;
    let rows = read_rows(&cli.csv)?;
    let tri_x: fn(&Row) -> f64 = |r| r.triangles.log10();
    let level_x: fn(&Row) -> f64 = |r| r.levels as f64;
    let by_levels = |r: &Row| format!("{}, {} levels", r.scene, r.levels);
    let by_split = |r: &Row| match r.subdivide {
        0 => r.scene.clone(),
        s => format!("{} x{}", r.scene, 4u64.pow(s)),
    };
    let panels = [
        Panel {
            title: "bake time vs triangles".to_string(),
            x_label: "triangles (log)",
            y_label: "seconds",
            x: tri_x,
            x_format: |v| count(10f64.powf(v)),
            lines: lines(&rows, by_levels, tri_x),
            quantities: &TIMES,
        },
        Panel {
            title: "memory and file vs triangles".to_string(),
            x_label: "triangles (log)",
            y_label: "MB",
            x: tri_x,
            x_format: |v| count(10f64.powf(v)),
            lines: lines(&rows, by_levels, tri_x),
            quantities: &SIZES,
        },
        Panel {
            title: "bake time vs receiver levels".to_string(),
            x_label: "receiver levels",
            y_label: "seconds",
            x: level_x,
            x_format: integer,
            lines: lines(&rows, by_split, level_x),
            quantities: &TIMES,
        },
        Panel {
            title: "memory and file vs receiver levels".to_string(),
            x_label: "receiver levels",
            y_label: "MB",
            x: level_x,
            x_format: integer,
            lines: lines(&rows, by_split, level_x),
            quantities: &SIZES,
        },
    ];
    let (w, h) = (1400u32, 1000u32);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE)?;
        for (area, panel) in root.split_evenly((2, 2)).iter().zip(&panels) {
            draw_panel(area, panel)?;
        }
        root.present()?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).ok_or_else(|| anyhow!("bad buffer"))?;
    img.save_with_format(&cli.out, image::ImageFormat::Png)
        .with_context(|| format!("writing {}", cli.out.display()))?;
    eprintln!("wrote {}", cli.out.display());
    Ok(())
}
