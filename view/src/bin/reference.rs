//! `reference INPUT --out DIR --spp N`: the brute-force Monte Carlo reference of
//! `mlt_view::reference` for a baked file's (or a scene's) camera and light, as images, and at
//! probe points. INPUT is a `.mlt` file (camera, light and scene recorded in it; `--scene`
//! overrides the scene) or a scene specification (manifest, mesh or `builtin:` name, with its
//! own camera and light).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Parser;
use glam::Vec3;
use mlt_format::BakedFile;
use mlt_view::probe::parse_probes;
use mlt_view::reference::{
    camera_probes, probes_to_csv, reference_json, reference_probes, render_reference_with,
    write_reference, ReferenceOptions, DEFAULT_MAX_BOUNCES,
};
use mlt_view::{Camera, Light};

/// Renders the brute-force reference (path tracing, no basis) of the viewer's images.
#[derive(Parser)]
#[command(name = "reference", version)]
struct Cli {
    /// A baked .mlt file, or a scene (manifest .toml, .obj/.gltf/.glb, builtin:NAME?...).
    input: String,
    /// The scene to ray-cast (default: the source recorded in the file).
    #[arg(long)]
    scene: Option<String>,
    /// Write reference_*.exr, reference.png and reference.json here.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Paths per pixel or probe (even: two independent halves).
    #[arg(long, default_value_t = 256)]
    spp: u32,
    /// Seed of the random streams.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Hard cap on the path length (Russian roulette ends most paths long before).
    #[arg(long, default_value_t = DEFAULT_MAX_BOUNCES)]
    max_bounces: u32,
    /// Light position (default: the file's or scene's light).
    #[arg(long, value_parser = mlt_view::camera::parse_vec3)]
    light_pos: Option<Vec3>,
    /// Light RGB intensity in W/sr.
    #[arg(long, value_parser = mlt_view::camera::parse_vec3)]
    light_intensity: Option<Vec3>,
    /// Image width (default: the camera's); the field of view is kept.
    #[arg(long)]
    width: Option<u32>,
    /// Image height (default: the camera's).
    #[arg(long)]
    height: Option<u32>,
    /// Probe points, rows x,y,z,nx,ny,nz (as `view --probe`).
    #[arg(long, requires = "probe_out")]
    probe: Option<PathBuf>,
    /// Where to write the probes' reference irradiance (CSV with standard errors).
    #[arg(long, requires = "probe")]
    probe_out: Option<PathBuf>,
    /// Write probe points where the camera sees the scene (a COLSxROWS grid of pixels) here.
    #[arg(long)]
    make_probes: Option<PathBuf>,
    /// Grid of --make-probes, COLSxROWS.
    #[arg(long, default_value = "32x18")]
    probe_grid: String,
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    let (spec, mut camera, mut light) = if cli.input.ends_with(".mlt") {
        let file = BakedFile::open(std::path::Path::new(&cli.input))
            .with_context(|| format!("opening {}", cli.input))?;
        let meta = file
            .meta()
            .with_context(|| format!("reading {}", cli.input))?;
        let spec = cli.scene.clone().unwrap_or(meta.scene.source.clone());
        (
            spec,
            Camera::from_info(&meta.camera).context("the file's camera")?,
            Light::from_info(&meta.light).context("the file's light")?,
        )
    } else {
        let scene = mlt_scenes::load_scene(&cli.input)
            .with_context(|| format!("loading the scene {}", cli.input))?;
        let c = &scene.camera;
        let camera = Camera::new(
            c.position.into(),
            c.target.into(),
            c.up.into(),
            c.fovy_deg,
            c.width,
            c.height,
        )
        .context("the scene's camera")?;
        let light = Light::from_desc(&scene.light).context("the scene's light")?;
        (
            cli.scene.clone().unwrap_or(cli.input.clone()),
            camera,
            light,
        )
    };
    if let Some(p) = cli.light_pos {
        light.position = p;
    }
    if let Some(i) = cli.light_intensity {
        light.intensity = i.to_array();
    }
    Light::point(light.position, light.intensity)?;
    if cli.width.is_some() || cli.height.is_some() {
        camera = Camera::new(
            camera.position,
            camera.target,
            camera.up,
            camera.fovy_deg,
            cli.width.unwrap_or(camera.width),
            cli.height.unwrap_or(camera.height),
        )?;
    }
    let scene = mlt_scenes::load_scene(&spec)
        .with_context(|| format!("loading the scene {spec} (give --scene if it moved)"))?;
    let caster = scene.build_caster();
    let mut opts = ReferenceOptions::new(cli.spp, cli.seed);
    opts.max_bounces = cli.max_bounces;

    let mut did = false;
    if let Some(path) = &cli.make_probes {
        let (cols, rows) = cli
            .probe_grid
            .split_once('x')
            .and_then(|(a, b)| Some((a.parse::<u32>().ok()?, b.parse::<u32>().ok()?)))
            .filter(|&(a, b)| a > 0 && b > 0)
            .with_context(|| format!("--probe-grid {}: expected COLSxROWS", cli.probe_grid))?;
        let probes = camera_probes(caster.as_ref(), &camera, cols, rows);
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
        did = true;
    }
    if let (Some(input), Some(output)) = (&cli.probe, &cli.probe_out) {
        let text = std::fs::read_to_string(input)
            .with_context(|| format!("reading {}", input.display()))?;
        let probes = parse_probes(input, &text)?;
        let t = std::time::Instant::now();
        let values = reference_probes(caster.as_ref(), &light, &probes, &opts)?;
        mlt_format::file::write_atomic(output, probes_to_csv(&probes, &values).as_bytes())
            .with_context(|| format!("writing {}", output.display()))?;
        eprintln!(
            "{} reference probes ({} paths each) written to {} in {:.1} s",
            probes.len(),
            cli.spp,
            output.display(),
            t.elapsed().as_secs_f64()
        );
        did = true;
    }
    if let Some(dir) = &cli.out {
        let r = render_reference_with(caster.as_ref(), &camera, &light, &opts)?;
        write_reference(dir, &r).with_context(|| format!("writing into {}", dir.display()))?;
        eprintln!(
            "reference {}x{} at {} spp in {:.1} s: indirect noise {:.3e} ({:.2} % of the mean), written to {}",
            camera.width,
            camera.height,
            cli.spp,
            r.seconds,
            r.indirect_noise.rms,
            100.0 * r.indirect_noise.relative,
            dir.display()
        );
        println!("{}", serde_json::to_string_pretty(&reference_json(&r))?);
        did = true;
    }
    if !did {
        bail!("nothing to do: give --out DIR, --probe IN --probe-out OUT, or --make-probes OUT");
    }
    Ok(())
}
