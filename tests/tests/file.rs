//! Baked files: round trips, and clear errors for truncated, corrupted and wrong-version files.

use mlt_format::{BakedFile, FormatError, WriteOptions};
use mlt_tests::{bake_small, TempDir};

#[test]
fn round_trip_through_disk_with_and_without_compression() {
    let out = bake_small("builtin:cornell", 2, 20, 2);
    let dir = TempDir::new("roundtrip");
    for compress in [false, true] {
        let path = dir.join(format!("c{compress}.mlt"));
        let size =
            mlt_format::file::write(&path, &out.contents, WriteOptions { compress }).unwrap();
        assert_eq!(std::fs::metadata(&path).unwrap().len(), size);
        let f = BakedFile::open(&path).unwrap();
        let back = f.contents().unwrap();
        assert_eq!(back, out.contents);
        let info = f.info().unwrap();
        assert_eq!(info.points, out.contents.basis.basis.len() as u64);
        assert_eq!(info.levels.len(), 2);
        assert!(info.sections.iter().all(|s| s.compressed == compress));
        // The box's blocks clip the floor's supports: the planes travel with the basis
        // (compared above).
        assert!(!out.contents.basis.clip.is_empty());
        assert!(info.sections.iter().any(|s| s.tag == "CLIP"));
        // No temporary file is left behind.
        let leftovers: Vec<_> = std::fs::read_dir(&*dir)
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().contains(".tmp"))
            .collect();
        assert!(leftovers.is_empty());
    }
}

#[test]
fn damaged_files_are_rejected_with_a_message_naming_them() {
    let out = bake_small("builtin:cornell", 2, 20, 2);
    let bytes = mlt_format::file::encode(&out.contents, WriteOptions::default()).unwrap();
    let p = std::path::Path::new("damaged.mlt");
    // Truncated anywhere: header, table, payload.
    for len in [0, 5, 40, 64, 100, bytes.len() / 2, bytes.len() - 1] {
        let e = BakedFile::from_bytes(p, &bytes[..len])
            .err()
            .expect("truncated file accepted");
        assert!(e.to_string().contains("damaged.mlt"), "{e}");
    }
    // A flipped bit in the payload: checksum.
    let mut bad = bytes.clone();
    let mid = bad.len() / 2;
    bad[mid] ^= 1;
    let e = BakedFile::from_bytes(p, &bad)
        .err()
        .expect("corrupted file accepted");
    assert!(matches!(e, FormatError::Checksum { .. }), "{e}");
    // A future major version.
    let mut v2 = bytes.clone();
    v2[8..10].copy_from_slice(&2u16.to_le_bytes());
    let e = BakedFile::from_bytes(p, &v2)
        .err()
        .expect("wrong version accepted");
    assert!(
        matches!(e, FormatError::WrongVersion { major: 2, .. }),
        "{e}"
    );
    assert!(e.to_string().contains("format version 2."), "{e}");
    // Not our file at all.
    let e = BakedFile::from_bytes(p, b"solid cube\nfacet normal 0 0 1\n")
        .err()
        .unwrap();
    assert!(matches!(e, FormatError::BadMagic { .. }), "{e}");
}

#[test]
fn a_file_with_consistent_checksums_but_forged_contents_is_rejected() {
    // Rewrite a section's bytes and recompute the checksums, as a buggy writer might: the
    // rkyv validation or the basis validation must catch it, never a panic.
    let out = bake_small("builtin:cornell", 2, 20, 2);
    let bytes = mlt_format::file::encode(&out.contents, WriteOptions::default()).unwrap();
    let f = BakedFile::from_bytes(std::path::Path::new("x.mlt"), &bytes).unwrap();
    let sections = f.header().sections.clone();
    for s in &sections {
        for frac in [0.0, 0.3, 0.6, 0.95] {
            let mut forged = bytes.clone();
            let at = s.offset as usize
                + ((s.stored_len as f64 * frac) as usize).min(s.stored_len as usize - 1);
            forged[at] = forged[at].wrapping_add(0x55);
            assert!(mlt_format::container::reseal(&mut forged));
            let f = BakedFile::from_bytes(std::path::Path::new("forged.mlt"), &forged).unwrap();
            // Either it still reads as a valid file (the byte was padding or a value that is
            // still valid) or it gives an error; it must not panic.
            if let Err(e) = f.contents() {
                assert!(e.to_string().contains("forged.mlt"), "{e}");
            }
        }
    }
    // Forge an out-of-bounds R-tree node index specifically.
    let mut c = out.contents.clone();
    c.basis.trees[0].node_first[0] = 1_000_000;
    c.basis.trees[0].node_count[0] = 0;
    let forged = mlt_format::file::encode(&c, WriteOptions::default()).unwrap();
    let f = BakedFile::from_bytes(std::path::Path::new("tree.mlt"), &forged).unwrap();
    let e = f.basis().expect_err("forged tree accepted");
    assert!(e.to_string().contains("R-tree"), "{e}");
}

/// The version rule: the sections of a baked file read from any minor version of the major
/// version; a shard's `TSHD` only from the minor versions with the layout this build reads,
/// and any other is refused naming both versions.
#[test]
fn shard_sections_are_read_only_from_the_minor_versions_with_their_layout() {
    use mlt_format::container::{SHARD_LAYOUT_MINOR, VERSION_MAJOR, VERSION_MINOR};
    use mlt_format::file::{readable_minors, TAG_BASIS, TAG_META, TAG_SHARD};
    let out = mlt_tests::bake_with(
        "builtin:cornell",
        mlt_bake::BakeOptions {
            receiver_levels: Some(2),
            coarse_count: Some(20),
            gather_rays: Some(16),
            shard: Some((0, 2)),
            ..Default::default()
        },
        1,
    );
    assert!(out.contents.shard.is_some());
    let bytes = mlt_format::file::encode(&out.contents, WriteOptions::default()).unwrap();
    let with_minor = |minor: u16| {
        let mut b = bytes.clone();
        b[10..12].copy_from_slice(&minor.to_le_bytes());
        assert!(mlt_format::container::reseal(&mut b));
        b
    };
    let path = std::path::Path::new("shard.mlt");
    for minor in [SHARD_LAYOUT_MINOR, VERSION_MINOR] {
        let b = with_minor(minor);
        let f = BakedFile::from_bytes(path, &b).unwrap();
        assert_eq!(f.shard().unwrap(), out.contents.shard, "minor {minor}");
    }
    for minor in [SHARD_LAYOUT_MINOR - 1, VERSION_MINOR + 1] {
        let b = with_minor(minor);
        let f = BakedFile::from_bytes(path, &b).unwrap();
        let e = f.shard().expect_err("a shard of another layout was read");
        let msg = e.to_string();
        assert!(matches!(e, FormatError::BadSection { .. }), "{msg}");
        assert!(
            msg.contains("TSHD")
                && msg.contains(&format!("{VERSION_MAJOR}.{minor}"))
                && msg.contains(&format!("{VERSION_MAJOR}.{SHARD_LAYOUT_MINOR}")),
            "{msg}"
        );
        // The baked file's sections read whatever the minor version.
        assert_eq!(f.meta().unwrap(), out.contents.meta);
        assert_eq!(f.basis().unwrap(), out.contents.basis);
    }
    assert!(readable_minors(TAG_META).contains(&u16::MAX));
    assert!(readable_minors(TAG_BASIS).contains(&0));
    assert!(!readable_minors(TAG_SHARD).contains(&(VERSION_MINOR + 1)));
}
