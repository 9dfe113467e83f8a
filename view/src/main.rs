//! `view`: the viewer of baked files.
//!
//! Implemented: memory-mapping and validating a file, per-frame CPU relighting with its stage
//! timings (`--frames N`, a moving light), and probes (`--probe IN.csv --probe-out OUT.csv`).
//! NOT implemented yet: GPU rendering (G-buffer, splatting, shadow-mapped direct light), the
//! window and headless images; without `--probe` or `--frames` the binary says so and exits
//! with status 2.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Parser;
use glam::Vec3;
use mlt_format::BakedFile;
use mlt_view::probe::{evaluate, parse_probes, to_csv};
use mlt_view::{CpuRelighter, Light, Relight, StageTimes};

/// Views a baked light-transport file (CPU relighting and probes; GPU rendering to come).
#[derive(Parser)]
#[command(name = "view", version)]
struct Cli {
    /// A file written by `bake`.
    file: PathBuf,
    /// The scene to ray-cast for visibility (default: the source recorded in the file).
    #[arg(long)]
    scene: Option<String>,
    /// Light position (default: the file's light).
    #[arg(long, value_parser = vec3)]
    light_pos: Option<Vec3>,
    /// Light RGB intensity in W/sr.
    #[arg(long, value_parser = vec3)]
    light_intensity: Option<Vec3>,
    /// Spot direction (with --cone-deg): makes the light a spot.
    #[arg(long, value_parser = vec3, requires = "cone_deg")]
    light_dir: Option<Vec3>,
    /// Spot full cone angle, degrees.
    #[arg(long, requires = "light_dir")]
    cone_deg: Option<f32>,
    /// Smooth (glTF) spot falloff instead of a hard cone.
    #[arg(long)]
    smooth: bool,
    /// Shadow rays per sender point for the direct light.
    #[arg(long, default_value_t = 8)]
    shadow_rays: u32,
    /// Probe points, rows x,y,z,nx,ny,nz.
    #[arg(long, requires = "probe_out")]
    probe: Option<PathBuf>,
    /// Where to write the probes' irradiance.
    #[arg(long, requires = "probe")]
    probe_out: Option<PathBuf>,
    /// Relight N frames with the light moving on a circle and report per-stage medians.
    #[arg(long)]
    frames: Option<u32>,
    /// Write the per-stage timings (JSON) here.
    #[arg(long)]
    timings_out: Option<PathBuf>,
}

