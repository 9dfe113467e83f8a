//! `bake merge`: shard files into the file a single bake gives.

use anyhow::{bail, Context, Result};
use mlt_bake::report::{estimate_table, transport_table};
use mlt_format::{BakedFile, WriteOptions};

use crate::cli::MergeArgs;
use crate::progress::Reporter;

pub fn run(args: &MergeArgs) -> Result<()> {
    let MergeArgs {
        shards,
        output,
        scene,
        compress,
        quiet,
    } = args;
    mlt_bake::output_check::files([output])?;
    let mut contents = Vec::new();
    for s in shards {
        let f = BakedFile::open(s).with_context(|| format!("opening {}", s.display()))?;
        contents.push((
            s.display().to_string(),
            f.contents()
                .with_context(|| format!("reading {}", s.display()))?,
        ));
    }
    let caster = match (scene, contents.first()) {
        (Some(spec), Some((_, first))) => {
            let scene =
                mlt_scenes::load_scene(spec).with_context(|| format!("loading scene {spec}"))?;
            let recorded = &first.meta.scene;
            if scene.content_hash != recorded.content_hash || scene.scale != recorded.scale {
                bail!(
                    "scene {spec} is not the shards' scene ({}, content hash {:016x} at scale {}; \
                     {spec} has {:016x} at scale {})",
                    recorded.source,
                    recorded.content_hash,
                    recorded.scale,
                    scene.content_hash,
                    scene.scale
                );
            }
            Some(scene.build_caster())
        }
        _ => None,
    };
    let reporter = Reporter::new(*quiet);
    let merged =
        mlt_bake::shard::merge(contents, caster.as_deref(), &reporter).context("merging")?;
    let size = mlt_format::file::write(
        output,
        &merged,
        WriteOptions {
            compress: *compress,
        },
    )
    .with_context(|| format!("writing {}", output.display()))?;
    if !quiet {
        if let Some(t) = &merged.transport {
            eprint!("{}", transport_table(&t.meta, None));
            if let Some(r) = &t.report {
                eprint!(
                    "{}",
                    estimate_table(r, t.drop.as_ref(), t.camera_check.as_ref())
                );
            }
        }
        eprintln!(
            "merged {} shards: {} ({:.2} MB)",
            shards.len(),
            output.display(),
            size as f64 / 1e6
        );
    }
    println!("{}", output.display());
    Ok(())
}
