//! Coverage of the coarser levels: every point of a finer level must lie inside the support of
//! each coarser level, or the hierarchical expansion (Eq. 6) has a hole there.
//!
//! The levels are placed independently by dart throwing (section 2.3), each from its own
//! candidates with its own miss limit, so a coarse level can leave a patch of surface outside
//! every one of its supports while the finer levels cover it (on the built-in Cornell box, part
//! of the short block's front face has no level-0 function). The Shepard reconstruction of a
//! level (Eq. 2) is normalised, so it jumps from the full value to zero at the edge of the
//! level's support, and the finer levels cannot repair that: a finer receiver whose centre the
//! coarse level still covers carries a difference (Eq. 17) that is added, in the hole, to a
//! coarse reconstruction of zero, and receivers inside the hole carry full values of the
//! single bounce only (bounces 2 and later are computed on the coarsest receivers). The
//! rendered solution is dark there.
//!
//! The fix is in the basis: after placement, from the second-finest level down to level 0,
//! each point of every finer level (in index order, fills included) whose weight sum on level
//! `l` (Eq. 8) is below [`COVER_MIN_WEIGHT`] is copied onto level `l`, with level `l`'s support
//! radius; later points see the copies already added. A copy sits inside a Poisson disk of the
//! level (it breaks the disk property there, not the expansion), and a level covering all finer
//! points covers the surface those levels describe. The added points are re-sorted with the rest
//! of their level into Morton order. Deterministic: it depends only on the placed points.

use mlt_format::kernel::weight;
use mlt_format::morton::morton_order;
use mlt_format::{Basis, IndexedBasis};
use rayon::prelude::*;

/// Smallest weight sum (Eq. 8) of a coarser level at a finer point that counts as covered.
/// A point whose coarser weight sum is below it lies at the rim of that level's supports,
/// where the finer functions reach beyond them.
pub const COVER_MIN_WEIGHT: f32 = 0.05;

/// Points copied onto each level.
pub type Fills = Vec<Vec<([f32; 3], [f32; 3])>>;

/// The points to add to each level of `ib` so that every point of a finer level has a weight
/// sum of at least [`COVER_MIN_WEIGHT`] on it (see the module docs).
pub fn coverage_fills(ib: &IndexedBasis) -> Fills {
    let b = &ib.basis;
    let levels = b.levels();
    let mut fills: Fills = vec![Vec::new(); levels];
    for l in (0..levels.saturating_sub(1)).rev() {
        let radius = b.radii[b.level_range(l).start];
        // Copies only add weight, so a point the placed level covers stays covered: only the
        // points it leaves uncovered (found in parallel, in index order) go through the
        // sequential pass that sees the copies added before them.
        let finer: Vec<([f32; 3], [f32; 3])> = (l + 1..levels)
            .flat_map(|m| {
                b.level_range(m)
                    .map(|i| (b.positions[i], b.normals[i]))
                    .chain(fills[m].iter().copied())
            })
            .collect();
        let uncovered: Vec<([f32; 3], [f32; 3])> = finer
            .into_par_iter()
            .filter(|&(x, n)| ib.weight_sum(l, x, n) < COVER_MIN_WEIGHT)
            .collect();
        let mut added: Vec<([f32; 3], [f32; 3])> = Vec::new();
        for (x, n) in uncovered {
            let mut sum = ib.weight_sum(l, x, n);
            for (y, ny) in &added {
                sum += weight(x, n, *y, *ny, radius);
            }
            if sum < COVER_MIN_WEIGHT {
                added.push((x, n));
            }
        }
        fills[l] = added;
    }
    fills
}

/// `b` with the points of `fills` added to their levels, each level in Morton order again.
pub fn with_fills(b: &Basis, fills: &Fills) -> Basis {
    let mut out = Basis {
        level_offsets: vec![0],
        disk_radii: b.disk_radii.clone(),
        ..Basis::default()
    };
    for l in 0..b.levels() {
        let range = b.level_range(l);
        let radius = b.radii.get(range.start).copied().unwrap_or(0.0);
        let mut points: Vec<([f32; 3], [f32; 3], f32)> = range
            .map(|i| (b.positions[i], b.normals[i], b.radii[i]))
            .collect();
        if let Some(extra) = fills.get(l).filter(|f| !f.is_empty()) {
            points.extend(extra.iter().map(|(x, n)| (*x, *n, radius)));
            let positions: Vec<[f32; 3]> = points.iter().map(|p| p.0).collect();
            let order = morton_order(&positions);
            points = order.iter().map(|&i| points[i as usize]).collect();
        }
        for (x, n, r) in points {
            out.positions.push(x);
            out.normals.push(n);
            out.radii.push(r);
        }
        out.level_offsets.push(out.positions.len() as u32);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two levels on the plane z = 0 (normals +z): level 0 covers only x < 0.5, level 1 spans
    /// x in [0, 1].
    fn holed() -> IndexedBasis {
        let mut b = Basis::default();
        let up = [0.0, 0.0, 1.0];
        for k in 0..3 {
            b.positions.push([0.2 * k as f32, 0.0, 0.0]);
            b.normals.push(up);
            b.radii.push(0.3);
        }
        for k in 0..11 {
            b.positions.push([0.1 * k as f32, 0.0, 0.0]);
            b.normals.push(up);
            b.radii.push(0.15);
        }
        b.level_offsets = vec![0, 3, 14];
        b.disk_radii = vec![0.2, 0.1];
        IndexedBasis::build(b).unwrap()
    }

    #[test]
    fn a_hole_of_a_coarse_level_is_filled_and_every_finer_point_is_covered() {
        let ib = holed();
        let before = (ib.basis.level_range(1))
            .filter(|&i| ib.weight_sum(0, ib.basis.positions[i], ib.basis.normals[i]) < 0.05)
            .count();
        assert!(before >= 4, "{before}");
        let fills = coverage_fills(&ib);
        assert!(fills[1].is_empty());
        // Greedy: fewer copies than uncovered points (each covers its neighbours).
        assert!(
            !fills[0].is_empty() && fills[0].len() < before,
            "{:?}",
            fills[0]
        );
        let filled = IndexedBasis::build(with_fills(&ib.basis, &fills)).unwrap();
        let b = &filled.basis;
        assert_eq!(b.level_range(0).len(), 3 + fills[0].len());
        assert_eq!(b.level_range(1).len(), 11);
        for i in b.level_range(1) {
            let s = filled.weight_sum(0, b.positions[i], b.normals[i]);
            assert!(s >= COVER_MIN_WEIGHT, "point {i}: {s}");
        }
        for i in b.level_range(0) {
            assert_eq!(b.radii[i], 0.3);
        }
        assert!(coverage_fills(&filled).iter().all(|f| f.is_empty()));
    }

    #[test]
    fn a_covered_basis_is_left_alone() {
        let ib = holed();
        let b = &ib.basis;
        let mut covered = b.clone();
        covered.positions.truncate(3);
        covered.normals.truncate(3);
        covered.radii.truncate(3);
        covered.positions.extend(b.positions[3..8].iter().copied());
        covered.normals.extend(b.normals[3..8].iter().copied());
        covered.radii.extend(b.radii[3..8].iter().copied());
        covered.level_offsets = vec![0, 3, 8];
        let ib = IndexedBasis::build(covered).unwrap();
        assert!(coverage_fills(&ib).iter().all(|f| f.is_empty()));
    }
}
