//! The occluders inside each basis function's support, found by a ring of rays along its
//! surface: the clip planes of [`mlt_format::support_clip`], so that a function stops at a
//! wall instead of reaching under it into the next room (a sender emitting there, a receiver
//! showing its light there).
//!
//! From a point `p` with support radius `r` on a face of normal `n` (the face's, not the
//! point's shading normal, which on a curved mesh would tilt the ring into the next facet),
//! [`RING_RAYS`] rays leave `p + h n` (`h` = [`LIFT`] `r`, less where something stands closer
//! above the point) in directions evenly spread over the face's plane, each out to `r`. A ray
//! that hits a surface standing more than 60 degrees from the point's face (a wall on a floor)
//! gives that surface's plane, turned to face the point; a surface closer to the face's own
//! orientation ([`MAX_FACE_COS`]) is the surface going on (a bump, a ramp, a curve the ring
//! grazes), and cutting behind it would cut the surface's own far part. Consecutive rays whose
//! planes agree (normals within [`SAME_NORMAL`], offsets within [`SAME_OFFSET`] `r`) make one
//! clip plane with the wedge of azimuths they span, half a ray's spacing beyond the first and
//! the last, at most half a turn (longer runs are split). A plane that has the point itself
//! behind it (by more than the tolerance) is dropped, and a point keeps at most
//! [`MAX_PLANES`], the widest. Points on an occluder's own plane are kept: the plane's offset
//! holds [`TOLERANCE_EPS`] ray epsilons.
//!
//! The ring sees only what stands higher than `h` over the tangent plane: a wall, the side
//! of a block, a column; not a skirting board lower than `h`. It depends only on the point
//! and the scene, so recomputing it after the basis changes gives the same planes.

use glam::Vec3;
use mlt_format::support_clip::{ClipPlane, SupportClip};
use mlt_format::IndexedBasis;
use mlt_scenes::raycast::geometric_normal_under;
use mlt_scenes::sampling::tangent_frame;
use mlt_scenes::RayCaster;
use rayon::prelude::*;

/// Rays in a point's ring.
pub const RING_RAYS: usize = 32;
/// The ring's height over the point, as a fraction of its support radius.
pub const LIFT: f32 = 0.02;
/// Most clip planes a point keeps.
pub const MAX_PLANES: usize = 8;
/// Two hits lie on one plane when their normals' cosine is above this...
pub const SAME_NORMAL: f32 = 0.999;
/// ... and their planes' offsets differ by less than this many support radii.
pub const SAME_OFFSET: f32 = 0.01;
/// A hit surface whose normal's cosine with the point's face normal exceeds this (in
/// magnitude) is not an occluder: it is the point's own surface going on.
pub const MAX_FACE_COS: f32 = 0.5;
/// How far behind its occluder's plane, in ray epsilons, a point must lie to be cut.
pub const TOLERANCE_EPS: f32 = 4.0;

/// Clip planes of the points of levels `0..levels` of `ib`, computed in parallel, in point
/// order; the finer points get none.
pub fn clip_supports(ib: &IndexedBasis, caster: &dyn RayCaster, levels: usize) -> SupportClip {
    let b = &ib.basis;
    let levels = levels.min(b.levels());
    let end = if levels == 0 {
        0
    } else {
        b.level_offsets[levels] as usize
    };
    let eps = caster.ray_epsilon();
    let rows: Vec<Vec<ClipPlane>> = (0..end)
        .into_par_iter()
        .map(|j| {
            clip_planes(
                caster,
                Vec3::from(b.positions[j]),
                Vec3::from(b.normals[j]),
                b.radii[j],
                eps,
            )
        })
        .collect();
    let clip = SupportClip::from_rows(rows);
    if clip.is_empty() {
        SupportClip::default()
    } else {
        clip
    }
}

