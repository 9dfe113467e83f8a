//! Ray-casting throughput of [`MeshCaster`] on a mesh file.
//!
//! ```text
//! cargo run --release -p mlt-scenes --example raycast_bench -- PATH.obj [--scale S] [--viewpoint x,y,z] [--rays N]
//! ```
//! Prints the machine (CPU model, logical cores), the triangle count, the BVH build time, and
//! rays per second for closest-hit and occlusion queries, single-threaded and with rayon on
//! every thread. Rays start at the viewpoint (default: the centre of the bounds) in uniformly
//! random directions from a fixed seed; occlusion rays go to the closest-hit point of the
//! same direction (or a point at the scene's extent for misses), shortened by 1 %.

use std::path::PathBuf;
use std::time::Instant;

use glam::Vec3;
use mlt_scenes::{scene_from_mesh_file, Geometry, MeshCaster, RayCaster};
use rayon::prelude::*;

struct Args {
    path: PathBuf,
    scale: f32,
    viewpoint: Option<Vec3>,
    rays: usize,
}

fn usage() -> ! {
    eprintln!(
        "usage: raycast_bench PATH.(obj|gltf|glb) [--scale S] [--viewpoint x,y,z] [--rays N]"
    );
    std::process::exit(2)
}

fn parse_args() -> Args {
    let mut it = std::env::args().skip(1);
    let mut path = None;
    let mut scale = 1.0;
    let mut viewpoint = None;
    let mut rays = 1_000_000;
    while let Some(a) = it.next() {
        match a.as_str() {
            "--scale" => {
                scale = it
                    .next()
                    .and_then(|s| s.parse().ok())
                    .unwrap_or_else(|| usage())
            }
            "--viewpoint" => {
                let v: Vec<f32> = it
                    .next()
                    .unwrap_or_else(|| usage())
                    .split(',')
                    .map(|s| s.trim().parse().unwrap_or_else(|_| usage()))
                    .collect();
                if v.len() != 3 {
                    usage();
                }
                viewpoint = Some(Vec3::new(v[0], v[1], v[2]));
            }
            "--rays" => {
                rays = it
                    .next()
                    .and_then(|s| s.parse().ok())
                    .unwrap_or_else(|| usage())
            }
            "-h" | "--help" => usage(),
            _ if path.is_none() => path = Some(PathBuf::from(a)),
            _ => usage(),
        }
    }
    Args {
        path: path.unwrap_or_else(|| usage()),
        scale,
        viewpoint,
        rays,
    }
}

/// splitmix64: a tiny, good-enough generator for benchmark directions.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform on the unit sphere.
    fn direction(&mut self) -> Vec3 {
        let z = 2.0 * self.next_f32() - 1.0;
        let phi = std::f32::consts::TAU * self.next_f32();
        let r = (1.0 - z * z).max(0.0).sqrt();
        Vec3::new(r * phi.cos(), r * phi.sin(), z)
    }
}

fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, v)| v.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".to_string())
}

fn rate(n: usize, secs: f64) -> String {
    format!("{:>8.2} Mrays/s", n as f64 / secs.max(1e-9) / 1e6)
}

fn main() {
    let args = parse_args();
    let threads = rayon::current_num_threads();
    println!(
        "machine: {} ({} logical cores, rayon threads {threads})",
        cpu_model(),
        std::thread::available_parallelism().map_or(0, |n| n.get())
    );
    let t0 = Instant::now();
    let scene = match scene_from_mesh_file(&args.path, args.scale) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    };
    let load = t0.elapsed();
    let Geometry::Mesh(mesh) = scene.geometry else {
        eprintln!("error: not a mesh");
        std::process::exit(1);
    };
    println!(
        "scene: {} ({} triangles, {} zero-area dropped), loaded in {:.2?}",
        args.path.display(),
        mesh.triangles.len(),
        mesh.degenerate_dropped,
        load
    );
    let caster = MeshCaster::new(mesh);
    println!("BVH build: {:.2?}", caster.build_time());
    let (lo, hi) = caster.bounds();
    let origin = args.viewpoint.unwrap_or((lo + hi) * 0.5);
    let extent = (hi - lo).length();
    println!("viewpoint: {origin}");

    let mut rng = SplitMix64(0x5EED);
    let dirs: Vec<Vec3> = (0..args.rays).map(|_| rng.direction()).collect();

    // Closest hit, one thread.
    let t = Instant::now();
    let hits: Vec<Option<f32>> = dirs
        .iter()
        .map(|d| {
            caster
                .intersect(origin, *d, 0.0, f32::INFINITY)
                .map(|h| h.t)
        })
        .collect();
    let single_closest = t.elapsed().as_secs_f64();
    let hit_count = hits.iter().filter(|h| h.is_some()).count();

    // Closest hit, all threads.
    let t = Instant::now();
    let par_hits = dirs
        .par_iter()
        .filter(|d| caster.intersect(origin, **d, 0.0, f32::INFINITY).is_some())
        .count();
    let multi_closest = t.elapsed().as_secs_f64();
    assert_eq!(par_hits, hit_count, "parallel and serial results differ");

    // Occlusion rays towards the hit points (unoccluded by construction up to the
    // epsilon) or towards far points for misses: a worst case for any-hit.
    let ends: Vec<Vec3> = dirs
        .iter()
        .zip(&hits)
        .map(|(d, h)| origin + *d * h.map_or(extent, |t| 0.99 * t))
        .collect();
    let t = Instant::now();
    let occluded = ends.iter().filter(|e| caster.occluded(origin, **e)).count();
    let single_occ = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let par_occluded = ends
        .par_iter()
        .filter(|e| caster.occluded(origin, **e))
        .count();
    let multi_occ = t.elapsed().as_secs_f64();
    assert_eq!(par_occluded, occluded, "parallel and serial results differ");

    let n = dirs.len();
    println!("rays: {n} ({hit_count} hit, {occluded} shadow rays occluded)");
    println!(
        "closest hit: 1 thread {}   {threads} threads {}",
        rate(n, single_closest),
        rate(n, multi_closest)
    );
    println!(
        "occlusion:   1 thread {}   {threads} threads {}",
        rate(n, single_occ),
        rate(n, multi_occ)
    );
}
