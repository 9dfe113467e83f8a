//! What the view crate's test files share. (Each test file compiles this module on its own and
//! uses part of it, hence the allowance.)
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use mlt_bake::{bake_scene, BakeOptions, Silent};
use mlt_format::WriteOptions;

/// Bakes the scene `spec` with `opts` into `path`.
pub fn bake_to(path: &Path, spec: &str, opts: BakeOptions) {
    let scene = mlt_scenes::load_scene(spec).unwrap();
    let out = bake_scene(&scene, &opts, &Silent).unwrap();
    mlt_format::file::write(path, &out.contents, WriteOptions::default()).unwrap();
}

/// A fresh, empty directory `mlt-{file}-{name}-{process}` under the system's temporary one.
pub fn temp_dir(file: &str, name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mlt-{file}-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}