/// The clip planes of one point (module docs).
pub fn clip_planes(caster: &dyn RayCaster, p: Vec3, n: Vec3, r: f32, eps: f32) -> Vec<ClipPlane> {
    if !(r.is_finite() && r > 0.0 && p.is_finite() && n.is_finite()) {
        return Vec::new();
    }
    // The ring lies in the plane of the face the point is on: a shading normal smoothed
    // across a curved surface's facets would tilt it into the neighbouring facet, whose
    // plane would then cut the curved surface's own far side.
    let n = geometric_normal_under(caster, p, n, eps);
    let mut h = (LIFT * r).max(8.0 * eps);
    // Something closer above the point than the ring's height: lift it halfway there.
    if let Some(above) = caster.intersect(p + n * eps, n, 0.0, h) {
        h = 0.5 * (above.t + eps);
    }
    let origin = p + n * h;
    let (t, _) = tangent_frame(n);
    let bt = n.cross(t);
    let step = std::f32::consts::TAU / RING_RAYS as f32;
    let dir = |a: f32| t * a.cos() + bt * a.sin();
    let tol = TOLERANCE_EPS * eps;
    // Per ray: the plane (normal, offset) of what it hit, facing the point.
    let hits: Vec<Option<(Vec3, f32)>> = (0..RING_RAYS)
        .map(|k| {
            let d = dir(k as f32 * step);
            let hit = caster.intersect(origin, d, 0.0, r)?;
            let mut m = hit.geometric_normal.normalize_or_zero();
            if m == Vec3::ZERO {
                return None;
            }
            if m.dot(d) > 0.0 {
                m = -m;
            }
            // A surface within 60 degrees of the point's face is that surface going on (a
            // bump, a ramp, a curve the ring grazes), not a wall standing on it.
            if m.dot(n).abs() > MAX_FACE_COS {
                return None;
            }
            let c = -m.dot(hit.position);
            // A plane with the point behind it would cut the point's own surface. A point on
            // it (within the tolerance: a floor's point at the foot of a wall) keeps it.
            (m.dot(p) + c >= -tol).then_some((m, c))
        })
        .collect();
    let same = |a: (Vec3, f32), b: (Vec3, f32)| {
        a.0.dot(b.0) > SAME_NORMAL && (a.1 - b.1).abs() < SAME_OFFSET * r
    };
    // Start the cyclic scan where a run begins: after a miss or a change of plane.
    let start = (0..RING_RAYS).find(|&k| {
        let prev = hits[(k + RING_RAYS - 1) % RING_RAYS];
        match (prev, hits[k]) {
            (_, None) => false,
            (None, Some(_)) => true,
            (Some(a), Some(b)) => !same(a, b),
        }
    });
    // Runs as (first ray, rays, plane of the run's first ray).
    let mut runs: Vec<(usize, usize, (Vec3, f32))> = Vec::new();
    let max_run = RING_RAYS / 2 - 1;
    let first = start.unwrap_or(0);
    let mut k = 0;
    while k < RING_RAYS {
        let i = (first + k) % RING_RAYS;
        let Some(plane) = hits[i] else {
            k += 1;
            continue;
        };
        let mut len = 1;
        while k + len < RING_RAYS && len < max_run {
            match hits[(first + k + len) % RING_RAYS] {
                Some(q) if same(plane, q) => len += 1,
                _ => break,
            }
        }
        runs.push((i, len, plane));
        k += len;
    }
    if runs.len() > MAX_PLANES {
        // The widest, then in ring order.
        runs.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        runs.truncate(MAX_PLANES);
        runs.sort_by_key(|r| r.0);
    }
    runs.iter()
        .map(|&(k0, len, (m, c))| {
            let a0 = (k0 as f32 - 0.5) * step;
            let a1 = (k0 as f32 + len as f32 - 0.5) * step;
            let e0 = n.cross(dir(a0));
            let e1 = dir(a1).cross(n);
            ClipPlane {
                plane: [m.x, m.y, m.z, c + tol],
                edge0: [e0.x, e0.y, e0.z, -e0.dot(p)],
                edge1: [e1.x, e1.y, e1.z, -e1.dot(p)],
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use mlt_scenes::{Material, Mesh, MeshCaster};

    /// A floor 4 x 4 at y = 0 and, when `wall`, a wall across it at x = 0 (1 mm thick,
    /// 2 high), from z = -2 to `wall_end`.
    fn floor_and_wall(wall_end: f32) -> MeshCaster {
        let mut tris: Vec<[Vec3; 3]> = Vec::new();
        let v = Vec3::new;
        let quad = |tris: &mut Vec<[Vec3; 3]>, q: [Vec3; 4]| {
            tris.push([q[0], q[1], q[2]]);
            tris.push([q[0], q[2], q[3]]);
        };
        quad(
            &mut tris,
            [
                v(-2., 0., -2.),
                v(-2., 0., 2.),
                v(2., 0., 2.),
                v(2., 0., -2.),
            ],
        );
        for x in [-0.0005, 0.0005] {
            quad(
                &mut tris,
                [
                    v(x, 0., -2.),
                    v(x, 2., -2.),
                    v(x, 2., wall_end),
                    v(x, 0., wall_end),
                ],
            );
        }
        let mut mesh = Mesh {
            materials: vec![Material::plain("m", [0.5; 3])],
            ..Default::default()
        };
        for t in &tris {
            let base = mesh.positions.len() as u32;
            mesh.positions.extend_from_slice(t);
            mesh.triangles.push([base, base + 1, base + 2]);
            mesh.triangle_material.push(0);
        }
        MeshCaster::new(mesh)
    }

    fn cut_by(planes: &[ClipPlane], x: Vec3) -> bool {
        planes.iter().any(|p| p.cuts(x.to_array()))
    }

    #[test]
    fn a_floor_point_near_a_thin_wall_is_cut_off_behind_it_only() {
        let caster = floor_and_wall(2.0);
        let eps = caster.ray_epsilon();
        let p = Vec3::new(-0.3, 0.0, 0.0);
        let planes = clip_planes(&caster, p, Vec3::Y, 1.0, eps);
        assert!(!planes.is_empty());
        // The floor behind the 1 mm wall, right behind it and further, is cut; the floor on
        // the point's side, the point itself and the wall's near face are not.
        for x in [0.001, 0.01, 0.3, 0.6] {
            assert!(cut_by(&planes, Vec3::new(x, 0.0, 0.0)), "x = {x}");
            assert!(cut_by(&planes, Vec3::new(x, 0.0, 0.4)), "x = {x}, aside");
        }
        for q in [p, Vec3::new(-0.001, 0.0, 0.0), Vec3::new(-0.9, 0.0, 0.3)] {
            assert!(!cut_by(&planes, q), "{q}");
        }
        assert!(
            !cut_by(&planes, Vec3::new(-0.0005, 0.5, 0.1)),
            "the near face"
        );
        // A point at the wall's foot, closer to it than the tolerance, keeps the wall's plane.
        let foot = Vec3::new(-0.0005 - 0.25 * TOLERANCE_EPS * eps, 0.0, 0.0);
        let planes = clip_planes(&caster, foot, Vec3::Y, 0.05, eps);
        assert!(cut_by(&planes, Vec3::new(0.001, 0.0, 0.0)), "{planes:?}");
        assert!(!cut_by(&planes, foot) && !cut_by(&planes, Vec3::new(-0.01, 0.0, 0.0)));
    }

    #[test]
    fn light_passes_a_wall_s_end_and_open_floor_is_never_cut() {
        // The wall ends at z = 0.2: past its end, beside the point, the floor is seen.
        let caster = floor_and_wall(0.2);
        let eps = caster.ray_epsilon();
        let p = Vec3::new(-0.3, 0.0, 0.0);
        let planes = clip_planes(&caster, p, Vec3::Y, 1.0, eps);
        assert!(cut_by(&planes, Vec3::new(0.3, 0.0, -0.2)));
        assert!(
            !cut_by(&planes, Vec3::new(0.1, 0.0, 0.8)),
            "past the wall's end"
        );
        // Far from the wall (beyond the support radius) nothing is hit: no planes.
        let far = clip_planes(&caster, Vec3::new(-1.5, 0.0, 0.0), Vec3::Y, 1.0, eps);
        assert!(far.is_empty(), "{far:?}");
    }

    #[test]
    fn planes_of_a_basis_are_its_senders_only() {
        let caster = floor_and_wall(2.0);
        let mut b = mlt_format::Basis::default();
        for x in [-0.3f32, 0.3, -0.2] {
            b.positions.push([x, 0.0, 0.0]);
            b.normals.push([0.0, 1.0, 0.0]);
            b.radii.push(1.0);
        }
        b.level_offsets = vec![0, 2, 3];
        b.disk_radii = vec![0.5, 0.25];
        let ib = IndexedBasis::build(b).unwrap();
        let clip = clip_supports(&ib, &caster, 1);
        assert_eq!(clip.points(), 2);
        assert!(clip.cuts(0, [0.3, 0.0, 0.0]) && clip.cuts(1, [-0.3, 0.0, 0.0]));
        assert!(!clip.cuts(2, [0.3, 0.0, 0.0]), "a receiver-only point");
        let ib = ib.with_clip(clip).unwrap();
        // Each side's function is alone on its side: the Shepard value there is 1.
        let mut seen = Vec::new();
        ib.for_each_basis_value(0, [0.2, 0.0, 0.0], [0.0, 1.0, 0.0], |j, v| {
            seen.push((j, v))
        });
        assert_eq!(seen, vec![(1, 1.0)]);
    }
}
