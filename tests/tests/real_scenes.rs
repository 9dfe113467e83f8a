//! Bakes of the real third-party scenes (see `mlt-test-support`) through their manifests (few
//! levels, so that the test stays quick; the full-size runs are benchmarks).

use mlt_format::kernel::poisson_distance;
use mlt_tests::{bake_small, shared_manifest as manifest};

fn check_basis(name: &str, levels: u32, coarse: u32) {
    let out = bake_small(&manifest(name).spec(), levels, coarse, 2);
    let b = &out.contents.basis.basis;
    b.validate().unwrap();
    assert_eq!(b.levels(), levels as usize);
    let meta = &out.contents.meta;
    assert!(meta.scene.triangles > 0);
    assert_ne!(meta.scene.content_hash, 0);
    for l in 0..b.levels() {
        let range = b.level_range(l);
        assert!(!range.is_empty(), "{name}: level {l} is empty");
        // Every point lies inside the scene's bounds.
        for j in range.clone() {
            for a in 0..3 {
                let (lo, hi) = (meta.scene.bounds_min[a], meta.scene.bounds_max[a]);
                let slack = 1e-4 * (hi - lo);
                assert!(b.positions[j][a] >= lo - slack && b.positions[j][a] <= hi + slack);
            }
        }
    }
    // The Poisson-disk property on the coarsest level (all pairs; few points), for the points
    // placed: a pair closer than the disk holds a coverage fill, a copy of a finer level's
    // point (bake/src/coverage.rs; clipping the supports at walls adds some).
    let r = b.disk_radii[0];
    let l0 = b.level_range(0);
    let finer: std::collections::HashSet<[u32; 3]> = (l0.end..b.len())
        .map(|k| b.positions[k].map(f32::to_bits))
        .collect();
    let is_fill = |i: usize| finer.contains(&b.positions[i].map(f32::to_bits));
    for i in l0.clone() {
        for j in l0.clone().filter(|&j| j > i) {
            let d = poisson_distance(b.positions[i], b.normals[i], b.positions[j], b.normals[j]);
            assert!(
                d >= r || is_fill(i) || is_fill(j),
                "{name}: level-0 points {i} and {j} at {d} < {r}, neither a coverage fill"
            );
        }
    }
    let counts: Vec<u64> = meta.stats.levels.iter().map(|l| l.points).collect();
    eprintln!(
        "{name}: points per level {counts:?}, R_coarse {}",
        meta.params.coarse_radius
    );
}

#[test]
fn cornell_obj_bakes() {
    check_basis("cornell_obj.toml", 3, 40);
}

#[test]
fn sponza_bakes() {
    check_basis("sponza.toml", 2, 60);
}

#[test]
fn conference_with_degenerate_triangles_bakes() {
    check_basis("conference.toml", 2, 40);
}
