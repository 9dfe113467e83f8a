//! Fuzzing of everything that reads user files: the baked-file reader, the OBJ+MTL loader,
//! the glTF loader and the manifest parser. A seeded mutator (bit flips, interesting bytes,
//! deleted, duplicated and spliced ranges, tokens of the format, huge and non-finite numbers)
//! turns small real inputs into malformed ones; every input must be refused or accepted
//! without a panic, within [`TIME_LIMIT`], allocating at most [`ALLOC_CAP`] above what was
//! allocated before it (a counting global allocator).
//!
//! `MLT_FUZZ_COUNT` sets the inputs per target (default [`DEFAULT_COUNT`]) and `MLT_FUZZ_SEED`
//! the seed; `scripts/fuzz.sh` runs many more. Failing inputs are written to
//! `$MLT_FUZZ_OUT` (default the system temp directory) for replay.

use std::alloc::{GlobalAlloc, Layout, System};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use mlt_bake::rng::{Rng, Stream};
use mlt_bake::{bake_scene, BakeOptions, Silent};
use mlt_format::{BakedFile, WriteOptions};

/// Inputs per target in a plain `cargo test`.
const DEFAULT_COUNT: usize = 1500;
/// Longest any one small input may take (debug build, shared machine).
const TIME_LIMIT: Duration = Duration::from_secs(2);
/// Most bytes one input below 64 KiB may allocate beyond what was live before it.
const ALLOC_CAP: usize = 64 << 20;

/// The system allocator, counting live bytes and their peak.
struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

// SAFETY: every call forwards to `System` with the caller's layout unchanged; the counters
// are plain atomics and allocate nothing.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = System.alloc(layout);
        if !p.is_null() {
            let now = LIVE.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout);
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = System.realloc(ptr, layout, new_size);
        if !p.is_null() {
            if new_size >= layout.size() {
                let now = LIVE.fetch_add(new_size - layout.size(), Ordering::Relaxed)
                    + (new_size - layout.size());
                PEAK.fetch_max(now, Ordering::Relaxed);
            } else {
                LIVE.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
            }
        }
        p
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// The targets run one at a time, so that the allocation peak is one input's.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn count() -> usize {
    std::env::var("MLT_FUZZ_COUNT")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(DEFAULT_COUNT)
}

fn seed() -> u64 {
    std::env::var("MLT_FUZZ_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1)
}

/// A fresh directory, removed with its contents when dropped.
fn temp(name: &str) -> mlt_test_support::TempDir {
    mlt_test_support::TempDir::new(&format!("fuzz-{name}"))
}

/// Byte strings the mutator inserts or overwrites with.
const NUMBERS: &[&str] = &[
    "0",
    "-1",
    "1e999",
    "-1e999",
    "nan",
    "inf",
    "4294967295",
    "18446744073709551616",
    "2147483648",
    "-2147483649",
    "1e-45",
    "0.0",
    "99999999999",
    "3",
];

/// A seeded mutator of byte strings.
struct Mutator<'a> {
    rng: Rng,
    seeds: &'a [Vec<u8>],
    tokens: &'a [&'a str],
}

impl Mutator<'_> {
    fn pick(&mut self, n: usize) -> usize {
        self.rng.below(n.max(1) as u64) as usize
    }

    /// A mutant of a random seed: one to three mutations, or (rarely) random bytes.
    fn next(&mut self) -> Vec<u8> {
        if self.pick(50) == 0 {
            let n = self.pick(256);
            return (0..n).map(|_| self.rng.next_u64() as u8).collect();
        }
        let mut v = self.seeds[self.pick(self.seeds.len())].clone();
        for _ in 0..1 + self.pick(3) {
            self.mutate(&mut v);
        }
        v
    }

    fn mutate(&mut self, v: &mut Vec<u8>) {
        let len = v.len();
        let at = self.pick(len + 1);
        match self.pick(9) {
            0 if len > 0 => v[at.min(len - 1)] ^= 1 << self.pick(8),
            1 if len > 0 => {
                v[at.min(len - 1)] = [0u8, 0xff, 0x7f, 0x80, b'\n', b' ', b'/'][self.pick(7)]
            }
            2 => {
                let end = (at + 1 + self.pick(64)).min(len);
                v.drain(at.min(end)..end);
            }
            3 => {
                let end = (at + 1 + self.pick(256)).min(len);
                let piece = v[at.min(end)..end].to_vec();
                let to = self.pick(len + 1);
                v.splice(
                    to..to,
                    piece
                        .iter()
                        .copied()
                        .cycle()
                        .take(piece.len() * (1 + self.pick(4))),
                );
            }
            4 => {
                let other = &self.seeds[self.pick(self.seeds.len())];
                let from = self.pick(other.len());
                let end = (from + 1 + self.pick(512)).min(other.len());
                let piece = other[from..end].to_vec();
                v.splice(at..at, piece);
            }
            5 => {
                let n = NUMBERS[self.pick(NUMBERS.len())].as_bytes().to_vec();
                let end = v[at..]
                    .iter()
                    .position(|c| !(c.is_ascii_digit() || b".-+e".contains(c)))
                    .map_or(len, |p| at + p);
                v.splice(at..end, n);
            }
            6 if !self.tokens.is_empty() => {
                let t = self.tokens[self.pick(self.tokens.len())]
                    .as_bytes()
                    .to_vec();
                v.splice(at..at, t);
            }
            7 => v.truncate(at),
            _ if len >= 8 => {
                // An aligned little-endian integer overwritten with an extreme value.
                let at = (at.min(len - 8)) & !7;
                let x = [0u64, u64::MAX, 1 << 31, 1 << 40, u32::MAX as u64][self.pick(5)];
                v[at..at + 8].copy_from_slice(&x.to_le_bytes());
            }
            _ => v.push(self.rng.next_u64() as u8),
        }
    }
}

