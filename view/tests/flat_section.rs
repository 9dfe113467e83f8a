//! The `FLT2` section (format 1.6; `FLAT` in 1.5): a bake stores the flat basis that
//! `FlatBasis::build` gives for its basis and links; the viewer reads it instead of building
//! it, renders the same image from a file without it (format 1.4) or with a 1.5 section (by
//! an older rule), and refuses a damaged or inconsistent one with an error naming the file.

mod common;

use std::path::Path;
use std::process::Command;

use common::bake_to;
use mlt_bake::BakeOptions;
use mlt_format::container::VERSION_MINOR;
use mlt_format::flat_basis::FlatBasis;
use mlt_format::flat_section::{linked_flags, FlatRule, StoredFlat};
use mlt_format::{BakeContents, BakedFile, FormatError, WriteOptions};

fn small_opts() -> BakeOptions {
    BakeOptions {
        receiver_levels: Some(4),
        coarse_count: Some(40),
        gather_rays: Some(64),
        ..Default::default()
    }
}

/// The file's basis, contents and the link flags of its links.
fn open(path: &Path) -> (BakedFile, BakeContents, Vec<bool>) {
    let file = BakedFile::open(path).unwrap();
    let contents = file.contents().unwrap();
    let links = &contents.transport.as_ref().unwrap().links;
    let linked = linked_flags(
        contents.basis.basis.len(),
        links.receiver_ids.iter().copied(),
    );
    (file, contents, linked)
}

/// `contents` written as format `minor` (the header's version patched and re-hashed).
fn write_as(path: &Path, contents: &BakeContents, minor: u16) {
    let mut bytes = mlt_format::file::encode(contents, WriteOptions::default()).unwrap();
    bytes[10..12].copy_from_slice(&minor.to_le_bytes());
    assert!(mlt_format::container::reseal(&mut bytes));
    std::fs::write(path, bytes).unwrap();
}

/// `view render FILE` at 48x36; the output and the directory of its images.
fn render(file: &Path, out: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_view"))
        .arg("render")
        .arg(file)
        .arg("--out")
        .arg(out)
        .args(["--width", "48", "--height", "36"])
        .output()
        .unwrap()
}

#[test]
fn a_bake_stores_the_flat_basis_and_the_viewer_reads_it() {
    let d = common::temp_dir("flat_section", "stored");
    let f = d.join("cornell.mlt");
    bake_to(&f, "builtin:cornell", small_opts());
    let (file, contents, linked) = open(&f);
    assert_eq!(file.header().minor, VERSION_MINOR);
    let built = FlatBasis::build(&contents.basis, Some(&linked)).unwrap();
    assert!(!built.is_empty() && built.len() < contents.basis.basis.len());
    match file.flat_basis(&contents.basis, &linked).unwrap() {
        StoredFlat::Stored(stored) => assert_eq!(*stored, built),
        other => panic!("no stored flat basis: {other:?}"),
    }

    // The same file as format 1.4, without the section: the viewer builds the flat basis
    // and renders the same image.
    let old = d.join("old.mlt");
    let mut without = contents.clone();
    without.flat = None;
    write_as(&old, &without, 4);
    let (old_file, _, _) = open(&old);
    assert!(matches!(
        old_file.flat_basis(&contents.basis, &linked).unwrap(),
        StoredFlat::Absent
    ));
    let (a, b) = (d.join("a"), d.join("b"));
    for (file, out) in [(&f, &a), (&old, &b)] {
        let r = render(file, out);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    }
    let stored_flag = |dir: &Path| {
        let t = std::fs::read_to_string(dir.join("timings.json")).unwrap();
        let json: serde_json::Value = serde_json::from_str(&t).unwrap();
        json["load"]["flat_stored"].as_bool().unwrap()
    };
    assert!(stored_flag(&a));
    assert!(!stored_flag(&b));
    for image in ["final.exr", "indirect.exr"] {
        let (x, y) = (
            std::fs::read(a.join(image)).unwrap(),
            std::fs::read(b.join(image)).unwrap(),
        );
        assert!(x == y, "{image} differs with and without the FLAT section");
    }
}

/// `path`'s sections re-encoded with its `FLT2` section as format 1.5 wrote it (under `FLAT`,
/// the rule without `finer_cover`), as format 1.5.
fn write_as_1_5(path: &Path, out: &Path) {
    use mlt_format::container::{self, SectionIn};
    use mlt_format::flat_section::FlatSection1_5;
    let bytes = std::fs::read(path).unwrap();
    let header = container::parse_header(path, &bytes).unwrap();
    let sections: Vec<([u8; 4], Vec<u8>)> = header
        .sections
        .iter()
        .map(|e| {
            let b = container::section_bytes(path, &bytes, e).unwrap().to_vec();
            if &e.tag != b"FLT2" {
                return (e.tag, b);
            }
            let current = BakedFile::open(path)
                .unwrap()
                .flat_section()
                .unwrap()
                .unwrap();
            let old = FlatSection1_5::from_current(&current);
            (*b"FLAT", old.archive().unwrap())
        })
        .collect();
    let ins: Vec<SectionIn> = sections
        .iter()
        .map(|(tag, bytes)| SectionIn {
            tag: *tag,
            bytes,
            compress: false,
        })
        .collect();
    let mut bytes = container::encode(&ins, header.input_key).unwrap();
    bytes[10..12].copy_from_slice(&5u16.to_le_bytes());
    assert!(container::reseal(&mut bytes));
    std::fs::write(out, bytes).unwrap();
}

