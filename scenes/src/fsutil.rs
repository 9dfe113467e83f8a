//! Small file-system helpers shared by the loaders.

use std::path::{Path, PathBuf};

/// Returns `path` if it exists; otherwise looks in its directory for a file whose name
/// differs only in ASCII case (scene files written on case-insensitive systems often
/// disagree with their references, e.g. `KAMEN-stup.jpg` vs `KAMEN-stup.JPG`). Only the
/// file name is matched case-insensitively, not the directories above it.
pub(crate) fn resolve_case_insensitive(path: &Path) -> Option<PathBuf> {
    if path.is_file() {
        return Some(path.to_path_buf());
    }
    let name = path.file_name()?.to_str()?;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let mut matches: Vec<PathBuf> = std::fs::read_dir(dir)
        .ok()?
        .filter_map(|e| e.ok())
        .filter(|e| {
            e.file_name()
                .to_str()
                .is_some_and(|n| n.eq_ignore_ascii_case(name))
        })
        .map(|e| e.path())
        .filter(|p| p.is_file())
        .collect();
    // Directory order is arbitrary; pick deterministically.
    matches.sort();
    matches.into_iter().next()
}

/// Joins a file reference from a scene file (MTL `map_Kd`, `mtllib`, ...) to `base`,
/// accepting Windows separators.
pub(crate) fn join_reference(base: &Path, reference: &str) -> PathBuf {
    base.join(reference.trim().replace('\\', "/"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_file_with_different_case() {
        let dir = mlt_test_support::TempDir::new("fsutil");
        let real = dir.join("Tex.JPG");
        std::fs::write(&real, b"x").expect("write");
        assert_eq!(
            resolve_case_insensitive(&dir.join("tex.jpg")),
            Some(real.clone())
        );
        assert_eq!(resolve_case_insensitive(&real), Some(real.clone()));
        assert_eq!(resolve_case_insensitive(&dir.join("other.jpg")), None);
    }
}
