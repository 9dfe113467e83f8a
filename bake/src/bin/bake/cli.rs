//! The `bake` command line: the bake itself (the default command) and its subcommands.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};
use mlt_bake::BakeOptions;

/// Bakes a scene's light transport (Lehtinen et al. 2008) into one file for `view`.
#[derive(Parser)]
#[command(name = "bake", version, args_conflicts_with_subcommands = true)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Option<Command>,
    #[command(flatten)]
    pub bake: BakeArgs,
}

#[derive(Subcommand)]
pub enum Command {
    /// Combines the shards of `bake SCENE --shard I/N` into the file one bake would give.
    Merge(MergeArgs),
    /// Bakes every job of scene or batch manifests into --out-dir, skipping those up to date.
    Batch(BatchArgs),
    /// Prints the paper's Table-1 figures of baked files, beside the paper's or another bake's.
    Stats(StatsArgs),
    /// Prints what a baked file holds: version, scene, parameters, levels, sections.
    Info(InfoArgs),
}

/// `bake merge` (see the subcommand's help).
#[derive(Args)]
pub struct MergeArgs {
    /// The shard files, all N of them, in any order.
    #[arg(required = true)]
    pub shards: Vec<PathBuf>,
    /// The merged file.
    #[arg(short, long, value_name = "FILE")]
    pub output: PathBuf,
    /// The shards' scene, as given to `bake`: needed unless they were baked with
    /// --level0-paths 0.
    #[arg(long, value_name = "SCENE")]
    pub scene: Option<String>,
    /// Compress the file with zstd: smaller, but read into memory instead of mapped.
    #[arg(long)]
    pub compress: bool,
    /// Print only warnings and errors.
    #[arg(short, long)]
    pub quiet: bool,
}

/// `bake batch` (see the subcommand's help).
#[derive(Args)]
pub struct BatchArgs {
    /// Scene manifests, or batch manifests listing [[job]] entries.
    #[arg(required = true)]
    pub manifests: Vec<PathBuf>,
    /// Where to write NAME.mlt and NAME.json per job, and summary.md and summary.json.
    #[arg(long, value_name = "DIR")]
    pub out_dir: PathBuf,
    /// Jobs baked at once (they share the threads).
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub jobs: usize,
    /// Worker threads in all (default: all cores).
    #[arg(long, value_name = "N")]
    pub threads: Option<usize>,
    /// Bake even the jobs whose outputs are up to date.
    #[arg(long)]
    pub force: bool,
    /// Store wall-clock timings in the files (they then differ from run to run).
    #[arg(long, hide = true)]
    pub record_timings: bool,
    /// Compress the files with zstd: smaller, but read into memory instead of mapped.
    #[arg(long)]
    pub compress: bool,
    /// Print the summary as JSON instead of Markdown.
    #[arg(long)]
    pub json: bool,
    /// No per-stage log lines; only warnings, errors and the summary.
    #[arg(short, long)]
    pub quiet: bool,
}

/// `bake stats` (see the subcommand's help).
#[derive(Args)]
pub struct StatsArgs {
    /// Baked .mlt files, or the JSON statistics of `bake --stats-json`.
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// Compare with paper:sponza, paper:greathall, paper:jadepalace, or another .mlt or .json.
    #[arg(long, value_name = "WHAT")]
    pub against: Option<String>,
    /// Machine-readable JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// `bake info` (see the subcommand's help).
#[derive(Args)]
pub struct InfoArgs {
    /// A file written by `bake`.
    pub file: PathBuf,
    /// Machine-readable JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// `bake [SCENE]`: the bake's parameters ([`BakeOptions`]) and what to do with its output.
#[derive(Args)]
pub struct BakeArgs {
    /// A manifest (.toml), a mesh (.obj, .gltf, .glb) or builtin:cornell, builtin:sphere, ...
    /// (default: builtin:cornell).
    pub scene: Option<String>,
    /// Output file (default: the scene's name with .mlt, in the current directory).
    #[arg(short, long, value_name = "FILE")]
    pub output: Option<PathBuf>,
    #[command(flatten)]
    pub options: BakeOptions,
    /// Worker threads (default: all cores); the file is the same whatever the count.
    #[arg(long, value_name = "N")]
    pub threads: Option<usize>,
    /// Also write the statistics (the paper's Table-1 figures, rays, times) as JSON here.
    #[arg(long, value_name = "FILE")]
    pub stats_json: Option<PathBuf>,
    /// Print only warnings, errors and the output path.
    #[arg(short, long)]
    pub quiet: bool,
    /// Print the statistics as JSON on standard output instead of the output path.
    #[arg(long)]
    pub json: bool,
}