/// A format 1.5 file's `FLAT` section (which kept every needed point) is read for its rule
/// only: another rule than this build's, so the viewer builds the flat basis and renders the
/// image of the 1.6 file.
#[test]
fn a_format_1_5_flat_section_is_read_for_its_rule() {
    let d = common::temp_dir("flat_section", "format_1_5");
    let f = d.join("cornell.mlt");
    bake_to(&f, "builtin:cornell", small_opts());
    let old = d.join("old.mlt");
    write_as_1_5(&f, &old);
    let (old_file, contents, linked) = open(&old);
    assert_eq!(old_file.header().minor, 5);
    assert!(contents.flat.is_none());
    let current = FlatRule::current();
    match old_file.flat_basis(&contents.basis, &linked).unwrap() {
        StoredFlat::OtherRule(rule) => assert_eq!(
            rule,
            FlatRule {
                finer_cover: 0.0,
                ..current
            }
        ),
        other => panic!("expected the 1.5 rule, got {other:?}"),
    }
    let (a, b) = (d.join("a"), d.join("b"));
    for (file, out) in [(&f, &a), (&old, &b)] {
        let r = render(file, out);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    }
    for image in ["final.exr", "indirect.exr"] {
        let (x, y) = (
            std::fs::read(a.join(image)).unwrap(),
            std::fs::read(b.join(image)).unwrap(),
        );
        assert!(x == y, "{image} differs between the 1.6 and the 1.5 file");
    }
}

/// A flat section that does not belong to the file's basis and links, or that is malformed,
/// is an error naming the file and the section, from the library and from `view`.
#[test]
fn an_inconsistent_flat_section_is_an_error_naming_the_file() {
    let d = common::temp_dir("flat_section", "inconsistent");
    let f = d.join("cornell.mlt");
    bake_to(&f, "builtin:cornell", small_opts());
    let (_, contents, linked) = open(&f);
    let n = contents.basis.basis.len() as u32;
    let flat = contents.flat.clone().unwrap();
    type Damage = fn(&mut mlt_format::flat_section::FlatSection, u32);
    let damages: [(&str, Damage); 6] = [
        ("out of range", |s, n| s.source[0] = n + 3),
        ("repeated", |s, _| s.source[1] = s.source[0]),
        ("radius", |s, _| s.radii[2] = f32::NAN),
        ("radii", |s, _| {
            s.radii.pop();
        }),
        ("other linked receivers", |s, _| s.linked_key ^= 1),
        ("hierarchical points", |s, _| s.points += 1),
    ];
    for (what, damage) in damages {
        let mut c = contents.clone();
        let mut s = flat.clone();
        damage(&mut s, n);
        c.flat = Some(s);
        let p = d.join("bad.mlt");
        write_as(&p, &c, VERSION_MINOR);
        let file = BakedFile::open(&p).unwrap();
        let e = file
            .flat_basis(&contents.basis, &linked)
            .expect_err(what)
            .to_string();
        assert!(
            e.contains("bad.mlt") && e.contains("FLT2") && e.contains(what),
            "{what}: {e}"
        );
    }
    // A tree that does not bound its points.
    let mut c = contents.clone();
    let mut s = flat.clone();
    s.tree.node_first[0] = 1_000_000;
    c.flat = Some(s);
    let p = d.join("tree.mlt");
    write_as(&p, &c, VERSION_MINOR);
    let e = BakedFile::open(&p)
        .unwrap()
        .flat_basis(&contents.basis, &linked)
        .expect_err("forged tree");
    assert!(matches!(e, FormatError::BadSection { .. }), "{e}");
    assert!(e.to_string().contains("tree.mlt"), "{e}");

    // The section's bytes damaged and the checksums recomputed: rkyv's validation or the
    // checks refuse it; never a panic. From `view`, the error names the file.
    let mut bytes = std::fs::read(&f).unwrap();
    let header = mlt_format::container::parse_header(&f, &bytes).unwrap();
    let entry = header.sections.iter().find(|e| &e.tag == b"FLT2").unwrap();
    // The root object ends the section: point its `source` array far out of the section.
    use mlt_format::flat_section::ArchivedFlatSection;
    let root = entry.offset as usize + entry.stored_len as usize
        - std::mem::size_of::<ArchivedFlatSection>();
    let at = root + std::mem::offset_of!(ArchivedFlatSection, source);
    bytes[at..at + 4].copy_from_slice(&0x7fff_fff0u32.to_le_bytes());
    assert!(mlt_format::container::reseal(&mut bytes));
    let p = d.join("damaged.mlt");
    std::fs::write(&p, bytes).unwrap();
    let e = BakedFile::open(&p)
        .unwrap()
        .flat_basis(&contents.basis, &linked)
        .expect_err("damaged section");
    assert!(e.to_string().contains("damaged.mlt"), "{e}");
    let r = Command::new(env!("CARGO_BIN_EXE_view"))
        .arg("timings")
        .arg(&p)
        .args(["--frames", "1"])
        .output()
        .unwrap();
    assert!(!r.status.success());
    let stderr = String::from_utf8_lossy(&r.stderr);
    assert!(
        stderr.contains("damaged.mlt") && stderr.contains("FLT2"),
        "{stderr}"
    );
}
