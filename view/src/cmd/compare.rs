//! `view compare REF_DIR TEST_DIR [--json]`: error of a rendering against the brute-force
//! reference (see `mlt_view::compare` for the definitions): relative RMSE, mean relative error
//! over lit pixels and ratio of means, for the indirect and final images, with the reference's
//! noise. `view compare --probes REF.csv TEST.csv` does the same for probe irradiances.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use mlt_view::breakdown::{by_brightness, by_tiles, format_parts, Part};
use mlt_view::compare::{compare_dirs, compare_probe_csv, format_blocks, format_metrics, Metrics};
use mlt_view::images::{luminance, RgbImage};

/// Compares images (or probes) against the brute-force reference.
#[derive(Args, Debug)]
pub struct CompareArgs {
    /// The reference's directory (from `view reference`), or with --probes its probe CSV.
    pub reference: PathBuf,
    /// A directory of `view render` (or another reference), or with --probes a `view probe` CSV.
    pub test: PathBuf,
    /// Compare probe CSVs instead of image directories.
    #[arg(long)]
    pub probes: bool,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Also write a PNG of the test's indirect light, the reference's and their difference.
    #[arg(long, value_name = "PNG")]
    pub side_by_side: Option<PathBuf>,
    /// Also break the error down by image tile (4x3 if no grid is given) and by brightness.
    #[arg(long, value_name = "COLSxROWS", num_args = 0..=1, default_missing_value = "4x3",
          value_parser = parse_grid)]
    pub breakdown: Option<(usize, usize)>,
}

/// `COLSxROWS` for [`CompareArgs::breakdown`].
fn parse_grid(s: &str) -> Result<(usize, usize), String> {
    let (c, r) = s
        .split_once('x')
        .ok_or_else(|| format!("expected COLSxROWS (e.g. 4x3), got {s}"))?;
    let parse = |v: &str| v.trim().parse::<usize>().map_err(|e| format!("{v}: {e}"));
    let (c, r) = (parse(c)?, parse(r)?);
    if !(1..=64).contains(&c) || !(1..=64).contains(&r) {
        return Err(format!("COLS and ROWS must be 1 to 64, got {s}"));
    }
    Ok((c, r))
}

