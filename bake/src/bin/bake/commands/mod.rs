//! The commands of `bake`, one module each, and what they share.

pub mod bake;
pub mod batch;
pub mod info;
pub mod merge;
pub mod stats;

use std::path::Path;

/// On Ctrl-C or SIGTERM, removes this process' temporary files in `dir` (outputs are written
/// to `.NAME.tmpPID` and renamed into place, so a finished output is never partial and an
/// unfinished one never appears) and exits with status 130.
pub fn watch_for_interrupts(dir: &Path) {
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
