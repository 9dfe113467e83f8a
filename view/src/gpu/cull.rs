//! Frustum culling of the flat basis functions with each level's R-tree (section 4.1), through
//! its visitor (`RTree::visit`): a node whose box (which bounds its points' own support
//! spheres, never smaller than the flat ones) lies outside a frustum plane is skipped with its
//! whole subtree; in the leaves that remain, each flat support sphere is tested.

use glam::Vec3;
use mlt_format::IndexedBasis;

pub use mlt_relight::Frustum;

/// Indices of the points of every level whose support sphere of radius `radius` (at most each
/// point's own radius: the flat basis's) meets the frustum, in increasing order within each
/// level (levels coarsest first), written into `out`. Returns the number of R-tree nodes
/// visited.
pub fn visible_points(
    ib: &IndexedBasis,
    frustum: &Frustum,
    radius: f32,
    out: &mut Vec<u32>,
) -> usize {
    out.clear();
    let b = &ib.basis;
    let mut visited = 0;
    for tree in &ib.trees {
        let start = out.len();
        visited += tree.visit(
            |lo, hi| frustum.meets_box(Vec3::from(lo), Vec3::from(hi)),
            |j| {
                let ju = j as usize;
                if frustum.meets_sphere(Vec3::from(b.positions[ju]), radius.min(b.radii[ju])) {
                    out.push(j);
                }
            },
        );
        out[start..].sort_unstable();
    }
    visited
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;

    #[test]
    fn culling_keeps_exactly_the_spheres_that_meet_the_frustum() {
        // A synthetic basis: a grid of points on a plane with varied radii.
        let mut basis = mlt_format::Basis::default();
        for k in 0..400 {
            let (x, z) = ((k % 20) as f32 * 0.5 - 5.0, (k / 20) as f32 * 0.5 - 5.0);
            basis.positions.push([x, 0.0, z]);
            basis.normals.push([0.0, 1.0, 0.0]);
            basis.radii.push(0.2 + 0.3 * ((k * 7) % 5) as f32 / 5.0);
        }
        basis.level_offsets = vec![0, 100, 400];
        basis.disk_radii = vec![1.0, 0.5];
        let ib = IndexedBasis::build(basis).unwrap();
        let cam = Camera::new(
            Vec3::new(0.0, 3.0, 6.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::Y,
            40.0,
            64,
            48,
        )
        .unwrap();
        let f = Frustum::from_view_proj(&cam.reversed_view_proj((0.1, 50.0)));
        let mut out = Vec::new();
        for radius in [0.25, f32::INFINITY] {
            visible_points(&ib, &f, radius, &mut out);
            let brute: Vec<u32> = (0..400u32)
                .filter(|&j| {
                    let j = j as usize;
                    let r = radius.min(ib.basis.radii[j]);
                    f.meets_sphere(Vec3::from(ib.basis.positions[j]), r)
                })
                .collect();
            assert_eq!(out, brute);
            assert!(!out.is_empty() && out.len() < 400, "{}", out.len());
        }
    }
}
