//! The bake's estimate of the single-bounce light that the refinement of T drops
//! ([`RefinementDrop`], the file's `TDRP` section), weighted by a representative emission.
//!
//! Under uniform emission the dropped links of finer senders carry nothing (a constant has no
//! detail coefficients), and the dropped differences of finer receivers (Eq. 17) partly cancel,
//! so an estimate under uniform emission can have the wrong sign for a real light. Here the
//! links are weighted by the emission the file's own light gives: its direct irradiance at
//! every sender point (the light model `I max(0, cos) / d^2` inside a spot's cone, one shadow
//! ray), pull-pushed onto the sender levels as the viewer projects it (section 3.3). Per
//! processed receiver `i` of level `l` the light `sum_j (n_i . T_ij) e_j` of its kept and of
//! its dropped links is summed per colour channel and weighted by `R_l^2`, the area its basis
//! function stands for, so that the sums over all levels approximate integrals of the
//! hierarchical expansion (finer rows are differences, Eq. 17, and add with their sign).

use glam::Vec3;
use mlt_format::light::{LightDesc, LightKind};
use mlt_format::links::LINK_DIM;
use mlt_format::meta::RefinementDrop;
use mlt_format::pull_push::pull_push_levels;
use mlt_format::IndexedBasis;
use mlt_scenes::RayCaster;
use rayon::prelude::*;

use crate::refine::ReceiverLinks;

/// What [`RefinementDrop::emission`] says the sums are weighted by.
pub const EMISSION: &str = "file light";

/// Unoccluded direct irradiance of `light` at `(x, n)`: `I max(0, cos) / d^2`, zero outside a
/// spot's cone (a smooth falloff counts as the full cone: an estimate's emission).
fn irradiance(light: &LightDesc, x: Vec3, n: Vec3) -> [f32; 3] {
    let d = Vec3::from(light.position) - x;
    let d2 = d.length_squared();
    if !(d2 > 0.0) {
        return [0.0; 3];
    }
    let l = d / d2.sqrt();
    if light.kind == LightKind::Spot {
        let axis = Vec3::from(light.direction.unwrap_or([0.0, -1.0, 0.0])).normalize_or_zero();
        let half = light.cone_deg.unwrap_or(0.0).to_radians() * 0.5;
        if (-l).dot(axis) < half.cos() {
            return [0.0; 3];
        }
    }
    let k = n.dot(l).max(0.0) / d2;
    light.intensity.map(|i| i * k)
}

/// The representative emission: `light`'s direct irradiance sampled at the points of the
/// coarsest `sender_levels` levels and pull-pushed onto them (3 floats per sender point).
pub fn representative_emission(
    ib: &IndexedBasis,
    caster: &dyn RayCaster,
    light: &LightDesc,
    sender_levels: usize,
) -> Vec<f32> {
    let b = &ib.basis;
    let levels = sender_levels.min(b.levels());
    let points = b.level_offsets[levels] as usize;
    let eps = caster.ray_epsilon();
    let target = Vec3::from(light.position);
    let samples: Vec<f32> = (0..points)
        .into_par_iter()
        .flat_map_iter(|j| {
            let (x, n) = (Vec3::from(b.positions[j]), Vec3::from(b.normals[j]));
            let mut e = irradiance(light, x, n);
            if e != [0.0; 3] && caster.occluded(x + n * eps, target) {
                e = [0.0; 3];
            }
            e
        })
        .collect();
    pull_push_levels(ib, &samples, 3, levels).0
}

/// Per channel, `(n . v_c) e_j[c]` of a link `v` from sender `j` at a receiver of normal `n`.
#[inline]
pub fn link_light(v: &[f32; LINK_DIM], n: [f32; 3], e: &[f32], j: u32) -> [f64; 3] {
    let ej = &e[3 * j as usize..3 * j as usize + 3];
    std::array::from_fn(|c| {
        let along = n[0] * v[3 * c] + n[1] * v[3 * c + 1] + n[2] * v[3 * c + 2];
        along as f64 * ej[c] as f64
    })
}

/// The estimate from T's per-row sums, added in row order (the same in a single bake and in
/// a merge of shards, which rebuilds the rows in that order).
pub fn estimate(ib: &IndexedBasis, t: &ReceiverLinks) -> RefinementDrop {
    let (mut kept, mut dropped) = ([0.0f64; 3], [0.0f64; 3]);
    for (&r, d) in t.rows.iter().zip(&t.drop_light) {
        let area = (ib.basis.disk_radii[ib.basis.level_of(r as usize)] as f64).powi(2);
        for c in 0..3 {
            kept[c] += area * d[c];
            dropped[c] += area * d[3 + c];
        }
    }
    RefinementDrop::new(EMISSION, kept, dropped)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_light_above_a_surface_gives_inverse_square_cosine() {
        let light = LightDesc {
            kind: LightKind::Point,
            position: [0.0, 2.0, 0.0],
            intensity: [4.0, 8.0, 0.0],
            direction: None,
            cone_deg: None,
            falloff: Default::default(),
        };
        let e = irradiance(&light, Vec3::ZERO, Vec3::Y);
        assert_eq!(e, [1.0, 2.0, 0.0]);
        let side = irradiance(&light, Vec3::new(2.0, 0.0, 0.0), Vec3::Y);
        let expect = 4.0 * (2.0 / 8f32.sqrt()) / 8.0;
        assert!((side[0] - expect).abs() < 1e-6, "{side:?}");
        assert_eq!(irradiance(&light, Vec3::ZERO, -Vec3::Y), [0.0; 3]);
        let spot = LightDesc {
            kind: LightKind::Spot,
            direction: Some([0.0, -1.0, 0.0]),
            cone_deg: Some(60.0),
            ..light
        };
        assert_eq!(irradiance(&spot, Vec3::ZERO, Vec3::Y), [1.0, 2.0, 0.0]);
        assert_eq!(irradiance(&spot, Vec3::new(4.0, 0.0, 0.0), Vec3::Y), [0.0; 3]);
    }

    #[test]
    fn the_share_has_the_sign_of_the_dropped_light() {
        let d = RefinementDrop::new(EMISSION, [9.0, 9.0, 9.0], [1.0, -0.5, 0.0]);
        assert!((d.share - 0.1).abs() < 1e-12);
        let d = RefinementDrop::new(EMISSION, [9.0, 4.0, 9.0], [0.0, -2.0, 0.0]);
        assert!((d.share + 1.0).abs() < 1e-12);
    }
}
