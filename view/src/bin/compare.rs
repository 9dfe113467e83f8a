//! `compare REF_DIR TEST_DIR [--json]`: error of a rendering against the brute-force reference
//! (see `mlt_view::compare` for the definitions): relative RMSE, mean relative error over lit
//! pixels and ratio of means, for the indirect and final images, with the reference's noise.
//! `compare --probes REF.csv TEST.csv` does the same for probe irradiances.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Parser;
use mlt_view::compare::{compare_dirs, compare_probe_csv, format_metrics};

/// Compares images (or probes) against the brute-force reference.
#[derive(Parser)]
#[command(name = "compare", version)]
struct Cli {
    /// Reference directory (reference_{indirect,final,noise}.exr, reference.json), or with
    /// --probes the reference's probe CSV.
    reference: PathBuf,
    /// Directory with indirect.exr and final.exr (falls back to reference_*.exr), or with
    /// --probes the CSV of `view --probe-out`.
    test: PathBuf,
    /// Compare probe CSVs instead of image directories.
    #[arg(long)]
    probes: bool,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    if cli.probes {
        let c = compare_probe_csv(&cli.reference, &cli.test).with_context(|| {
            format!(
                "comparing probes {} against {}",
                cli.test.display(),
                cli.reference.display()
            )
        })?;
        if cli.json {
            println!("{}", serde_json::to_string_pretty(&c)?);
        } else {
            println!(
                "{} against the reference {} (irradiance, luminance)",
                cli.test.display(),
                cli.reference.display()
            );
            println!("{}", format_metrics("indirect", &c.indirect));
            println!("{}", format_metrics("final", &c.final_image));
        }
        return Ok(());
    }
    let c = compare_dirs(&cli.reference, &cli.test).with_context(|| {
        format!(
            "comparing {} against {}",
            cli.test.display(),
            cli.reference.display()
        )
    })?;
    if cli.json {
        println!("{}", serde_json::to_string_pretty(&c)?);
    } else {
        println!(
            "{} against the reference {} (radiance, luminance)",
            cli.test.display(),
            cli.reference.display()
        );
        println!("{}", format_metrics("indirect", &c.indirect));
        println!("{}", format_metrics("final", &c.final_image));
        if let Some(n) = &c.reference_noise {
            println!("reference noise (reference.json): {n}");
        }
    }
    Ok(())
}
