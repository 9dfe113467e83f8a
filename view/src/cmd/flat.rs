//! `view flat FILE [--width W --height H] [--json] [--by-normal] [--list N]`: the flat basis in the
//! file's view (or the given camera), relit once with the file's light (or the given one): flat
//! functions per surface pixel (mean, histogram, uncovered pixels) and the flat indirect image
//! against the exact per-pixel evaluation of Eq. 6 (relative RMSE; with `--by-normal` also
//! with the flat points' values taken at each pixel's normal; with `--list` the flagged pixels
//! themselves), on the CPU without a GPU.

use anyhow::Result;
use clap::Args;
use mlt_view::flat_check::FlatCheck;
use mlt_view::Relight;

use crate::cmd::args::BakedArgs;
use crate::cmd::load::with_viewing;

/// Measures the flat basis in one view.
#[derive(Args, Debug)]
pub struct FlatArgs {
    #[command(flatten)]
    pub baked: BakedArgs,
    /// Print the figures as JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Also measure flattening with each flat point taken at the pixel's own normal (slow).
    #[arg(long, hide = true)]
    pub by_normal: bool,
    /// Also list up to N flagged pixels with their surface point and covering functions.
    #[arg(long, value_name = "N", default_value_t = 0, hide = true)]
    pub list: usize,
}

pub fn run(args: &FlatArgs) -> Result<()> {
    with_viewing(&args.baked, |mut v| {
        let frame = v.relighter.relight(&v.light).clone();
        let fb = v.relighter.flat_basis();
        let mut check = FlatCheck::measure(v.ib, &frame.i, fb, &frame.flat, &v.camera, v.caster);
        if args.by_normal {
            check.split_by_normal(v.ib, &frame.i, fb);
        }
        if args.json {
            let mut json = serde_json::to_value(&check)?;
            json["darker"] = serde_json::json!(check.darker.len());
            json["file"] = serde_json::json!(v.path.display().to_string());
            json["flat_stored"] = serde_json::json!(v.relighter.load_stats().flat_stored);
            json["flat_normal_power"] = serde_json::json!(fb.normal_power);
            json["sharpened"] = serde_json::json!(v.relighter.sharpen);
            if args.list > 0 {
                json["flagged"] = serde_json::to_value(check.flagged(args.list))?;
            }
            println!("{}", serde_json::to_string_pretty(&json)?);
        } else {
            print!("{}", check.summary());
            if args.list > 0 {
                println!("the exact image's brightest pixel: {:.4e}", check.exact_max);
            }
            for p in check.flagged(args.list) {
                println!(
                    "{} pixel ({}, {}): point {:?}, normal {:?}, {} covering, flat {:.4e}, exact {:.4e}",
                    p.kind, p.x, p.y, p.position, p.normal, p.coverage, p.flat, p.exact
                );
            }
        }
        Ok(())
    })
}
