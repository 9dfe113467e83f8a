//! What the view crate's test files share. (Each test file compiles this module on its own and
//! uses part of it, hence the allowance.)
#![allow(dead_code, unused_imports)]

use std::path::Path;

use mlt_bake::{bake_scene, BakeOptions, Silent};
use mlt_format::WriteOptions;

/// Bakes the scene `spec` with `opts` into `path`.
pub fn bake_to(path: &Path, spec: &str, opts: BakeOptions) {
    let scene = mlt_scenes::load_scene(spec).unwrap();
    let out = bake_scene(&scene, &opts, &Silent).unwrap();
    mlt_format::file::write(path, &out.contents, WriteOptions::default()).unwrap();
}

pub use mlt_test_support::{shared_scenes, TempDir};

/// A fresh, empty directory for the test `name` of the test file `file`, removed on drop.
pub fn temp_dir(file: &str, name: &str) -> TempDir {
    TempDir::new(&format!("{file}-{name}"))
}
