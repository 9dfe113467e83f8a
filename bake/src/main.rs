//! `bake`: scene in, versioned memory-mappable basis file out.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use mlt_bake::batch::{read_jobs, run_batch, stats_json, summary_markdown, BatchSettings};
use mlt_bake::report::{bake_table, estimate_table, info_text, transport_table};
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
    /// Combines the shard files of `bake SCENE --shard I/N` (all N of them, any order) into
    /// the file a single bake gives.
    Merge {
        #[arg(required = true)]
        shards: Vec<PathBuf>,
        #[arg(short, long)]
        output: PathBuf,
        /// zstd-compress the file's sections.
        #[arg(long)]
        compress: bool,
        #[arg(short, long)]
        quiet: bool,
    },
    /// Bakes every job of the given manifests (scene manifests, or batch manifests listing
    /// [[job]] entries): NAME.mlt and NAME.json per job in --out-dir, and summary.json and
    /// summary.md. Jobs whose outputs carry the same input key are skipped. Exits 1 when any
    /// job failed, after all the others finished.
    Batch(BatchArgs),
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

/// `bake batch` (see the subcommand's help).
#[derive(Args)]
struct BatchArgs {
    #[arg(required = true)]
    manifests: Vec<PathBuf>,
    #[arg(long)]
    out_dir: PathBuf,
    /// Jobs baked at once (they share the threads).
    #[arg(long, default_value_t = 1)]
    jobs: usize,
    /// Worker threads in all (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Bake even the jobs whose outputs are up to date.
    #[arg(long)]
    force: bool,
    /// Store wall-clock timings in the files (they then differ from run to run).
    #[arg(long)]
    record_timings: bool,
    /// zstd-compress the files' sections.
    #[arg(long)]
    compress: bool,
    /// Print the summary as JSON instead of Markdown.
    #[arg(long)]
    json: bool,
    /// No per-stage log lines; only warnings, errors and the summary.
    #[arg(short, long)]
    quiet: bool,
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
    /// Bounces of the Neumann series S = T + T^2 + ...: a count (paper: 4), or `auto` to
    /// choose it from the spectral-radius estimate so that the bounces left out carry at
    /// most --bounce-tolerance of the indirect light (`auto:N` caps it at N, default 1000).
    #[arg(long, value_name = "N|auto|auto:N", value_parser = parse_bounces)]
    bounces: Option<BounceArg>,
    /// Fraction of the indirect light the series may leave out (default 0.01): the target of
    /// --bounces auto, and the threshold above which a fixed count is warned about.
    #[arg(long)]
    bounce_tolerance: Option<f64>,
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
    /// Compute shard I of N of the transport (I from 0) into a shard file for `bake merge`.
    #[arg(long, value_name = "I/N", value_parser = parse_shard)]
    shard: Option<(u32, u32)>,
    /// Dart thrower's consecutive-miss limit (paper: 2000).
    #[arg(long)]
    max_misses: Option<u32>,
    /// Print only errors and the output path.
    #[arg(short, long)]
    quiet: bool,
    /// Print the statistics JSON on standard output instead of the output path.
    #[arg(long)]
    json: bool,
}

/// Progress bars on a terminal, one log line per stage otherwise.
struct Reporter {
    start: Instant,
    quiet: bool,
    bar: Mutex<Option<ProgressBar>>,
    tty: bool,
    /// Put before every line (the job's name in a batch).
    prefix: String,
}

impl Reporter {
    fn new(quiet: bool) -> Reporter {
        Reporter {
            start: Instant::now(),
            quiet,
            bar: Mutex::new(None),
            tty: std::io::stderr().is_terminal(),
            prefix: String::new(),
        }
    }

    fn line(&self, msg: &str) {
        if !self.quiet {
            let elapsed = self.start.elapsed().as_secs_f64();
            let text = format!("[{elapsed:8.2}s] {}{msg}", self.prefix);
            match self.bar.lock().ok().and_then(|b| b.clone()) {
                Some(bar) => bar.println(text),
                None => eprintln!("{text}"),
            }
        }
    }
}

