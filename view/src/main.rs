//! `view`: the viewer of baked files (Lehtinen et al. 2008, sections 3.3 and 4.1).
//!
//! - `view FILE`: a window (winit + wgpu) with a free camera and a movable light;
//! - `view FILE --headless --out DIR`: the same rendering without a window, writing
//!   direct.exr, indirect.exr, final.exr (linear radiance), final.png (tone mapped) and
//!   timings.json; `--frames N` moves the light along a fixed path and reports medians;
//! - `view FILE --probe IN.csv --probe-out OUT.csv`: irradiance at given surface points;
//! - `view FILE --frames N` (without `--headless`): CPU relighting timings only.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Parser;
use glam::Vec3;
use mlt_format::BakedFile;
use mlt_view::gpu::mesh::GpuMesh;
use mlt_view::gpu::{Gpu, Renderer};
use mlt_view::headless::{light_on_path, median};
use mlt_view::probe::{evaluate, parse_probes, to_csv};
use mlt_view::{Camera, CpuRelighter, Light, Relight, StageTimes};

/// Views a baked light-transport file: window, headless images, probes.
#[derive(Parser)]
#[command(name = "view", version)]
struct Cli {
    /// A file written by `bake`.
    file: PathBuf,
    /// The scene to ray-cast for visibility and to rasterise (default: the source recorded
    /// in the file).
    #[arg(long)]
    scene: Option<String>,
    /// Render without a window into --out.
    #[arg(long, requires = "out")]
    headless: bool,
    /// Output directory of --headless.
    #[arg(long, requires = "headless")]
    out: Option<PathBuf>,
    /// Camera position (default: the file's camera).
    #[arg(long, value_parser = mlt_view::camera::parse_vec3)]
    camera_pos: Option<Vec3>,
    /// Camera target.
    #[arg(long, value_parser = mlt_view::camera::parse_vec3)]
    camera_target: Option<Vec3>,
    /// Camera up vector.
    #[arg(long, value_parser = mlt_view::camera::parse_vec3)]
    camera_up: Option<Vec3>,
    /// Vertical field of view, degrees.
    #[arg(long)]
    fovy: Option<f32>,
    /// Image width in pixels.
    #[arg(long)]
    width: Option<u32>,
    /// Image height in pixels.
    #[arg(long)]
    height: Option<u32>,
    /// Light position (default: the file's light).
    #[arg(long, value_parser = mlt_view::camera::parse_vec3)]
    light_pos: Option<Vec3>,
    /// Light RGB intensity in W/sr.
    #[arg(long, value_parser = mlt_view::camera::parse_vec3)]
    light_intensity: Option<Vec3>,
    /// Spot direction (with --cone-deg): makes the light a spot.
    #[arg(long, value_parser = mlt_view::camera::parse_vec3, requires = "cone_deg")]
    light_dir: Option<Vec3>,
    /// Spot full cone angle, degrees.
    #[arg(long, requires = "light_dir")]
    cone_deg: Option<f32>,
    /// Smooth (glTF) spot falloff instead of a hard cone.
    #[arg(long)]
    smooth: bool,
    /// Shadow rays per sender point for the direct light at the senders.
    #[arg(long, default_value_t = 8)]
    shadow_rays: u32,
    /// Cast every shadow ray at every point; by default half are cast first and the rest only
    /// where those disagree (the penumbra).
    #[arg(long)]
    all_shadow_rays: bool,
    /// Where the fourth relighting stage, flattening, runs: `gpu` (a compute pass), `cpu`, or
    /// `auto`: the GPU unless the adapter is a software rasteriser (on llvmpipe the compute
    /// pass costs more of the same CPU than the CPU path).
    #[arg(long, value_enum, default_value_t = FlattenOn::Auto)]
    flatten: FlattenOn,
    /// Shadow-map resolution of the rendered direct light.
    #[arg(long, default_value_t = 1024)]
    shadow_res: u32,
    /// Probe points, rows x,y,z,nx,ny,nz.
    #[arg(long, requires = "probe_out")]
    probe: Option<PathBuf>,
    /// Where to write the probes' irradiance.
    #[arg(long, requires = "probe")]
    probe_out: Option<PathBuf>,
    /// Relight (and with --headless render) N frames with the light moving on a circle and
    /// report per-stage medians.
    #[arg(long)]
    frames: Option<u32>,
    /// Without --headless: write the CPU stage timings (JSON) here.
    #[arg(long)]
    timings_out: Option<PathBuf>,
    /// Window mode, for scripts and tests: after N frames save a screenshot of every view
    /// (window-MODE.png in --screenshot-dir) and close.
    #[arg(long)]
    exit_after_frames: Option<u32>,
    /// With --headless: also render the brute-force path-traced reference with SPP paths per
    /// pixel (even; two independent halves state its noise) into DIR/reference_*.exr,
    /// reference.png and reference.json, for `compare`.
    #[arg(long, requires = "headless")]
    reference: Option<u32>,
    /// Seed of the reference's random streams.
    #[arg(long, default_value_t = 1)]
    reference_seed: u64,
    /// Where the window saves screenshots (P key).
    #[arg(long, default_value = ".")]
    screenshot_dir: PathBuf,
}

