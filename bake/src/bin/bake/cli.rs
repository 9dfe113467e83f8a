//! The `bake` command line: the bake itself (the default command) and its subcommands.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};
use mlt_bake::BakeOptions;

/// Bakes the meshless hierarchical basis of a scene (Lehtinen et al. 2008) into one file.
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
    /// Combines the shard files of `bake SCENE --shard I/N` (all N of them, any order) into
    /// the file a single bake gives.
    Merge(MergeArgs),
    /// Bakes every job of the given manifests (scene manifests, or batch manifests listing
    /// [[job]] entries): NAME.mlt and NAME.json per job in --out-dir, and summary.json and
    /// summary.md. Jobs whose outputs carry the same input key are skipped. Exits 1 when any
    /// job failed, after all the others finished.
    Batch(BatchArgs),
    /// Prints the paper's Table-1 columns for baked files (or --stats-json outputs), side by
    /// side; with --against, next to the paper's row or another bake, with ratios.
    Stats(StatsArgs),
    /// Prints what a baked file holds: version, scene, parameters, levels, sections.
    Info(InfoArgs),
}

/// `bake merge` (see the subcommand's help).
#[derive(Args)]
pub struct MergeArgs {
    #[arg(required = true)]
    pub shards: Vec<PathBuf>,
    #[arg(short, long)]
    pub output: PathBuf,
    /// The shards' scene (as given to `bake`), needed where they were baked with
    /// --level0-paths: the merge traces those paths, which end in the whole of T. Checked
    /// against the scene the shards record.
    #[arg(long, value_name = "SCENE")]
    pub scene: Option<String>,
    /// zstd-compress the file's sections.
    #[arg(long)]
    pub compress: bool,
    #[arg(short, long)]
    pub quiet: bool,
}

/// `bake batch` (see the subcommand's help).
#[derive(Args)]
pub struct BatchArgs {
    #[arg(required = true)]
    pub manifests: Vec<PathBuf>,
    #[arg(long)]
    pub out_dir: PathBuf,
    /// Jobs baked at once (they share the threads).
    #[arg(long, default_value_t = 1)]
    pub jobs: usize,
    /// Worker threads in all (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Bake even the jobs whose outputs are up to date.
    #[arg(long)]
    pub force: bool,
    /// Store wall-clock timings in the files (they then differ from run to run).
    #[arg(long)]
    pub record_timings: bool,
    /// zstd-compress the files' sections.
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
    /// .mlt files or JSON statistics written by --stats-json.
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// paper:sponza, paper:greathall, paper:jadepalace, or another .mlt / stats .json.
    #[arg(long)]
    pub against: Option<String>,
    /// Machine-readable JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// `bake info` (see the subcommand's help).
#[derive(Args)]
pub struct InfoArgs {
    pub file: PathBuf,
    /// Machine-readable JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// `bake [SCENE]`: the bake's parameters ([`BakeOptions`]) and what to do with its output.
#[derive(Args)]
pub struct BakeArgs {
    /// A manifest (.toml), a mesh (.obj, .gltf, .glb) or a built-in scene
    /// (builtin:cornell, builtin:sphere?albedo=0.5&radius=1, ...). Default: builtin:cornell.
    pub scene: Option<String>,
    /// Output file (default: the scene's name with extension .mlt, in the current directory).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    #[command(flatten)]
    pub options: BakeOptions,
    /// Worker threads (default: all cores). The result does not depend on it.
    #[arg(long)]
    pub threads: Option<usize>,
    /// Also write the statistics as JSON to this path.
    #[arg(long)]
    pub stats_json: Option<PathBuf>,
    /// Print only errors and the output path.
    #[arg(short, long)]
    pub quiet: bool,
    /// Print the statistics JSON on standard output instead of the output path.
    #[arg(long)]
    pub json: bool,
}
