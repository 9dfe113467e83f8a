//! `bake`: scene in, versioned memory-mappable basis file out.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use mlt_bake::report::{bake_table, info_text, transport_table};
use mlt_bake::table1::{compare_json, compare_text, our_row, paper_row, Table1Row};
use mlt_bake::{bake_scene, BakeOptions, Observer};
use mlt_format::{BakedFile, WriteOptions};

/// Bakes the meshless hierarchical basis of a scene (Lehtinen et al. 2008) into one file.
#[derive(Parser)]
#[command(name = "bake", version, args_conflicts_with_subcommands = true)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    bake: BakeArgs,
}

#[derive(Subcommand)]
enum Command {
    /// Prints the paper's Table-1 columns for baked files (or --stats-json outputs), side by
    /// side; with --against, next to the paper's row or another bake, with ratios.
    Stats {
        /// .mlt files or JSON statistics written by --stats-json.
        #[arg(required = true)]
        files: Vec<PathBuf>,
        /// paper:sponza, paper:greathall, paper:jadepalace, or another .mlt / stats .json.
        #[arg(long)]
        against: Option<String>,
        /// Machine-readable JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Prints what a baked file holds: version, scene, parameters, levels, sections.
    Info {
        file: PathBuf,
        /// Machine-readable JSON instead of text.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Args)]
struct BakeArgs {
    /// A manifest (.toml), a mesh (.obj, .gltf, .glb) or a built-in scene
    /// (builtin:cornell, builtin:sphere?albedo=0.5&radius=1, ...). Default: builtin:cornell.
    scene: Option<String>,
    /// Output file (default: the scene's name with extension .mlt, in the current directory).
    #[arg(short, long)]
    output: Option<PathBuf>,
    /// Number of hierarchy levels (paper: 6).
    #[arg(long)]
    receiver_levels: Option<u32>,
    /// Choose R_coarse so that level 0 has about this many points (paper's Sponza: 339).
    #[arg(long, conflicts_with = "coarse_radius")]
    coarse_count: Option<u32>,
    /// Level-0 Poisson-disk radius R_coarse in scene units (after the manifest's scale).
    #[arg(long)]
    coarse_radius: Option<f32>,
    /// Random seed; the same seed and inputs give a byte-identical file.
    #[arg(long)]
    seed: Option<u64>,
    /// Worker threads (default: all cores). The result does not depend on it.
    #[arg(long)]
    threads: Option<usize>,
    /// Also write the statistics as JSON to this path.
    #[arg(long)]
    stats_json: Option<PathBuf>,
    /// Store wall-clock timings in the file (the file then differs from run to run).
    #[arg(long)]
    record_timings: bool,
    /// zstd-compress the file's sections (smaller; readers decompress instead of mapping).
    #[arg(long)]
    compress: bool,
    /// Link threshold epsilon (paper: 0.025).
    #[arg(long)]
    epsilon: Option<f32>,
    /// Truncation threshold of bounces 2 and later (default: epsilon, as the paper; a smaller
    /// value keeps multi-bounce energy that epsilon would drop, see the bounce norms).
    #[arg(long)]
    bounce_epsilon: Option<f32>,
    /// Sender levels, the coarsest of the receiver levels (paper: 3).
    #[arg(long)]
    sender_levels: Option<u32>,
    /// Most bounces of the Neumann series S = T + T^2 + ... (paper: 4).
    #[arg(long)]
    bounces: Option<u32>,
    /// Rays per receiver gather (Eq. 16).
    #[arg(long)]
    gather_rays: Option<u32>,
    /// Compute bounces 2 and later on every refined receiver, not only the coarsest (the
    /// paper's choice; more accurate on curved geometry, slower).
    #[arg(long)]
    bounces_on_all_receivers: bool,
    /// Place the basis only; compute no transport operator.
    #[arg(long)]
    basis_only: bool,
    /// Dart thrower's consecutive-miss limit (paper: 2000).
    #[arg(long)]
    max_misses: Option<u32>,
    /// Print only errors and the output path.
    #[arg(short, long)]
    quiet: bool,
}

/// Progress bars on a terminal, one log line per stage otherwise.
struct Reporter {
    start: Instant,
    quiet: bool,
    bar: Mutex<Option<ProgressBar>>,
    tty: bool,
}

impl Reporter {
    fn new(quiet: bool) -> Reporter {
        Reporter {
            start: Instant::now(),
            quiet,
            bar: Mutex::new(None),
            tty: std::io::stderr().is_terminal(),
        }
    }

    fn line(&self, msg: &str) {
        if !self.quiet {
            let elapsed = self.start.elapsed().as_secs_f64();
            match self.bar.lock().ok().and_then(|b| b.clone()) {
                Some(bar) => bar.println(format!("[{elapsed:8.2}s] {msg}")),
                None => eprintln!("[{elapsed:8.2}s] {msg}"),
            }
        }
    }
}

impl Observer for Reporter {
    fn stage(&self, name: &str) {
        if self.quiet || !self.tty {
            return;
        }
        let bar = ProgressBar::new_spinner().with_message(name.to_string());
        if let Ok(style) = ProgressStyle::with_template("{spinner} {msg} {pos}/{len} [{elapsed}]") {
            bar.set_style(style);
        }
        bar.enable_steady_tick(std::time::Duration::from_millis(120));
        if let Ok(mut b) = self.bar.lock() {
            if let Some(old) = b.replace(bar) {
                old.finish_and_clear();
            }
        }
    }

    fn progress(&self, done: u64, total: u64) {
        if let Ok(b) = self.bar.lock() {
            if let Some(bar) = b.as_ref() {
                bar.set_length(total);
                bar.set_position(done);
            }
        }
    }

    fn done(&self, name: &str, secs: f64, detail: &str) {
        if let Ok(mut b) = self.bar.lock() {
            if let Some(bar) = b.take() {
                bar.finish_and_clear();
            }
        }
        self.line(&format!("{name}: {detail} ({secs:.2} s)"));
    }

    fn warn(&self, message: &str) {
        // Warnings show even with --quiet.
        eprintln!("warning: {message}");
    }
}

fn default_output(spec: &str) -> PathBuf {
    let stem = match spec.strip_prefix("builtin:") {
        Some(rest) => rest.split('?').next().unwrap_or("builtin").to_string(),
        None => Path::new(spec)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "scene".into()),
    };
    PathBuf::from(format!("{stem}.mlt"))
}

fn run_bake(args: BakeArgs) -> Result<()> {
    let spec = args
        .scene
        .clone()
        .unwrap_or_else(|| "builtin:cornell".into());
    let output = args.output.clone().unwrap_or_else(|| default_output(&spec));
    let mut builder = rayon::ThreadPoolBuilder::new();
    if let Some(t) = args.threads {
        anyhow::ensure!(t >= 1, "--threads must be at least 1");
        builder = builder.num_threads(t);
    }
    let pool = builder.build().context("starting the worker threads")?;
    let reporter = Reporter::new(args.quiet);
    let opts = BakeOptions {
        receiver_levels: args.receiver_levels,
        coarse_count: args.coarse_count,
        coarse_radius: args.coarse_radius,
        seed: args.seed,
        max_misses: args.max_misses,
        epsilon: args.epsilon,
        bounce_epsilon: args.bounce_epsilon,
        sender_levels: args.sender_levels,
        bounces: args.bounces,
        gather_rays: args.gather_rays,
        bounces_on_all_receivers: args.bounces_on_all_receivers,
        basis_only: args.basis_only,
        record_timings: args.record_timings,
        compress: args.compress,
    };

    let t = Instant::now();
    let scene = mlt_scenes::load_scene(&spec).with_context(|| format!("loading scene {spec}"))?;
    let load_s = t.elapsed().as_secs_f64();
    reporter.line(&format!(
        "loaded {spec}: {} triangles ({load_s:.2} s)",
        scene.triangle_count()
    ));
    for w in &scene.warnings {
        reporter.warn(w);
    }

    let mut out = pool
        .install(|| bake_scene(&scene, &opts, &reporter))
        .with_context(|| format!("baking {spec}"))?;
    out.timings.load_s = load_s;
    out.timings.total_s += load_s;
    if let Some(t) = out.contents.meta.timings.as_mut() {
        t.load_s = load_s;
        t.total_s = out.timings.total_s;
    }

    let t = Instant::now();
    let size = mlt_format::file::write(
        &output,
        &out.contents,
        WriteOptions {
            compress: opts.compress,
        },
    )
    .with_context(|| format!("writing {}", output.display()))?;
    out.timings.write_s = t.elapsed().as_secs_f64();
    out.timings.total_s += out.timings.write_s;

    if !args.quiet {
        eprint!("{}", bake_table(&out.contents.meta, &out.timings, size));
        if let Some(t) = &out.contents.transport {
            eprint!(
                "{}",
                transport_table(&t.meta, out.transport_timings.as_ref())
            );
        }
    }
    if let Some(path) = &args.stats_json {
        let json = serde_json::json!({
            "file": output.display().to_string(),
            "file_bytes": size,
            "meta": &out.contents.meta,
            "timings": &out.timings,
            "transport": out.contents.transport.as_ref().map(|t| {
                let mut m = t.meta.clone();
                m.timings = out.transport_timings.clone();
                m
            }),
            "warnings": &out.warnings,
        });
        let text = serde_json::to_string_pretty(&json).context("formatting statistics")?;
        mlt_format::file::write_atomic(path, text.as_bytes())
            .with_context(|| format!("writing statistics to {}", path.display()))?;
    }
    println!("{}", output.display());
    Ok(())
}

fn run_info(file: &Path, json: bool) -> Result<()> {
    let baked = BakedFile::open(file).with_context(|| format!("opening {}", file.display()))?;
    let info = baked
        .info()
        .with_context(|| format!("reading {}", file.display()))?;
    if json {
        println!("{}", serde_json::to_string_pretty(&info)?);
    } else {
        print!("{}", info_text(&info));
    }
    Ok(())
}

/// A Table-1 row from a baked file or a `--stats-json` output.
fn load_row(path: &Path) -> Result<Table1Row> {
    if path.extension().is_some_and(|e| e == "json") {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let v: serde_json::Value =
            serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))?;
        let meta: mlt_format::Meta = serde_json::from_value(v["meta"].clone())
            .with_context(|| format!("{}: no bake statistics in it", path.display()))?;
        let transport: Option<mlt_format::meta::TransportMeta> =
            serde_json::from_value(v["transport"].clone()).unwrap_or(None);
        let timings: Option<mlt_format::meta::Timings> =
            serde_json::from_value(v["timings"].clone()).ok();
        let mut row = our_row(
            &meta,
            transport.as_ref(),
            v["file_bytes"].as_u64(),
            timings.as_ref(),
            None,
        );
        row.title = path.display().to_string();
        return Ok(row);
    }
    let f = BakedFile::open(path).with_context(|| format!("opening {}", path.display()))?;
    let meta = f
        .meta()
        .with_context(|| format!("reading {}", path.display()))?;
    let transport = f
        .transport_meta()
        .with_context(|| format!("reading {}", path.display()))?;
    let mut row = our_row(&meta, transport.as_ref(), Some(f.file_len()), None, None);
    row.title = path.display().to_string();
    Ok(row)
}

fn run_stats(files: &[PathBuf], against: Option<&str>, json: bool) -> Result<()> {
    let mut rows = files
        .iter()
        .map(|f| load_row(f))
        .collect::<Result<Vec<_>>>()?;
    if let Some(a) = against {
        let other = match a.strip_prefix("paper:") {
            Some(name) => {
                let mut r = paper_row(name).with_context(|| {
                    format!("no paper row '{name}' (known: sponza, greathall, jadepalace)")
                })?;
                r.title = format!("paper: {}", r.title);
                r
            }
            None => load_row(Path::new(a))?,
        };
        rows.push(other);
    }
    let refs: Vec<&Table1Row> = rows.iter().collect();
    if json {
        println!("{}", serde_json::to_string_pretty(&compare_json(&refs))?);
    } else {
        print!("{}", compare_text(&refs));
    }
    Ok(())
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Info { file, json }) => run_info(&file, json),
        Some(Command::Stats {
            files,
            against,
            json,
        }) => run_stats(&files, against.as_deref(), json),
        None => run_bake(cli.bake),
    }
}
