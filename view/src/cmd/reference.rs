//! `view reference INPUT --out DIR --spp N`: the brute-force Monte Carlo reference of
//! `mlt_view::reference` for a baked file's (or a scene's) camera and light, as images, and at
//! probe points. INPUT is a `.mlt` file (camera, light and scene recorded in it; `--scene`
//! overrides the scene) or a scene specification (manifest, mesh or `builtin:` name, with its
//! own camera and light).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::Args;
use mlt_scenes::RayCaster;
use mlt_view::probe::parse_probes;
use mlt_view::reference::{
    camera_probes, probes_to_csv, reference_json, reference_probes, render_reference_with,
    write_reference, ReferenceOptions, DEFAULT_MAX_BOUNCES,
};

use crate::cmd::args::SceneArgs;
use crate::cmd::load::{input_setting, Setting};

/// Renders the brute-force reference (path tracing, no basis) of the viewer's images.
#[derive(Args, Debug)]
pub struct ReferenceArgs {
    /// A baked .mlt file, or a scene (manifest .toml, .obj, .gltf, .glb, builtin:NAME).
    pub input: String,
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Where to write reference_*.exr, reference.png and reference.json.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Paths per pixel or probe, even (its two halves measure the noise).
    #[arg(long, value_name = "N", default_value_t = 256)]
    pub spp: u32,
    /// Seed of the random numbers.
    #[arg(long, value_name = "S", default_value_t = 1)]
    pub seed: u64,
    /// The longest path, in bounces (Russian roulette ends most paths long before).
    #[arg(long, value_name = "N", default_value_t = DEFAULT_MAX_BOUNCES, hide = true)]
    pub max_bounces: u32,
    /// Probe points: a CSV of rows x,y,z,nx,ny,nz, as for `view probe`.
    #[arg(long, value_name = "CSV", requires = "probe_out")]
    pub probe: Option<PathBuf>,
    /// Where to write the probes' reference irradiance (CSV with standard errors).
    #[arg(long, value_name = "CSV", requires = "probe")]
    pub probe_out: Option<PathBuf>,
    /// Write probe points here: where the camera sees the scene, on a grid of pixels.
    #[arg(long, value_name = "CSV")]
    pub make_probes: Option<PathBuf>,
    /// The pixel grid of --make-probes.
    #[arg(long, value_name = "COLSxROWS", default_value = "32x18")]
    pub probe_grid: String,
}

pub fn run(args: &ReferenceArgs) -> Result<()> {
    let setting = input_setting(&args.input, &args.scene)?;
    let caster = setting.scene.build_caster();
    let mut opts = ReferenceOptions::new(args.spp, args.seed);
    opts.max_bounces = args.max_bounces;
    let mut did = false;
    if let Some(path) = &args.make_probes {
        make_probes(args, &setting, caster.as_ref(), path)?;
        did = true;
    }
    if let (Some(input), Some(output)) = (&args.probe, &args.probe_out) {
        probes(&setting, caster.as_ref(), &opts, input, output)?;
        did = true;
    }
    if let Some(dir) = &args.out {
        images(&setting, caster.as_ref(), &opts, dir)?;
        did = true;
    }
    if !did {
        bail!("nothing to do: give --out DIR, --probe IN --probe-out OUT, or --make-probes OUT");
    }
    Ok(())
}

/// Writes probe points where the camera's pixels of a COLSxROWS grid see the scene.
fn make_probes(
    args: &ReferenceArgs,
    setting: &Setting,
    caster: &dyn RayCaster,
    path: &Path,
) -> Result<()> {
    let (cols, rows) = args
        .probe_grid
        .split_once('x')
        .and_then(|(a, b)| Some((a.parse::<u32>().ok()?, b.parse::<u32>().ok()?)))
        .filter(|&(a, b)| a > 0 && b > 0)
        .with_context(|| format!("--probe-grid {}: expected COLSxROWS", args.probe_grid))?;
    let probes = camera_probes(caster, &setting.camera, cols, rows);
    let mut text = String::from("x,y,z,nx,ny,nz\n");
    for p in &probes {
        let v = [p.position.to_array(), p.normal.to_array()].concat();
        let f: Vec<String> = v.iter().map(|c| c.to_string()).collect();
        text.push_str(&f.join(","));
        text.push('\n');
    }
    mlt_format::file::write_atomic(path, text.as_bytes())
        .with_context(|| format!("writing {}", path.display()))?;
    eprintln!("{} probes written to {}", probes.len(), path.display());
    Ok(())
}

/// The reference irradiance at the probe points of `input`, written to `output`.
fn probes(
    setting: &Setting,
    caster: &dyn RayCaster,
    opts: &ReferenceOptions,
    input: &Path,
    output: &Path,
) -> Result<()> {
    let text =
        std::fs::read_to_string(input).with_context(|| format!("reading {}", input.display()))?;
    let probes = parse_probes(input, &text)?;
    let t = Instant::now();
    let values = reference_probes(caster, &setting.light, &probes, opts)?;
    mlt_format::file::write_atomic(output, probes_to_csv(&probes, &values).as_bytes())
        .with_context(|| format!("writing {}", output.display()))?;
    eprintln!(
        "{} reference probes ({} paths each) written to {} in {:.1} s",
        probes.len(),
        opts.spp,
        output.display(),
        t.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The reference images, written into `dir`, with their summary as JSON on stdout.
fn images(
    setting: &Setting,
    caster: &dyn RayCaster,
    opts: &ReferenceOptions,
    dir: &Path,
) -> Result<()> {
    let camera = &setting.camera;
    let r = render_reference_with(caster, camera, &setting.light, opts)?;
    write_reference(dir, &r).with_context(|| format!("writing into {}", dir.display()))?;
    eprintln!(
        "reference {}x{} at {} spp in {:.1} s: indirect noise {:.3e} ({:.2} % of the mean), written to {}",
        camera.width,
        camera.height,
        opts.spp,
        r.seconds,
        r.indirect_noise.rms,
        100.0 * r.indirect_noise.relative,
        dir.display()
    );
    println!("{}", serde_json::to_string_pretty(&reference_json(&r))?);
    Ok(())
}