impl Observer for Reporter {
    fn stage(&self, name: &str) {
        // Bars only for a single bake on a terminal; concurrent jobs log lines.
        if self.quiet || !self.tty || !self.prefix.is_empty() {
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

    fn step(&self, done: u64, total: u64, detail: &str) {
        self.progress(done, total);
        self.line(detail);
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
        eprintln!("warning: {}{message}", self.prefix);
    }
}

/// `--bounces`: a count or `auto[:cap]`.
#[derive(Clone, Copy, Debug)]
struct BounceArg {
    auto: bool,
    count: Option<u32>,
}

fn parse_bounces(s: &str) -> Result<BounceArg, String> {
    let s = s.trim();
    let count = |t: &str| {
        t.trim()
            .parse::<u32>()
            .map_err(|_| format!("'{t}' is not a bounce count (a whole number >= 1)"))
    };
    match s.strip_prefix("auto") {
        Some("") => Ok(BounceArg {
            auto: true,
            count: None,
        }),
        Some(rest) => match rest.strip_prefix(':') {
            Some(cap) => Ok(BounceArg {
                auto: true,
                count: Some(count(cap)?),
            }),
            None => Err(format!("'{s}' is not N, auto or auto:N")),
        },
        None => Ok(BounceArg {
            auto: false,
            count: Some(count(s)?),
        }),
    }
}

fn parse_shard(s: &str) -> Result<(u32, u32), String> {
    let (i, n) = s
        .split_once('/')
        .ok_or_else(|| format!("'{s}' is not I/N"))?;
    let i: u32 = i
        .trim()
        .parse()
        .map_err(|_| format!("'{i}' is not a shard index"))?;
    let n: u32 = n
        .trim()
        .parse()
        .map_err(|_| format!("'{n}' is not a shard count"))?;
    if n == 0 || i >= n {
        return Err(format!("shard {i}/{n}: need 0 <= I < N"));
    }
    Ok((i, n))
}

fn run_merge(shards: &[PathBuf], output: &Path, compress: bool, quiet: bool) -> Result<()> {
    mlt_bake::output_check::files([output])?;
    let mut contents = Vec::new();
    for s in shards {
        let f = BakedFile::open(s).with_context(|| format!("opening {}", s.display()))?;
        contents.push(
            f.contents()
                .with_context(|| format!("reading {}", s.display()))?,
        );
    }
    let reporter = Reporter::new(quiet);
    let merged = mlt_bake::shard::merge(contents, &reporter).context("merging")?;
    let size = mlt_format::file::write(output, &merged, WriteOptions { compress })
        .with_context(|| format!("writing {}", output.display()))?;
    if !quiet {
        if let Some(t) = &merged.transport {
            eprint!("{}", transport_table(&t.meta, None));
            if let Some(r) = &t.report {
                eprint!("{}", estimate_table(r));
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
    mlt_bake::output_check::files(std::iter::once(&output).chain(&args.stats_json))?;
    let mut builder = rayon::ThreadPoolBuilder::new();
    if let Some(t) = args.threads {
        anyhow::ensure!(t >= 1, "--threads must be at least 1");
        builder = builder.num_threads(t);
    }
    let pool = builder.build().context("starting the worker threads")?;
    let reporter = Reporter::new(args.quiet);
    let out_dir = match output.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    watch_for_interrupts(&out_dir);
    let opts = BakeOptions {
        receiver_levels: args.receiver_levels,
        coarse_count: args.coarse_count,
        coarse_radius: args.coarse_radius,
        seed: args.seed,
        max_misses: args.max_misses,
        epsilon: args.epsilon,
        bounce_epsilon: args.bounce_epsilon,
        sender_levels: args.sender_levels,
        bounces: args.bounces.and_then(|b| b.count),
        auto_bounces: args.bounces.is_some_and(|b| b.auto),
        bounce_tolerance: args.bounce_tolerance,
        gather_rays: args.gather_rays,
        bounces_on_all_receivers: args.bounces_on_all_receivers,
        basis_only: args.basis_only,
        shard: args.shard,
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
            if let Some(r) = &t.report {
                eprint!("{}", estimate_table(r));
            }
        }
    }
    let json = stats_json(&output, size, &out);
    let text = serde_json::to_string_pretty(&json).context("formatting statistics")?;
    if let Some(path) = &args.stats_json {
        mlt_format::file::write_atomic(path, text.as_bytes())
            .with_context(|| format!("writing statistics to {}", path.display()))?;
    }
    if let (false, Some(s)) = (args.quiet, &out.contents.shard) {
        eprintln!(
            "shard {}/{}: {} receivers, {} links of T (combine all shards with `bake merge`)",
            s.index,
            s.count,
            s.rows.len(),
            s.senders.len()
        );
    }
    if args.json {
        println!("{text}");
    } else {
        println!("{}", output.display());
    }
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

fn run_batch_command(args: &BatchArgs) -> Result<()> {
    let BatchArgs {
        manifests,
        out_dir,
        jobs,
        threads,
        force,
        record_timings,
        compress,
        json,
        quiet,
    } = args;
    let (jobs, threads, force, record_timings, compress, json, quiet) = (
        *jobs,
        *threads,
        *force,
        *record_timings,
        *compress,
        *json,
        *quiet,
    );
    let mut all = Vec::new();
    for m in manifests {
        all.extend(read_jobs(m).with_context(|| format!("reading {}", m.display()))?);
    }
    watch_for_interrupts(out_dir);
    let settings = BatchSettings {
        out_dir: out_dir.to_path_buf(),
        jobs,
        threads: threads.unwrap_or_else(|| {
            std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1)
        }),
        record_timings,
        compress,
        force,
    };
    let start = Instant::now();
    let observer = |name: &str| -> Box<dyn Observer> {
        let mut r = Reporter::new(quiet);
        r.start = start;
        r.prefix = format!("{name}: ");
        Box::new(r)
    };
    let summary = run_batch(&all, &settings, &observer).context("running the batch")?;
    if json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        print!("{}", summary_markdown(&summary));
    }
    if summary.failed > 0 {
        let names: Vec<&str> = summary
            .jobs
            .iter()
            .filter(|j| j.status == "failed")
            .map(|j| j.name.as_str())
            .collect();
        eprintln!(
            "error: {} of {} jobs failed: {}",
            summary.failed,
            summary.jobs.len(),
            names.join(", ")
        );
        std::process::exit(1);
    }
    Ok(())
}

/// On Ctrl-C or SIGTERM, removes this process' temporary files in `dir` (outputs are written
/// to `.NAME.tmpPID` and renamed into place, so a finished output is never partial and an
/// unfinished one never appears) and exits with status 130.
fn watch_for_interrupts(dir: &Path) {
    let dir = dir.to_path_buf();
    let suffix = format!(".tmp{}", std::process::id());
    let result = ctrlc::set_handler(move || {
        if let Ok(entries) = std::fs::read_dir(&dir) {
            for e in entries.flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                if name.starts_with('.') && name.ends_with(&suffix) {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
        eprintln!("interrupted: no partial output left in {}", dir.display());
        std::process::exit(130);
    });
    if let Err(e) = result {
        eprintln!("warning: cannot watch for interrupts: {e}");
    }
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Merge {
            shards,
            output,
            compress,
            quiet,
        }) => run_merge(&shards, &output, compress, quiet),
        Some(Command::Batch(args)) => run_batch_command(&args),
        Some(Command::Info { file, json }) => run_info(&file, json),
        Some(Command::Stats {
            files,
            against,
            json,
        }) => run_stats(&files, against.as_deref(), json),
        None => run_bake(cli.bake),
    }
}