/// What one target's run found.
struct Report {
    tried: usize,
    accepted: usize,
    failures: Vec<String>,
    slowest: Duration,
    most_bytes: usize,
}

/// Feeds `n` mutants of `seeds` to `run` (which says whether it accepted the input),
/// checking each for panics, time and allocation.
fn fuzz(
    target: &str,
    seeds: &[Vec<u8>],
    tokens: &[&str],
    n: usize,
    run: impl Fn(&[u8]) -> bool,
) -> Report {
    let mut m = Mutator {
        rng: Rng::new(seed(), Stream::Shuffle, 0xf022 ^ target.len() as u64),
        seeds,
        tokens,
    };
    let out = std::env::var_os("MLT_FUZZ_OUT")
        .map(PathBuf::from)
        .unwrap_or_else(std::env::temp_dir);
    let mut report = Report {
        tried: 0,
        accepted: 0,
        failures: Vec::new(),
        slowest: Duration::ZERO,
        most_bytes: 0,
    };
    for i in 0..n {
        let input = if i < seeds.len() {
            seeds[i].clone()
        } else {
            m.next()
        };
        let before = LIVE.load(Ordering::Relaxed);
        PEAK.store(before, Ordering::Relaxed);
        let start = Instant::now();
        let result = catch_unwind(AssertUnwindSafe(|| run(&input)));
        let took = start.elapsed();
        let bytes = PEAK.load(Ordering::Relaxed).saturating_sub(before);
        report.tried += 1;
        report.accepted += matches!(result, Ok(true)) as usize;
        report.slowest = report.slowest.max(took);
        report.most_bytes = report.most_bytes.max(bytes);
        let problem = if result.is_err() {
            Some("panicked".to_string())
        } else if took > TIME_LIMIT {
            Some(format!("took {took:?}"))
        } else if input.len() < 64 << 10 && bytes > ALLOC_CAP {
            Some(format!("allocated {bytes} bytes"))
        } else {
            None
        };
        if let Some(p) = problem {
            let file = out.join(format!("mlt-fuzz-{target}-{}-{i}.bin", seed()));
            let _ = std::fs::write(&file, &input);
            report.failures.push(format!(
                "{target} input {i}: {p} (saved to {})",
                file.display()
            ));
        }
    }
    eprintln!(
        "fuzz {target}: {} inputs ({} accepted), {} failures, slowest {:.1} ms, most allocated {:.2} MB",
        report.tried,
        report.accepted,
        report.failures.len(),
        report.slowest.as_secs_f64() * 1e3,
        report.most_bytes as f64 / 1e6
    );
    report
}

fn assert_clean(r: Report) {
    assert!(r.tried > 0);
    assert!(r.failures.is_empty(), "{}", r.failures.join("\n"));
}

/// Rewrites the container's file length and both checksums, so that mutants reach the
/// section parsers instead of stopping at the checksum.
fn fix_checksums(v: &mut [u8]) {
    if v.len() < 64 {
        return;
    }
    let len = v.len() as u64;
    v[24..32].copy_from_slice(&len.to_le_bytes());
    mlt_format::container::reseal(v);
}