fn vec3(s: &str) -> Result<Vec3, String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|c| {
            c.trim()
                .parse::<f32>()
                .map_err(|_| format!("'{c}' is not a number"))
        })
        .collect::<Result<_, _>>()?;
    if v.len() != 3 || v.iter().any(|c| !c.is_finite()) {
        return Err(format!("'{s}' is not three finite numbers x,y,z"));
    }
    Ok(Vec3::new(v[0], v[1], v[2]))
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    let path = &cli.file;
    let file = BakedFile::open(path).with_context(|| format!("opening {}", path.display()))?;
    let meta = file
        .meta()
        .with_context(|| format!("reading {}", path.display()))?;
    let ib = file
        .basis()
        .with_context(|| format!("reading {}", path.display()))?;
    let tm = file.transport_meta()?.with_context(|| {
        format!(
            "{}: no transport operator (baked with --basis-only?)",
            path.display()
        )
    })?;
    let link_bytes = file.links_bytes()?.context("no links section")?;
    let links = file.access_links(&link_bytes)?;

    if cli.probe.is_none() && cli.frames.is_none() {
        eprintln!(
            "{}: valid, {} basis points on {} levels, {} links; scene {}",
            path.display(),
            ib.basis.len(),
            ib.levels(),
            links.link_count(),
            meta.scene.source
        );
        eprintln!("view: GPU rendering (window and headless images) is not implemented yet; use --probe or --frames");
        std::process::exit(2);
    }

    let spec = cli
        .scene
        .clone()
        .unwrap_or_else(|| meta.scene.source.clone());
    let scene = mlt_scenes::load_scene(&spec)
        .with_context(|| format!("loading the scene {spec} (give --scene if it moved)"))?;
    if scene.content_hash != meta.scene.content_hash {
        eprintln!(
            "warning: {spec} has changed since {} was baked (content hash {:016x}, baked {:016x})",
            path.display(),
            scene.content_hash,
            meta.scene.content_hash
        );
    }
    let caster = scene.build_caster();

    let mut light = Light::from_info(&meta.light).context("the file's light")?;
    if let Some(p) = cli.light_pos {
        light.position = p;
    }
    if let Some(i) = cli.light_intensity {
        light.intensity = i.to_array();
    }
    if let (Some(d), Some(c)) = (cli.light_dir, cli.cone_deg) {
        light = Light::spot(light.position, light.intensity, d, c, cli.smooth)?;
    }
    // The overrides must be finite and non-negative too.
    Light::point(light.position, light.intensity)?;

    let sender_levels = tm.params.sender_levels as usize;
    let mut relighter =
        CpuRelighter::new(&ib, links, caster.as_ref(), sender_levels, cli.shadow_rays);

    if let (Some(input), Some(output)) = (&cli.probe, &cli.probe_out) {
        let text = std::fs::read_to_string(input)
            .with_context(|| format!("reading {}", input.display()))?;
        let probes = parse_probes(input, &text)?;
        let frame = relighter.relight(&light);
        let values: Vec<_> = probes
            .iter()
            .map(|p| evaluate(&ib, caster.as_ref(), &light, frame, sender_levels, p))
            .collect();
        if values.iter().flatten().flatten().any(|v| !v.is_finite()) {
            bail!("a probe's irradiance is not finite");
        }
        mlt_format::file::write_atomic(output, to_csv(&probes, &values).as_bytes())
            .with_context(|| format!("writing {}", output.display()))?;
        eprintln!("{} probes written to {}", probes.len(), output.display());
    }

    if let Some(n) = cli.frames {
        let (lo, hi) = (
            Vec3::from(meta.scene.bounds_min),
            Vec3::from(meta.scene.bounds_max),
        );
        let radius = 0.05 * (hi - lo).length();
        let centre = light.position;
        let mut per_stage: [Vec<f64>; 4] = Default::default();
        let mut senders = Vec::new();
        for f in 0..n.max(1) {
            let a = std::f32::consts::TAU * f as f32 / n.max(1) as f32;
            light.position = centre + Vec3::new(radius * a.cos(), 0.0, radius * a.sin());
            let frame = relighter.relight(&light);
            let t: StageTimes = frame.times;
            per_stage[0].push(t.direct_ms);
            per_stage[1].push(t.project_ms);
            per_stage[2].push(t.transport_ms);
            per_stage[3].push(t.flatten_ms);
            senders.push(frame.senders_used as f64);
        }
        let [d, p, s, fl] = per_stage.map(median);
        let json = serde_json::json!({
            "file": path.display().to_string(),
            "frames": n,
            "moving_light": true,
            "shadow_rays": cli.shadow_rays,
            "threads": rayon::current_num_threads(),
            "median_ms": {"direct": d, "project": p, "transport": s, "flatten": fl, "total": d + p + s + fl},
            "median_senders_used": median(senders),
            "gpu": "not implemented yet: CPU relighting only",
        });
        eprintln!(
            "median per frame over {n} frames with a moving light: direct {d:.1} ms, pull-push {p:.1} ms, S e {s:.1} ms, flatten {fl:.1} ms"
        );
        if let Some(out) = &cli.timings_out {
            write_json(out, &json)?;
        } else {
            println!("{}", serde_json::to_string_pretty(&json)?);
        }
    }
    Ok(())
}

fn write_json(out: &Path, json: &serde_json::Value) -> Result<()> {
    mlt_format::file::write_atomic(out, serde_json::to_string_pretty(json)?.as_bytes())
        .with_context(|| format!("writing {}", out.display()))
}
