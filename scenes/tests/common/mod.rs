//! Helpers shared by the integration tests.
#![allow(dead_code, unused_imports)]

pub use mlt_test_support::{shared_manifest, shared_scene, TempDir};

/// Deterministic unit vectors (splitmix64 → uniform on the sphere).
pub fn directions(n: usize, seed: u64) -> Vec<glam::Vec3> {
    let mut state = seed;
    let mut next = move || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    };
    (0..n)
        .map(|_| {
            let z = 2.0 * next() - 1.0;
            let phi = std::f32::consts::TAU * next();
            let r = (1.0 - z * z).max(0.0).sqrt();
            glam::Vec3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect()
}
