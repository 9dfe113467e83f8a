//! Checks that outputs can be written before any work starts, so that a bake, a batch, a
//! shard or a merge aimed at a missing or unwritable directory fails at once, naming the path
//! and the reason, instead of after the computation.

use std::fs::OpenOptions;
use std::path::{Path, PathBuf};

/// An output that cannot be written.
#[derive(Debug, thiserror::Error)]
#[error("cannot write {}: {reason}", path.display())]
pub struct OutputError {
    pub path: PathBuf,
    pub reason: String,
}

/// The directory a file `path` is written into (`.` for a bare file name).
fn parent_dir(path: &Path) -> PathBuf {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Checks that each file in `paths` could be written: not a directory, its directory exists,
/// and a temporary file can be created there (and is removed at once).
pub fn files<P: AsRef<Path>>(paths: impl IntoIterator<Item = P>) -> Result<(), OutputError> {
    for path in paths {
        let path = path.as_ref();
        let fail = |reason: String| OutputError {
            path: path.to_path_buf(),
            reason,
        };
        if path.is_dir() {
            return Err(fail("it is a directory".into()));
        }
        directory(&parent_dir(path)).map_err(|e| fail(e.reason))?;
    }
    Ok(())
}

/// Checks that `dir` exists, is a directory, and a temporary file can be created in it.
pub fn directory(dir: &Path) -> Result<(), OutputError> {
    let fail = |reason: String| OutputError {
        path: dir.to_path_buf(),
        reason,
    };
    match std::fs::metadata(dir) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(fail(format!(
                "the directory {} does not exist",
                dir.display()
            )))
        }
        Err(e) => return Err(fail(format!("cannot look at {}: {e}", dir.display()))),
        Ok(m) if !m.is_dir() => return Err(fail(format!("{} is not a directory", dir.display()))),
        Ok(_) => {}
    }
    // The same naming as the writers' temporary files, which an interrupt removes.
    let probe = dir.join(format!(".mlt-output-check.tmp{}", std::process::id()));
    match OpenOptions::new().write(true).create_new(true).open(&probe) {
        Ok(_) => {
            let _ = std::fs::remove_file(&probe);
            Ok(())
        }
        Err(e) => Err(fail(format!(
            "cannot create a file in {}: {e}",
            dir.display()
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fresh directory, removed with its contents when dropped.
    fn temp(name: &str) -> mlt_test_support::TempDir {
        mlt_test_support::TempDir::new(&format!("outcheck-{name}"))
    }

    #[test]
    fn a_writable_directory_passes_and_keeps_no_probe() {
        let d = temp("ok");
        files([&d.join("x.mlt")]).unwrap();
        directory(&d).unwrap();
        assert_eq!(std::fs::read_dir(&d).unwrap().count(), 0);
    }

    #[test]
    fn missing_directories_files_as_directories_and_directories_as_files_fail() {
        let d = temp("bad");
        let file = d.join("plain");
        std::fs::write(&file, b"x").unwrap();
        let missing = d.join("nope").join("x.mlt");
        let e = files([&missing]).unwrap_err();
        assert_eq!(e.path, missing);
        assert!(e.to_string().contains("does not exist"), "{e}");
        let e = files([&file.join("x.mlt")]).unwrap_err();
        assert!(e.to_string().contains("not a directory"), "{e}");
        let e = files([&d]).unwrap_err();
        assert!(e.to_string().contains("is a directory"), "{e}");
        assert!(directory(&file).is_err());
        assert!(directory(&d.join("nope")).is_err());
    }
}