pub fn run(cli: &CompareArgs) -> Result<()> {
    let what = if cli.probes { "probes " } else { "" };
    let context = || {
        format!(
            "comparing {what}{} against {}",
            cli.test.display(),
            cli.reference.display()
        )
    };
    anyhow::ensure!(
        !(cli.probes && cli.breakdown.is_some()),
        "--breakdown compares images, not probes"
    );
    if cli.probes {
        let c = compare_probe_csv(&cli.reference, &cli.test).with_context(context)?;
        if cli.json {
            println!("{}", serde_json::to_string_pretty(&c)?);
        } else {
            print_metrics(cli, "irradiance", &c.indirect, &c.final_image);
        }
        return Ok(());
    }
    let c = compare_dirs(&cli.reference, &cli.test).with_context(context)?;
    let parts = cli
        .breakdown
        .map(|(cols, rows)| breakdown(&cli.reference, &cli.test, cols, rows))
        .transpose()?;
    if cli.json {
        let mut v = serde_json::to_value(&c)?;
        if let (Some(b), Some(o)) = (&parts, v.as_object_mut()) {
            o.insert(
                "indirect_breakdown".into(),
                serde_json::json!({"tiles": b.tiles, "brightness": b.brightness}),
            );
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        print_metrics(cli, "radiance", &c.indirect, &c.final_image);
        println!("{}", format_blocks("indirect", &c.indirect_blocks));
        println!("{}", format_blocks("final", &c.final_blocks));
        if let Some(n) = &c.reference_noise {
            println!("reference noise (reference.json): {n}");
        }
        if let Some(b) = &parts {
            let (cols, rows) = b.grid;
            println!("indirect by tile ({cols}x{rows}, row by row from the top):");
            print!("{}", format_parts(&b.tiles));
            println!("indirect by the reference's brightness (fifths, darkest first):");
            print!("{}", format_parts(&b.brightness));
        }
    }
    if let Some(out) = &cli.side_by_side {
        side_by_side(&cli.reference, &cli.test, out)?;
    }
    Ok(())
}

/// The indirect images, reference and test (which falls back to a `reference_indirect.exr`,
/// so that two references compare), of the same size.
fn indirect_pair(reference: &Path, test: &Path) -> Result<(RgbImage, RgbImage)> {
    let r = RgbImage::read_exr(&reference.join("reference_indirect.exr"))?;
    let t = RgbImage::read_exr(&test.join("indirect.exr"))
        .or_else(|_| RgbImage::read_exr(&test.join("reference_indirect.exr")))?;
    anyhow::ensure!(
        (r.width, r.height) == (t.width, t.height),
        "{}: {}x{} against the reference's {}x{}",
        test.display(),
        t.width,
        t.height,
        r.width,
        r.height
    );
    Ok((r, t))
}

/// The indirect image's error on a grid of tiles and by fifth of the reference's brightness.
struct Breakdown {
    /// `(cols, rows)` of the tiles.
    grid: (usize, usize),
    tiles: Vec<Part>,
    brightness: Vec<Part>,
}

fn breakdown(reference: &Path, test: &Path, cols: usize, rows: usize) -> Result<Breakdown> {
    let (r, t) = indirect_pair(reference, test)?;
    let (w, h) = (r.width as usize, r.height as usize);
    let lum = |img: &RgbImage| -> Vec<f64> {
        img.pixels
            .iter()
            .map(|p| f64::from(luminance(*p)))
            .collect()
    };
    let (r, t) = (lum(&r), lum(&t));
    anyhow::ensure!(
        cols <= w && rows <= h,
        "a {cols}x{rows} grid is finer than the {w}x{h} image"
    );
    Ok(Breakdown {
        grid: (cols, rows),
        tiles: by_tiles(&r, &t, w, h, cols, rows),
        brightness: by_brightness(&r, &t, 5),
    })
}

/// `[test | reference | |test - reference|]`, tone-mapped alike.
fn side_by_side(reference: &Path, test: &Path, out: &Path) -> Result<()> {
    use mlt_view::images::{linear_to_srgb, ToneMap};
    let (r, t) = indirect_pair(reference, test)?;
    let tone = ToneMap::measure(&r);
    let (w, h) = (r.width, r.height);
    let mut img = image::RgbImage::new(3 * w, h);
    for y in 0..h {
        for x in 0..w {
            let (a, b) = (t.get(x, y), r.get(x, y));
            let d = [
                (a[0] - b[0]).abs(),
                (a[1] - b[1]).abs(),
                (a[2] - b[2]).abs(),
            ];
            for (k, c) in [a, b, d].into_iter().enumerate() {
                let s = tone.scale(luminance(c));
                let px = c.map(|v| (linear_to_srgb((v * s).clamp(0.0, 1.0)) * 255.0 + 0.5) as u8);
                img.put_pixel(k as u32 * w + x, y, image::Rgb(px));
            }
        }
    }
    let mut bytes = std::io::Cursor::new(Vec::new());
    img.write_to(&mut bytes, image::ImageFormat::Png)
        .with_context(|| format!("encoding {}", out.display()))?;
    mlt_format::file::write_atomic(out, bytes.get_ref())
        .with_context(|| format!("writing {}", out.display()))?;
    Ok(())
}

/// The text report: what was compared, then the indirect and final metrics.
fn print_metrics(cli: &CompareArgs, quantity: &str, indirect: &Metrics, final_image: &Metrics) {
    println!(
        "{} against the reference {} ({quantity}, luminance)",
        cli.test.display(),
        cli.reference.display()
    );
    println!("{}", format_metrics("indirect", indirect));
    println!("{}", format_metrics("final", final_image));
}