/// Small bakes of built-in scenes, as files: basis only, with transport, compressed.
fn baked_seeds() -> Vec<Vec<u8>> {
    let scene = mlt_scenes::load_scene("builtin:cornell").unwrap();
    let mut seeds = Vec::new();
    for basis_only in [true, false] {
        let opts = BakeOptions {
            receiver_levels: Some(2),
            coarse_count: Some(12),
            gather_rays: Some(16),
            sender_levels: Some(1),
            bounces: Some(2),
            basis_only,
            ..Default::default()
        };
        let out = bake_scene(&scene, &opts, &Silent).unwrap();
        for compress in [false, true] {
            seeds.push(mlt_format::file::encode(&out.contents, WriteOptions { compress }).unwrap());
        }
    }
    seeds
}

/// Reads everything a viewer or `bake info` reads; accepted when all of it reads.
fn read_baked(bytes: &[u8]) -> bool {
    let Ok(f) = BakedFile::from_bytes(Path::new("fuzz.mlt"), bytes) else {
        return false;
    };
    let ok = [
        f.meta().is_ok(),
        f.basis().is_ok(),
        f.transport_meta().is_ok(),
        f.transport_report().is_ok(),
        f.shard().is_ok(),
        f.info().is_ok(),
    ];
    f.contents().is_ok() && ok.iter().all(|&o| o)
}

#[test]
fn baked_file_reader_survives_mutated_files() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let seeds = baked_seeds();
    let n = count();
    // Half the mutants keep valid checksums, to reach the sections' validation.
    let r = fuzz("baked", &seeds, &[], n / 2, read_baked);
    assert_clean(r);
    let r = fuzz("baked-checksummed", &seeds, &[], n - n / 2, |b| {
        let mut v = b.to_vec();
        fix_checksums(&mut v);
        read_baked(&v)
    });
    assert_clean(r);
}

const OBJ: &str = "mtllib m.mtl\n# a box corner\nv 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\nv 0 1 0\n\
v 1 1 0\nvn 0 1 0\nvn 0 0 1\nvt 0 0\nvt 1 0\nvt 1 1\ng floor\nusemtl white\n\
f 1/1/1 4/2/1 3/3/1 2/1/1\ng wall\nusemtl red\nf 1//2 2//2 6//2 5//2\no extra\nf -1 -2 -3\n";

const MTL: &str = "newmtl white\nKd 0.7 0.7 0.7\nnewmtl red\nKd 0.8 0.1 0.1\nKe 1 1 1\n\
map_Kd missing.png\nnewmtl other\nKd 0.2 0.3 0.4\n";

#[test]
fn obj_and_mtl_loader_survives_mutated_files() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let d = temp("obj");
    let (obj, mtl) = (d.join("s.obj"), d.join("m.mtl"));
    let tokens = [
        "v ",
        "vn ",
        "vt ",
        "f ",
        "f 1 2 3\n",
        "/",
        "//",
        "usemtl ",
        "mtllib m.mtl\n",
        "g ",
        "o ",
        "\n",
        "newmtl ",
        "Kd ",
        "map_Kd ",
        "-0",
        "\\\n",
        "#",
    ];
    let n = count();
    // The OBJ mutated with the MTL intact, then the MTL mutated with the OBJ intact.
    std::fs::write(&mtl, MTL).unwrap();
    let r = fuzz("obj", &[OBJ.as_bytes().to_vec()], &tokens, n / 2, |b| {
        std::fs::write(&obj, b).unwrap();
        mlt_scenes::obj::load_obj(&obj, 1.0).is_ok()
    });
    assert_clean(r);
    std::fs::write(&obj, OBJ).unwrap();
    let r = fuzz("mtl", &[MTL.as_bytes().to_vec()], &tokens, n - n / 2, |b| {
        std::fs::write(&mtl, b).unwrap();
        mlt_scenes::obj::load_obj(&obj, 1.0).is_ok()
    });
    assert_clean(r);
}

/// One textured quad: positions, normals, UVs, u16 indices, and a 2x2 RGBA8 image... kept
/// as a raw buffer (no image), so that the loader's accessor checks are what is fuzzed.
fn gltf_buffer() -> Vec<u8> {
    let mut buf = Vec::new();
    for p in [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 0.0, 1.0],
        [0.0, 0.0, 1.0],
    ] {
        for c in p {
            buf.extend_from_slice(&c.to_le_bytes());
        }
    }
    for _ in 0..4 {
        for c in [0.0f32, 1.0, 0.0] {
            buf.extend_from_slice(&c.to_le_bytes());
        }
    }
    for i in [0u16, 1, 2, 0, 2, 3] {
        buf.extend_from_slice(&i.to_le_bytes());
    }
    buf
}

