//! The bake's estimate of the single-bounce light that the refinement of T drops
//! ([`RefinementDrop`], the file's `TDRP` section), weighted by a representative emission.
//!
//! Under uniform emission the dropped links of finer senders carry nothing (a constant has no
//! detail coefficients), and the dropped differences of finer receivers (Eq. 17) partly cancel,
//! so an estimate under uniform emission can have the wrong sign for a real light. Here the
//! links are weighted by the emission the file's own light gives: its direct irradiance at
//! every sender point (the viewer's light model, `mlt_format::light_model`, averaged over the
//! point's basis function near the light as the viewer does, one shadow ray),
//! pull-pushed onto the sender levels as the viewer projects it (section 3.3). The
//! dropped light is measured where it shows: at each processed receiver's point, the light its
//! gather found against what the kept hierarchy reconstructs there ([`estimate`]). A dropped
//! link of a coarse receiver that a finer receiver's difference (Eq. 17) restores costs
//! nothing there, and a receiver that refinement never processed costs its whole detail.

use glam::Vec3;
use mlt_format::light_model::Light;
use mlt_format::links::LINK_DIM;
use mlt_format::meta::RefinementDrop;
use mlt_format::pull_push::pull_push_levels;
use mlt_format::support_average::SupportAverage;
use mlt_format::IndexedBasis;
use mlt_scenes::RayCaster;
use rayon::prelude::*;

use crate::gather::Scratch;
use crate::refine::ReceiverLinks;

/// What [`RefinementDrop::emission`] says the sums are weighted by.
pub const EMISSION: &str = "file light";

/// The representative emission: `light`'s direct irradiance sampled at the points of the
/// coarsest `sender_levels` levels and pull-pushed onto them (3 floats per sender point).
/// Near the light a sample is the irradiance averaged over the point's basis function, blended
/// with the point's own as the viewer blends them (`mlt_format::support_average`), so that a
/// hot spot between sender points carries its flux here as in the viewer's frames.
pub fn representative_emission(
    ib: &IndexedBasis,
    caster: &dyn RayCaster,
    light: &Light,
    sender_levels: usize,
) -> Vec<f32> {
    let b = &ib.basis;
    let levels = sender_levels.min(b.levels());
    let points = b.level_offsets[levels] as usize;
    let eps = caster.ray_epsilon();
    let target = light.position;
    let support = SupportAverage::new(ib, points);
    let samples: Vec<f32> = (0..points)
        .into_par_iter()
        .flat_map_iter(|j| {
            let (x, n) = (Vec3::from(b.positions[j]), Vec3::from(b.normals[j]));
            let (mut e, _) = support.sample(j, light);
            if e != [0.0; 3] && caster.occluded(x + n * eps, target) {
                e = [0.0; 3];
            }
            e
        })
        .collect();
    pull_push_levels(ib, &samples, 3, levels).0
}

/// `sum_j T_j e_j` over the senders the gather touched: the vector irradiance under `e`.
pub fn applied(scratch: &Scratch, e: &[f32]) -> [f32; LINK_DIM] {
    let mut out = [0.0f32; LINK_DIM];
    for &j in &scratch.touched {
        if let Some(es) = e.get(3 * j as usize..3 * j as usize + 3) {
            let v = scratch.get(j);
            for k in 0..LINK_DIM {
                out[k] += v[k] * es[k / 3];
            }
        }
    }
    out
}

/// T's coefficients under the representative emission, `(T e)_i = sum_j T_ij e_j`, for the
/// `points` points of the basis (`LINK_DIM` floats each; zero where `t` has no row).
pub fn coefficients(points: usize, t: &ReceiverLinks) -> Vec<f32> {
    let e = &t.emission;
    let mut out = vec![0.0f32; points * LINK_DIM];
    for &r in &t.rows {
        let (senders, values) = t.row(r as usize);
        let c = &mut out[r as usize * LINK_DIM..(r as usize + 1) * LINK_DIM];
        for (&s, v) in senders.iter().zip(values) {
            if let Some(es) = e.get(3 * s as usize..3 * s as usize + 3) {
                for k in 0..LINK_DIM {
                    c[k] += v[k] * es[k / 3];
                }
            }
        }
    }
    out
}

