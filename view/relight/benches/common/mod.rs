//! What the benchmarks share: the machine they run on, and the baked file they measure (named
//! by an environment variable, or a small Cornell box baked into a temporary directory).
//! (Each benchmark compiles this module on its own and uses part of it, hence the allowance.)
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use mlt_bake::{bake_scene, BakeOptions, Silent};
use mlt_format::container::SectionBytes;
use mlt_format::links::ArchivedLinks;
use mlt_format::{BakedFile, IndexedBasis, WriteOptions};

/// The CPU model and the threads available, as one line.
pub fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|info| {
            info.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, m)| m.trim().to_string())
        })
        .unwrap_or_else(|| std::env::consts::ARCH.to_string());
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    format!(
        "{cpu}, {cores} hardware threads available, {} rayon threads",
        rayon::current_num_threads()
    )
}

/// A baked file opened for the whole run (leaked: benchmarks read it from statics).
pub struct Baked {
    pub path: PathBuf,
    pub file: &'static BakedFile,
    pub ib: IndexedBasis,
    pub links: &'static ArchivedLinks,
    /// The temporary directory of a file baked here, removed by [`Baked::clean_up`].
    temp: Option<PathBuf>,
}

impl Baked {
    /// The file named by the environment variable `var`, or else a small Cornell box (4
    /// receiver levels, 40 coarse points) baked into a fresh temporary directory.
    pub fn open_or_bake(var: &str) -> Result<Baked> {
        let (path, temp) = match std::env::var_os(var) {
            Some(path) => (PathBuf::from(path), None),
            None => {
                let dir =
                    std::env::temp_dir().join(format!("mlt-relight-bench-{}", std::process::id()));
                std::fs::create_dir_all(&dir)
                    .with_context(|| format!("creating {}", dir.display()))?;
                let path = dir.join("cornell.mlt");
                eprintln!(
                    "{var} is not set: baking a small Cornell box into {}",
                    dir.display()
                );
                bake_small_cornell(&path)?;
                (path, Some(dir))
            }
        };
        let file: &'static BakedFile = Box::leak(Box::new(
            BakedFile::open(&path).with_context(|| format!("opening {}", path.display()))?,
        ));
        let ib = file.basis()?;
        let bytes: &'static SectionBytes<'static> = Box::leak(Box::new(
            file.links_bytes()?
                .with_context(|| format!("{} holds no links", path.display()))?,
        ));
        let links = file.access_links(bytes)?;
        Ok(Baked {
            path,
            file,
            ib,
            links,
            temp,
        })
    }

    /// Removes the temporary directory of a file baked here.
    pub fn clean_up(&self) {
        if let Some(dir) = &self.temp {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

/// Bakes `builtin:cornell` small enough for a debug build into `path`.
fn bake_small_cornell(path: &Path) -> Result<()> {
    let scene = mlt_scenes::load_scene("builtin:cornell")?;
    let opts = BakeOptions {
        receiver_levels: Some(4),
        coarse_count: Some(40),
        gather_rays: Some(64),
        ..Default::default()
    };
    let out = bake_scene(&scene, &opts, &Silent)?;
    mlt_format::file::write(path, &out.contents, WriteOptions::default())?;
    Ok(())
}
