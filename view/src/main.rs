//! `view`: the viewer of baked files.
//!
//! PLACEHOLDER: rendering (per-frame relighting, GPU splatting, shadow-mapped direct light,
//! window and headless modes) is the viewer issue's work and is not implemented yet. For now
//! this binary memory-maps and validates a baked file, prints what it would show, and exits
//! with status 2 so that no script mistakes it for a renderer.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Parser;

/// Views a baked light-transport file (not implemented yet: validates the file only).
#[derive(Parser)]
#[command(name = "view", version)]
struct Cli {
    /// A file written by `bake`.
    file: PathBuf,
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    let f = mlt_format::BakedFile::open(&cli.file)
        .with_context(|| format!("opening {}", cli.file.display()))?;
    let contents = f
        .contents()
        .with_context(|| format!("reading {}", cli.file.display()))?;
    eprintln!(
        "{}: valid, {} basis points on {} levels, scene {}",
        cli.file.display(),
        contents.basis.basis.len(),
        contents.basis.levels(),
        contents.meta.scene.source
    );
    eprintln!("view: rendering is not implemented yet (placeholder until the viewer issue)");
    std::process::exit(2)
}
