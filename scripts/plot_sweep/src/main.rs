//! `plot_sweep SWEEP.csv --out PREFIX`: plots of `scripts/sweep_error.sh`'s CSV, error against
//! bake time (`PREFIX_vs_bake.png`) and against per-frame CPU time (`PREFIX_vs_frame.png`),
//! log-log, one marker per setting labelled with what it varied, the paper's operating point
//! (the row with `paper` = 1: epsilon 0.025 and the other defaults) ringed, and the
//! reference's own noise floor as a dashed line.
//!
//! Text is drawn with ab_glyph from a TrueType font file (`--font`, default DejaVu Sans from
//! the usual system path); no fontconfig or freetype is needed.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context, Result};
use clap::Parser;
use plotters::prelude::*;

use mlt_plot::axes::{log_ticks, range, short};
use mlt_plot::table::Table;

/// Plots error against run time from a sweep CSV.
#[derive(Parser)]
#[command(name = "plot_sweep", version)]
struct Cli {
    /// The sweep CSV (header row; columns label, paper, bake_s, frame_ms,
    /// indirect_rel_rmse, final_rel_rmse, noise_indirect_rel_rmse, noise_final_rel_rmse).
    csv: PathBuf,
    /// Output prefix: PREFIX_vs_bake.png and PREFIX_vs_frame.png.
    #[arg(long)]
    out: PathBuf,
    /// Title (the scene's name).
    #[arg(long, default_value = "")]
    title: String,
    /// TrueType font for the text.
    #[arg(
        long,
        default_value = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf"
    )]
    font: PathBuf,
}

struct Row {
    label: String,
    paper: bool,
    bake_s: f64,
    frame_ms: f64,
    indirect: f64,
    final_: f64,
    noise_indirect: f64,
    noise_final: f64,
}

fn read_rows(path: &Path) -> Result<Vec<Row>> {
    let t = Table::read(path)?;
    (0..t.rows.len())
        .map(|r| {
            Ok(Row {
                label: t.get(r, "label")?.to_string(),
                paper: t.num(r, "paper")? != 0.0,
                bake_s: t.num(r, "bake_s")?,
                frame_ms: t.num(r, "frame_ms")?,
                indirect: t.num(r, "indirect_rel_rmse")?,
                final_: t.num(r, "final_rel_rmse")?,
                noise_indirect: t.num(r, "noise_indirect_rel_rmse")?,
                noise_final: t.num(r, "noise_final_rel_rmse")?,
            })
        })
        .collect()
}

fn plot(rows: &[Row], x_of: fn(&Row) -> f64, x_label: &str, title: &str, out: &Path) -> Result<()> {
    let (w, h) = (1000u32, 700u32);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE)?;
        let (x0, x1) = range(rows.iter().map(x_of));
        let (y0, y1) = range(
            rows.iter()
                .flat_map(|r| [r.indirect, r.final_, r.noise_indirect, r.noise_final]),
        );
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 24))
            .margin(20)
            .x_label_area_size(50)
            .y_label_area_size(80)
            .build_cartesian_2d(
                (x0..x1).log_scale().with_key_points(log_ticks(x0, x1)),
                (y0..y1).log_scale().with_key_points(log_ticks(y0, y1)),
            )?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .x_label_formatter(&|v| short(*v))
            .y_label_formatter(&|v| short(*v))
            .y_desc("relative RMSE against the reference")
            .label_style(("sans-serif", 16))
            .axis_desc_style(("sans-serif", 18))
            .draw()?;
        let blue = RGBColor(30, 90, 200);
        let orange = RGBColor(220, 120, 20);
        chart
            .draw_series(
                rows.iter()
                    .map(|r| Circle::new((x_of(r), r.indirect), 6, blue.filled())),
            )?
            .label("indirect")
            .legend(move |(x, y)| Circle::new((x + 10, y), 6, blue.filled()));
        chart
            .draw_series(
                rows.iter()
                    .map(|r| TriangleMarker::new((x_of(r), r.final_), 7, orange.filled())),
            )?
            .label("final (direct + indirect)")
            .legend(move |(x, y)| TriangleMarker::new((x + 10, y), 7, orange.filled()));
        for r in rows {
            chart.draw_series(std::iter::once(Text::new(
                format!("  {}", r.label),
                (x_of(r), r.indirect),
                ("sans-serif", 13).into_font().color(&BLACK),
            )))?;
        }
        let paper: Vec<&Row> = rows.iter().filter(|r| r.paper).collect();
        let red = RGBColor(200, 20, 20);
        chart
            .draw_series(paper.iter().flat_map(|r| {
                [
                    Circle::new((x_of(r), r.indirect), 13, red.stroke_width(3)),
                    Circle::new((x_of(r), r.final_), 13, red.stroke_width(3)),
                ]
            }))?
            .label("paper's operating point (epsilon 0.025)")
            .legend(move |(x, y)| Circle::new((x + 10, y), 9, red.stroke_width(3)));
        let noise = rows.iter().map(|r| r.noise_indirect).fold(0.0f64, f64::max);
        if noise > 0.0 {
            let grey = RGBColor(120, 120, 120);
            chart
                .draw_series(DashedLineSeries::new(
                    [(x0, noise), (x1, noise)],
                    8,
                    6,
                    grey.stroke_width(2),
                ))?
                .label("reference noise (indirect)")
                .legend(move |(x, y)| {
                    PathElement::new([(x, y), (x + 20, y)], grey.stroke_width(2))
                });
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .label_font(("sans-serif", 16))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
        root.present()?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).ok_or_else(|| anyhow!("bad buffer"))?;
    img.save_with_format(out, image::ImageFormat::Png)
        .with_context(|| format!("writing {}", out.display()))?;
    Ok(())
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    let font = std::fs::read(&cli.font)
        .with_context(|| format!("reading the font {} (give --font)", cli.font.display()))?;
    let font: &'static [u8] = Box::leak(font.into_boxed_slice());
    plotters::style::register_font("sans-serif", FontStyle::Normal, font)
        .map_err(|_| anyhow!("{}: not a usable TrueType font", cli.font.display()))?;
    let rows = read_rows(&cli.csv)?;
    let name = cli
        .out
        .file_name()
        .map(|s| s.to_string_lossy().to_string())
        .unwrap_or_default();
    let with = |suffix: &str| cli.out.with_file_name(format!("{name}{suffix}"));
    let title = |what: &str| {
        if cli.title.is_empty() {
            what.to_string()
        } else {
            format!("{}: {what}", cli.title)
        }
    };
    let (a, b) = (with("_vs_bake.png"), with("_vs_frame.png"));
    plot(
        &rows,
        |r| r.bake_s,
        "bake time (s, wall clock)",
        &title("error vs bake time"),
        &a,
    )?;
    plot(
        &rows,
        |r| r.frame_ms,
        "per-frame CPU relighting time (ms, median, moving light)",
        &title("error vs frame time"),
        &b,
    )?;
    eprintln!("wrote {} and {}", a.display(), b.display());
    Ok(())
}
