//! Helpers for the end-to-end tests in `tests/tests/`.

use std::path::PathBuf;

use glam::Vec3;
use mlt_bake::{bake_scene, BakeOptions, BakeOutput, Silent};
use mlt_scenes::RayCaster;
pub use mlt_test_support::{shared_scenes, SharedManifest, TempDir};

/// Surface points (with shading normals facing `from`) hit by `n` rays from `from` in a
/// golden-angle spiral of directions: query points independent of any basis.
pub fn surface_samples(caster: &dyn RayCaster, from: Vec3, n: usize) -> Vec<(Vec3, Vec3)> {
    let golden = std::f32::consts::PI * (3.0 - 5.0f32.sqrt());
    (0..n)
        .filter_map(|i| {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let r = (1.0 - z * z).sqrt();
            let phi = golden * i as f32;
            let d = Vec3::new(r * phi.cos(), z, r * phi.sin());
            caster
                .intersect(from, d, 0.0, f32::INFINITY)
                .map(|h| (h.position, h.shading_normal))
        })
        .collect()
}

/// The workspace root.
pub fn repo_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The repository's manifest `scenes/NAME` of a third-party scene, pointed at the shared
/// scenes wherever they are (see [`mlt_test_support::shared_manifest`]).
///
/// # Panics
/// When the shared scenes are missing.
pub fn shared_manifest(name: &str) -> SharedManifest {
    mlt_test_support::shared_manifest(&repo_dir().join("scenes").join(name))
}

/// Bakes the basis only of `spec` with `levels` levels and about `coarse` level-0 points on
/// `threads` threads.
pub fn bake_small(spec: &str, levels: u32, coarse: u32, threads: usize) -> BakeOutput {
    bake_with(
        spec,
        BakeOptions {
            receiver_levels: Some(levels),
            coarse_count: Some(coarse),
            basis_only: true,
            ..Default::default()
        },
        threads,
    )
}

/// Bakes `spec` with `opts` on `threads` threads; panics with the error's message on failure.
pub fn bake_with(spec: &str, opts: BakeOptions, threads: usize) -> BakeOutput {
    let scene = mlt_scenes::load_scene(spec).unwrap_or_else(|e| panic!("{e}"));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool");
    pool.install(|| bake_scene(&scene, &opts, &Silent))
        .unwrap_or_else(|e| panic!("{e}"))
}