/// Per colour channel, `n . v_c` of a point's vector irradiance `v` (9 floats, RGB-major).
pub(crate) fn along(v: &[f32], n: [f32; 3]) -> [f32; 3] {
    std::array::from_fn(|c| n[0] * v[3 * c] + n[1] * v[3 * c + 1] + n[2] * v[3 * c + 2])
}

/// The estimate from T. Per processed receiver the gather's vector irradiance under the
/// representative emission (`ReceiverLinks::gathered`, before Eq. 17 and the keep rules) is
/// projected with Eq. 7 over the processed receivers (a receiver that was not processed has
/// no coefficient in either expansion), which is what T's coefficients `(T e)_i` would be had
/// no link been dropped (Eq. 17 with every link kept is Eq. 7 of the gathers). The estimate
/// weighs each coefficient's difference along the receiver's normal by `R_l^2`, the area its
/// basis function stands for: a link dropped at a coarse receiver that a finer receiver's
/// difference restores cancels there. Summed in row order (the same in a single bake and in a
/// merge of shards, which rebuilds the rows in that order).
pub fn estimate(ib: &IndexedBasis, t: &ReceiverLinks) -> RefinementDrop {
    let b = &ib.basis;
    // T's coefficients under e, and the projection of the gathers, per point (zero where no row).
    let cut = coefficients(b.len(), t);
    let mut full = vec![0.0f32; b.len() * LINK_DIM];
    for (row, &r) in t.rows.iter().enumerate() {
        full[r as usize * LINK_DIM..(r as usize + 1) * LINK_DIM].copy_from_slice(&t.gathered[row]);
    }
    // Eq. 7, level by level, over the processed receivers only.
    let mut start = 0;
    for l in 0..b.levels() {
        let end = start
            + t.rows[start..]
                .iter()
                .take_while(|&&r| b.level_of(r as usize) == l)
                .count();
        let coarser: Vec<[f32; LINK_DIM]> = t.rows[start..end]
            .par_iter()
            .map(|&r| {
                let mut v = [0.0f32; LINK_DIM];
                if l > 0 {
                    let (x, n) = (b.positions[r as usize], b.normals[r as usize]);
                    ib.reconstruct(&full, LINK_DIM, 0..l, x, n, &mut v);
                }
                v
            })
            .collect();
        for (&r, v) in t.rows[start..end].iter().zip(&coarser) {
            for k in 0..LINK_DIM {
                full[r as usize * LINK_DIM + k] -= v[k];
            }
        }
        start = end;
    }
    let (mut kept, mut dropped) = ([0.0f64; 3], [0.0f64; 3]);
    for &r in &t.rows {
        let (r, n) = (r as usize, b.normals[r as usize]);
        let area = (b.disk_radii[b.level_of(r)] as f64).powi(2);
        let k = along(&cut[r * LINK_DIM..(r + 1) * LINK_DIM], n).map(f64::from);
        let f = along(&full[r * LINK_DIM..(r + 1) * LINK_DIM], n).map(f64::from);
        for c in 0..3 {
            kept[c] += area * k[c];
            dropped[c] += area * (f[c] - k[c]);
        }
    }
    RefinementDrop::new(EMISSION, kept, dropped)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_share_has_the_sign_of_the_dropped_light() {
        let d = RefinementDrop::new(EMISSION, [9.0, 9.0, 9.0], [1.0, -0.5, 0.0]);
        assert!((d.share - 0.1).abs() < 1e-12);
        let d = RefinementDrop::new(EMISSION, [9.0, 4.0, 9.0], [0.0, -2.0, 0.0]);
        assert!((d.share + 1.0).abs() < 1e-12);
    }
}