/// Where flattening runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum FlattenOn {
    Auto,
    Cpu,
    Gpu,
}

impl FlattenOn {
    fn on_gpu(self, gpu: &Gpu) -> bool {
        match self {
            FlattenOn::Gpu => true,
            FlattenOn::Cpu => false,
            FlattenOn::Auto => !gpu.is_software(),
        }
    }
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
    let link_bytes = file
        .links_bytes()?
        .with_context(|| format!("{}: no links section", path.display()))?;
    let links = file.access_links(&link_bytes)?;

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

    let c = &meta.camera;
    let camera = Camera::new(
        cli.camera_pos.unwrap_or(Vec3::from(c.position)),
        cli.camera_target.unwrap_or(Vec3::from(c.target)),
        cli.camera_up.unwrap_or(Vec3::from(c.up)),
        cli.fovy.unwrap_or(c.fovy_deg),
        cli.width.unwrap_or(c.width),
        cli.height.unwrap_or(c.height),
    )
    .context("the camera")?;

    let sender_levels = tm.params.sender_levels as usize;
    let mut relighter =
        CpuRelighter::new(&ib, links, caster.as_ref(), sender_levels, cli.shadow_rays);
    relighter.adaptive_shadows = !cli.all_shadow_rays;
    if relighter.flatten_op().is_some() && !relighter.load_stats().points_in_morton_order {
        eprintln!(
            "note: {} stores its points in an older order; baking it again makes CPU flattening \
             faster (about 40 % on Sponza)",
            path.display()
        );
    }
    let (lo, hi) = (
        Vec3::from(meta.scene.bounds_min),
        Vec3::from(meta.scene.bounds_max),
    );
    let path_radius = 0.05 * (hi - lo).length();

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
        if cli.frames.is_none() && !cli.headless {
            return Ok(());
        }
    }

    if cli.headless {
        let out = cli.out.as_deref().context("--headless needs --out DIR")?;
        let gpu = Gpu::headless().context("starting the GPU for --headless")?;
        let mesh = GpuMesh::from_scene(&scene);
        let mut renderer = Renderer::new(&gpu, &mesh, &ib.basis, cli.shadow_res)
            .context("setting up the renderer")?;
        if cli.flatten.on_gpu(&gpu) {
            mlt_view::headless::flatten_on_gpu(&gpu, &mut renderer, &mut relighter)
                .context("uploading the flattening operator")?;
        }
        let (buffers, timings) = mlt_view::headless::render(
            &gpu,
            &mut renderer,
            &mut relighter,
            &ib,
            &camera,
            &light,
            cli.frames.unwrap_or(1),
            path_radius,
        )
        .with_context(|| format!("rendering {}", path.display()))?;
        let mut timings = timings;
        timings.load = Some(*relighter.load_stats());
        mlt_view::headless::write_outputs(out, &buffers, &timings)?;
        if let Some(spp) = cli.reference {
            let start = std::time::Instant::now();
            let r = mlt_view::reference::render_reference(
                caster.as_ref(),
                &camera,
                &light,
                spp,
                cli.reference_seed,
            )
            .context("rendering the reference")?;
            mlt_view::reference::write_reference(out, &r)
                .with_context(|| format!("writing the reference into {}", out.display()))?;
            eprintln!(
                "reference: {spp} paths per pixel in {:.1} s, written to {}/reference_*.exr (compare with: compare {} {})",
                start.elapsed().as_secs_f64(),
                out.display(),
                out.display(),
                out.display()
            );
        }
        let c = &timings.cpu_median_ms;
        let g = &timings.gpu_median_ms;
        eprintln!(
            "{}x{} on {} ({}): wrote {}/{{direct,indirect,final}}.exr, final.png, timings.json",
            camera.width,
            camera.height,
            timings.adapter.name,
            timings.adapter.backend,
            out.display()
        );
        eprintln!(
            "median over {} frame(s): CPU direct {:.1} + pull-push {:.1} + S e {:.1} + flatten {:.1} = {:.1} ms; GPU passes {:.1} ms, of which flattening {:.1} ms ({} of {} basis functions splatted)",
            timings.frames, c.direct, c.project, c.transport, c.flatten, c.total, g.total,
            g.flatten, timings.splatted_points, timings.basis_points
        );
        let l = relighter.load_stats();
        eprintln!(
            "set-up once per file: {:.0} ms building the relighting operators ({:.1} MB)",
            l.build_ms,
            (l.flatten_bytes + l.pull_push_bytes + l.links_bytes) as f64 / 1e6
        );
        return Ok(());
    }

    if let Some(n) = cli.frames {
        let mut per_stage: [Vec<f64>; 4] = Default::default();
        let mut senders = Vec::new();
        let mut rays = Vec::new();
        for f in 0..n.max(1) {
            let l = light_on_path(&light, path_radius, f, n.max(1));
            let frame = relighter.relight(&l);
            let t: StageTimes = frame.times;
            per_stage[0].push(t.direct_ms);
            per_stage[1].push(t.project_ms);
            per_stage[2].push(t.transport_ms);
            per_stage[3].push(t.flatten_ms);
            senders.push(frame.senders_used as f64);
            rays.push(frame.shadow_rays as f64);
        }
        let [d, p, s, fl] = per_stage.map(median);
        let json = serde_json::json!({
            "file": path.display().to_string(),
            "frames": n,
            "moving_light": true,
            "shadow_rays": cli.shadow_rays,
            "adaptive_shadow_rays": !cli.all_shadow_rays,
            "threads": rayon::current_num_threads(),
            "median_ms": {"direct": d, "project": p, "transport": s, "flatten": fl, "total": d + p + s + fl},
            "median_senders_used": median(senders),
            "median_shadow_rays_cast": median(rays),
            "load": relighter.load_stats(),
            "gpu": "not used: CPU relighting only (add --headless --out DIR to render)",
        });
        eprintln!(
            "median per frame over {n} frames with a moving light: direct {d:.1} ms, pull-push {p:.1} ms, S e {s:.1} ms, flatten {fl:.1} ms"
        );
        if let Some(out) = &cli.timings_out {
            write_json(out, &json)?;
        } else {
            println!("{}", serde_json::to_string_pretty(&json)?);
        }
        return Ok(());
    }

    mlt_view::window::run(mlt_view::window::WindowSetup {
        title: format!("view {}", path.display()),
        scene: &scene,
        ib: &ib,
        relighter: &mut relighter,
        camera,
        light,
        bounds: (lo, hi),
        shadow_res: cli.shadow_res,
        gpu_flatten: match cli.flatten {
            FlattenOn::Gpu => Some(true),
            FlattenOn::Cpu => Some(false),
            FlattenOn::Auto => None,
        },
        exit_after_frames: cli.exit_after_frames,
        screenshot_dir: cli.screenshot_dir.clone(),
    })
}

fn write_json(out: &Path, json: &serde_json::Value) -> Result<()> {
    mlt_format::file::write_atomic(out, serde_json::to_string_pretty(json)?.as_bytes())
        .with_context(|| format!("writing {}", out.display()))
}
