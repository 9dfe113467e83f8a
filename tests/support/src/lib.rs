//! What the tests of every crate share: a temporary directory that removes itself, one
//! policy for the third-party scenes that live outside the repository, and the commands'
//! printed help read back ([`help`]).
//!
//! The scenes (Cornell box, Sponza, Sibenik, conference room: OBJ files with their materials
//! and textures) are not committed; they sit in a `shared/scenes` folder beside the checkout
//! (`../shared/scenes` from the workspace root), or wherever `MLT_SHARED` points. A test that
//! needs one asks [`shared_scene`], which panics with the path it looked at when the scene is
//! missing: a missing scene fails the test, it never lets it pass without checking anything.
//!
//! The repository's manifests of these scenes (`scenes/*.toml`) name their meshes as
//! `../../shared/scenes/...`, relative to the manifest; [`shared_manifest`] gives a copy that
//! points at the shared folder wherever it is (a worktree elsewhere, `MLT_SHARED`).

pub mod help;

use std::ops::Deref;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// The environment variable that names the shared folder.
pub const SHARED_ENV: &str = "MLT_SHARED";

/// The shared folder: `$MLT_SHARED` if set, else `shared` beside the workspace root.
pub fn shared_dir() -> PathBuf {
    match std::env::var_os(SHARED_ENV) {
        Some(p) => PathBuf::from(p),
        None => workspace_dir().join("../shared"),
    }
}

/// The workspace root (the directory holding the workspace's `Cargo.toml`).
pub fn workspace_dir() -> PathBuf {
    // This crate lives at `tests/support` in the workspace.
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The `shared/scenes` folder.
///
/// # Panics
/// When it does not exist, with a message naming the path looked at and `MLT_SHARED`.
pub fn shared_scenes() -> PathBuf {
    let p = shared_dir().join("scenes");
    if !p.is_dir() {
        panic!("{}", missing_message(&p));
    }
    p
}

/// The file or folder `relative` under `shared/scenes/`.
///
/// # Panics
/// When it does not exist, with a message naming the path looked at and `MLT_SHARED`.
pub fn shared_scene(relative: &str) -> PathBuf {
    let p = shared_scenes().join(relative);
    if !p.exists() {
        panic!("{}", missing_message(&p));
    }
    p
}

/// How the repository's manifests name the shared scenes (relative to `scenes/`).
const MANIFEST_PREFIX: &str = "\"../../shared/scenes/";

/// A copy of a repository manifest whose mesh lies in the shared scenes, with the mesh's path
/// made absolute under [`shared_scenes`]; the copy (same file name) lives as long as this.
#[derive(Debug)]
pub struct SharedManifest {
    path: PathBuf,
    _dir: TempDir,
}

impl SharedManifest {
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The copy as a scene specification.
    pub fn spec(&self) -> String {
        self.path.display().to_string()
    }
}

/// Copies `manifest` (a repository manifest naming its mesh `../../shared/scenes/...`) with
/// the mesh's path pointed at [`shared_scenes`].
///
/// # Panics
/// When the shared scenes are missing, or the manifest cannot be read or names no shared scene.
pub fn shared_manifest(manifest: &Path) -> SharedManifest {
    let scenes = shared_scenes();
    let text = std::fs::read_to_string(manifest)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", manifest.display()));
    assert!(
        text.contains(MANIFEST_PREFIX),
        "{} names no mesh under {MANIFEST_PREFIX}",
        manifest.display()
    );
    let absolute = format!("\"{}/", scenes.display());
    let name = manifest.file_name().expect("a manifest file name");
    let dir = TempDir::new("manifest");
    let path = dir.join(name);
    std::fs::write(&path, text.replace(MANIFEST_PREFIX, &absolute))
        .unwrap_or_else(|e| panic!("cannot write {}: {e}", path.display()));
    SharedManifest { path, _dir: dir }
}

/// Whether `shared/scenes/relative` exists (for tests whose subject is the scene's absence).
pub fn has_shared_scene(relative: &str) -> bool {
    shared_dir().join("scenes").join(relative).exists()
}

fn missing_message(p: &Path) -> String {
    format!(
        "{} not found: this test needs the third-party scenes in shared/scenes beside the \
         checkout; set {SHARED_ENV} to the folder that holds scenes/ (e.g. {SHARED_ENV}=/work/shared)",
        p.display()
    )
}

/// A fresh, empty directory under the system's temporary one, removed with its contents when
/// dropped. The name joins a prefix, the test's name, the process id and a per-process counter,
/// so tests running in parallel (threads or processes) never share one.
#[derive(Debug)]
pub struct TempDir {
    path: PathBuf,
}

static COUNTER: AtomicU64 = AtomicU64::new(0);

impl TempDir {
    /// Creates `mlt-{name}-{process}-{counter}` under [`std::env::temp_dir`].
    ///
    /// # Panics
    /// When the directory cannot be created.
    pub fn new(name: &str) -> TempDir {
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let path = std::env::temp_dir().join(format!("mlt-{name}-{}-{n}", std::process::id()));
        let _ = std::fs::remove_dir_all(&path);
        if let Err(e) = std::fs::create_dir_all(&path) {
            panic!(
                "cannot create the temporary directory {}: {e}",
                path.display()
            );
        }
        TempDir { path }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Deref for TempDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.path
    }
}

impl AsRef<Path> for TempDir {
    fn as_ref(&self) -> &Path {
        &self.path
    }
}

impl AsRef<std::ffi::OsStr> for TempDir {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.path.as_os_str()
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.path);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temp_dirs_are_distinct_and_removed_on_drop() {
        let a = TempDir::new("support-a");
        let b = TempDir::new("support-a");
        assert_ne!(a.path(), b.path());
        assert!(a.is_dir() && b.is_dir());
        std::fs::write(a.join("f.txt"), b"x").unwrap();
        std::fs::create_dir(a.join("sub")).unwrap();
        let kept = a.path().to_path_buf();
        drop(a);
        assert!(!kept.exists());
        assert!(b.is_dir());
    }

    #[test]
    fn a_missing_scene_panics_naming_the_path_and_the_variable() {
        // Whether or not the shared folder is there, the scene is not.
        let r = std::panic::catch_unwind(|| shared_scene("no/such/scene-7f3a.obj"));
        let e = r.expect_err("a missing scene must panic");
        let msg = e.downcast_ref::<String>().expect("a formatted message");
        assert!(msg.contains("scene"), "{msg}");
        assert!(msg.contains(SHARED_ENV), "{msg}");
        assert!(!has_shared_scene("no/such/scene-7f3a.obj"));
        let msg = missing_message(Path::new("/x/scenes/a.obj"));
        assert!(
            msg.contains("/x/scenes/a.obj") && msg.contains(SHARED_ENV),
            "{msg}"
        );
    }

    #[test]
    fn the_workspace_dir_holds_the_workspace_manifest() {
        let m = std::fs::read_to_string(workspace_dir().join("Cargo.toml")).unwrap();
        assert!(m.contains("[workspace]"));
    }
}
