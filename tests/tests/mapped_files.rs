//! A memory-mapped baked file stays readable when another process replaces it by renaming a
//! new file over it (as every writer here does): the mapping keeps the old inode, so the open
//! file still reads its old contents, and a fresh open reads the new ones.

use std::path::Path;

use mlt_bake::{bake_scene, BakeOptions, Silent};
use mlt_format::{BakedFile, WriteOptions};

fn basis_bytes(levels: u32, coarse: u32) -> mlt_format::BakeContents {
    let scene = mlt_scenes::load_scene("builtin:cornell").unwrap();
    let opts = BakeOptions {
        receiver_levels: Some(levels),
        coarse_count: Some(coarse),
        basis_only: true,
        ..Default::default()
    };
    bake_scene(&scene, &opts, &Silent).unwrap().contents
}

fn positions(f: &BakedFile) -> Vec<[f32; 3]> {
    f.basis().unwrap().basis.positions
}

#[test]
fn an_open_file_replaced_by_rename_keeps_its_old_contents() {
    let d = mlt_test_support::TempDir::new("mapped");
    let path = d.join("scene.mlt");
    let (old, new) = (basis_bytes(2, 12), basis_bytes(3, 20));
    let opts = WriteOptions { compress: false };
    mlt_format::file::write(&path, &old, opts).unwrap();
    let open = BakedFile::open(&path).unwrap();
    let before = positions(&open);

    // Another writer: a temporary file renamed over the mapped one.
    let tmp = d.join(".scene.mlt.tmp");
    mlt_format::file::write(Path::new(&tmp), &new, opts).unwrap();
    std::fs::rename(&tmp, &path).unwrap();

    assert_eq!(positions(&open), before);
    assert_eq!(open.meta().unwrap().stats.levels.len(), 2);
    let reopened = BakedFile::open(&path).unwrap();
    assert_eq!(reopened.meta().unwrap().stats.levels.len(), 3);
    assert_ne!(positions(&reopened), before);
}