fn gltf_json(buffer: &str) -> String {
    format!(
        r#"{{"asset": {{"version": "2.0"}}, "scene": 0, "scenes": [{{"nodes": [0]}}],
"nodes": [{{"translation": [0, 1, 0], "scale": [2, 2, 2], "mesh": 0, "children": [1]}}, {{"rotation": [0, 0, 0, 1], "mesh": 0}}],
"materials": [{{"name": "m", "pbrMetallicRoughness": {{"baseColorFactor": [0.8, 0.1, 0.1, 1]}}}}],
"meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0, "NORMAL": 1}}, "indices": 2, "material": 0}}]}}],
"buffers": [{{{buffer}}}],
"bufferViews": [{{"buffer": 0, "byteOffset": 0, "byteLength": 48}}, {{"buffer": 0, "byteOffset": 48, "byteLength": 48}}, {{"buffer": 0, "byteOffset": 96, "byteLength": 12}}],
"accessors": [{{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0,0,0], "max": [1,0,1]}}, {{"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"}}, {{"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}}]}}"#
    )
}

/// The quad as a binary .glb: a JSON chunk and a BIN chunk.
fn glb() -> Vec<u8> {
    let mut bin = gltf_buffer();
    let mut json = gltf_json(&format!(r#""byteLength": {}"#, bin.len())).into_bytes();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut v = Vec::with_capacity(total);
    v.extend_from_slice(b"glTF");
    v.extend_from_slice(&2u32.to_le_bytes());
    v.extend_from_slice(&(total as u32).to_le_bytes());
    v.extend_from_slice(&(json.len() as u32).to_le_bytes());
    v.extend_from_slice(&0x4E4F_534Au32.to_le_bytes());
    v.extend_from_slice(&json);
    v.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    v.extend_from_slice(&0x004E_4942u32.to_le_bytes());
    v.extend_from_slice(&bin);
    v
}

#[test]
fn gltf_loader_survives_mutated_files() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let d = temp("gltf");
    let buf = gltf_buffer();
    std::fs::write(d.join("quad.bin"), &buf).unwrap();
    let text = gltf_json(&format!(
        r#""byteLength": {}, "uri": "quad.bin""#,
        buf.len()
    ));
    let tokens = [
        "{",
        "}",
        "[",
        "]",
        ",",
        "\"count\": 4000000000",
        "\"byteOffset\": 4294967295",
        "\"mode\": 0",
        "\"children\": [0]",
        "\"indices\": 1",
        "\"uri\": \"../../x\"",
    ];
    let n = count();
    let (gltf, glb_path) = (d.join("s.gltf"), d.join("s.glb"));
    let r = fuzz("gltf", &[text.into_bytes()], &tokens, n / 2, |b| {
        std::fs::write(&gltf, b).unwrap();
        mlt_scenes::gltf_scene::load_gltf(&gltf, 1.0).is_ok()
    });
    assert_clean(r);
    let r = fuzz("glb", &[glb()], &tokens, n - n / 2, |b| {
        std::fs::write(&glb_path, b).unwrap();
        mlt_scenes::gltf_scene::load_gltf(&glb_path, 1.0).is_ok()
    });
    assert_clean(r);
}

const MANIFEST: &str = r#"# a small scene
[scene]
source = "s.obj"
scale = 2.0
viewpoint = [0.5, 0.5, 0.5]

[camera]
position = [0.5, 0.5, 3.0]
target = [0.5, 0.5, 0.0]
fovy_deg = 60.0
width = 64
height = 48

[light]
kind = "point"
position = [0.5, 0.9, 0.5]
intensity = [1.0, 1.0, 1.0]

[bake]
receiver_levels = 3
coarse_count = 20
seed = 7
"#;

#[test]
fn manifest_parser_survives_mutated_files() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let d = temp("manifest");
    std::fs::write(d.join("s.obj"), OBJ).unwrap();
    std::fs::write(d.join("m.mtl"), MTL).unwrap();
    let path = d.join("s.toml");
    let tokens = [
        "[scene]\n",
        "[bake]\n",
        "[light]\n",
        "kind = \"spot\"\n",
        "=",
        "\"",
        "[",
        "]",
        "\n",
        "source = \"builtin:sphere\"\n",
        "source = \"s.toml\"\n",
        "scale = 0\n",
        "receiver_levels = 99\n",
        "falloff = \"x\"\n",
    ];
    let r = fuzz(
        "manifest",
        &[MANIFEST.as_bytes().to_vec()],
        &tokens,
        count(),
        |b| {
            std::fs::write(&path, b).unwrap();
            mlt_scenes::manifest::load_manifest(&path).is_ok()
        },
    );
    assert_clean(r);
}
