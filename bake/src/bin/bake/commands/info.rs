//! `bake info`: what a baked file holds.

use anyhow::{Context, Result};
use mlt_bake::report::info_text;
use mlt_format::BakedFile;

use crate::cli::InfoArgs;

pub fn run(args: &InfoArgs) -> Result<()> {
    let file = &args.file;
    let baked = BakedFile::open(file).with_context(|| format!("opening {}", file.display()))?;
    let info = baked
        .info()
        .with_context(|| format!("reading {}", file.display()))?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&info)?);
    } else {
        print!("{}", info_text(&info));
    }
    Ok(())
}
