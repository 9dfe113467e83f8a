//! Flattening only what a view needs: the rows of the flattening operator and of the
//! sharpening steps (step 4 of [`crate::cpu`]) for the flat points whose functions a view
//! can splat, and those their sharpening reads.
//!
//! A renderer splats only the flat functions whose support sphere meets the view frustum, so
//! the other flat coefficients of a frame are never looked at. The flat points are stored in
//! Morton order and the products run in blocks of [`BLOCK_ROWS`] consecutive rows, so a block
//! is a compact patch of surface: each block gets the box that bounds its points' support
//! spheres, and the blocks whose box meets the frustum are the ones the view needs. The
//! sharpening steps `c_{k+1} = c_k + w_k (c_0 - W c_k)` couple neighbours through `W`, so
//! step `k` must compute its rows on the blocks that step `k + 1`'s rows read as well,
//! and the flattening product on those the first step reads: with `s` steps the blocks needed
//! are the visible ones dilated `s` times by "reads a column of" in `W`'s block structure.
//! Every row computed is computed as in the whole product (the same entries in the same
//! order), so the coefficients the view needs are the same bits as without culling.

use glam::Vec3;

use crate::flatten_op::{FlattenOp, SharpenOp, BLOCK_ROWS};
use crate::frustum::Frustum;
use mlt_format::flat_basis::FlatBasis;

/// The blocks of flat points and the sharpening's block structure, built once per flat basis.
#[derive(Clone, Debug, PartialEq)]
pub struct FlatCulling {
    /// Flat points.
    points: usize,
    /// Per block, the corners of the box bounding its points' support spheres.
    lo: Vec<Vec3>,
    hi: Vec<Vec3>,
    /// `blocks + 1` offsets into `reads`.
    read_offsets: Vec<u32>,
    /// The blocks whose coefficients each block's rows of `W` read, block after block, in
    /// ascending order (the block itself included: a point's own function weighs at it).
    reads: Vec<u32>,
}

/// The blocks a view needs, per product.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewMasks {
    /// The flattening product's blocks (`c_0`).
    pub flatten: Vec<bool>,
    /// Sharpening step `k`'s blocks (`c_{k+1}`), one mask per step.
    pub sharpen: Vec<Vec<bool>>,
    /// The blocks whose functions may meet the view: those of the last product.
    pub visible: Vec<bool>,
}

impl ViewMasks {
    /// Rows the flattening product computes (of `points`).
    pub fn flatten_rows(&self, points: usize) -> usize {
        rows_of(&self.flatten, points)
    }
}

/// Rows of the blocks `mask` holds, of `points` rows in blocks of [`BLOCK_ROWS`].
fn rows_of(mask: &[bool], points: usize) -> usize {
    mask.iter()
        .enumerate()
        .filter(|(_, &m)| m)
        .map(|(b, _)| BLOCK_ROWS.min(points - b * BLOCK_ROWS))
        .sum()
}

impl FlatCulling {
    /// The blocks of `flat` and, with `sharpen`, `W`'s block structure; `None` where the
    /// operators' rows are not stored in the flat point order (flat bases that did not come
    /// from [`FlatBasis::build`]), which culling by blocks of points needs.
    pub fn build(
        flat: &FlatBasis,
        flatten: &FlattenOp,
        sharpen: Option<&SharpenOp>,
    ) -> Option<FlatCulling> {
        let points = flat.len();
        let blocks = points.div_ceil(BLOCK_ROWS);
        let w = sharpen.map(SharpenOp::smoothing);
        let in_order = |op: &FlattenOp| {
            op.in_point_order() && op.points() == points && op.block_count() == blocks
        };
        if !in_order(flatten) || w.is_some_and(|w| !in_order(w)) {
            return None;
        }
        let b = &flat.ib.basis;
        let (mut lo, mut hi) = (Vec::with_capacity(blocks), Vec::with_capacity(blocks));
        for block in 0..blocks {
            let (mut l, mut h) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
            for j in block * BLOCK_ROWS..((block + 1) * BLOCK_ROWS).min(points) {
                let c = Vec3::from(b.positions[j]);
                // A little more than the radius, so that rounding in the box test can never
                // reject a sphere that the renderer's sphere test keeps.
                let r = b.radii[j] * (1.0 + 1e-4) + 1e-5 * c.abs().max_element();
                l = l.min(c - r);
                h = h.max(c + r);
            }
            lo.push(l);
            hi.push(h);
        }
        let mut read_offsets = vec![0u32];
        let mut reads = Vec::new();
        let mut read = Vec::new();
        for block in 0..blocks {
            if let Some(parts) = w.map(FlattenOp::parts) {
                let cols = &parts.block_cols
                    [parts.block_offsets[block] as usize..parts.block_offsets[block + 1] as usize];
                read.clear();
                read.extend(cols.iter().map(|&k| k / BLOCK_ROWS as u32));
                read.push(block as u32);
                read.sort_unstable();
                read.dedup();
                reads.extend_from_slice(&read);
            }
            read_offsets.push(reads.len() as u32);
        }
        Some(FlatCulling {
            points,
            lo,
            hi,
            read_offsets,
            reads,
        })
    }

    /// Number of blocks.
    pub fn blocks(&self) -> usize {
        self.lo.len()
    }

    /// The blocks whose support spheres may meet `frustum`.
    pub fn visible(&self, frustum: &Frustum) -> Vec<bool> {
        self.lo
            .iter()
            .zip(&self.hi)
            .map(|(&lo, &hi)| frustum.meets_box(lo, hi))
            .collect()
    }

    /// The blocks each product computes for `frustum` when `steps` sharpening steps follow
    /// the flattening (0: none). Panics when `steps` is above 0 and `W`'s structure was not
    /// given to [`FlatCulling::build`].
    pub fn masks(&self, frustum: &Frustum, steps: usize) -> ViewMasks {
        // Every block reads itself in `W`, so `reads` is empty only without it.
        assert!(
            steps == 0 || !self.reads.is_empty(),
            "sharpening steps without W's structure"
        );
        let visible = self.visible(frustum);
        let mut sharpen = vec![visible.clone()];
        for _ in 0..steps {
            let next = sharpen.last().expect("one mask at least");
            let mut wider = next.clone();
            for (b, _) in next.iter().enumerate().filter(|(_, &m)| m) {
                for &r in
                    &self.reads[self.read_offsets[b] as usize..self.read_offsets[b + 1] as usize]
                {
                    wider[r as usize] = true;
                }
            }
            sharpen.push(wider);
        }
        // `sharpen` holds the last step's blocks first, the flattening's last.
        sharpen.reverse();
        let flatten = sharpen.remove(0);
        ViewMasks {
            flatten,
            sharpen,
            visible,
        }
    }

    /// Rows of the blocks `mask` holds.
    pub fn rows(&self, mask: &[bool]) -> usize {
        rows_of(mask, self.points)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flatten_op::tests::{all, coefficients};
    use crate::flatten_op::{FlattenScratch, SharpenScratch};
    use mlt_format::links::LINK_DIM;
    use mlt_format::test_support::plane_basis;

    /// A camera above the unit square at `(x, y, h)` looking straight down (up: +y).
    fn looking_down(x: f32, y: f32, h: f32, fov: f32) -> Frustum {
        let view =
            glam::camera::rh::view::look_at_mat4(Vec3::new(x, y, h), Vec3::new(x, y, 0.0), Vec3::Y);
        let proj = glam::camera::rh::proj::directx::perspective(fov, 1.5, 0.01, 10.0);
        Frustum::from_view_proj(&(proj * view))
    }

    #[test]
    fn the_view_needs_the_same_bits_as_the_whole_product() {
        let ib = plane_basis(6, 3);
        let fb = all(&ib);
        let op = FlattenOp::build(&ib, &fb, None).unwrap();
        let sharpen = SharpenOp::build(&fb).unwrap();
        let culling = FlatCulling::build(&fb, &op, Some(&sharpen)).unwrap();
        assert!(culling.blocks() > 12, "{}", culling.blocks());
        let alpha = coefficients(&ib, LINK_DIM);
        let mut whole = vec![0.0; fb.len() * LINK_DIM];
        op.apply(&alpha, LINK_DIM, &mut whole, &mut FlattenScratch::default());
        sharpen.apply(&mut whole, LINK_DIM, &mut SharpenScratch::default());
        let b = &fb.ib.basis;
        for (x, y, h) in [(0.2, 0.3, 0.1), (0.8, 0.5, 0.1), (0.5, 0.5, 0.05)] {
            let frustum = looking_down(x, y, h, 0.8);
            let masks = culling.masks(&frustum, sharpen.steps());
            assert_eq!(masks.sharpen.len(), sharpen.steps());
            // Each product needs at least what the next one does, and the view not all.
            assert!(masks
                .sharpen
                .iter()
                .zip(std::iter::once(&masks.flatten).chain(&masks.sharpen))
                .all(|(next, before)| next.iter().zip(before).all(|(n, b)| !n || *b)));
            let rows = masks.flatten_rows(fb.len());
            assert!(
                rows < fb.len() && culling.rows(&masks.visible) > 0,
                "{rows}"
            );
            // Stale values everywhere else: NaN, which must not reach a needed row.
            let mut flat = vec![f32::NAN; fb.len() * LINK_DIM];
            let mut scratch = SharpenScratch::default();
            op.apply_masked(
                &alpha,
                LINK_DIM,
                &mut flat,
                &mut FlattenScratch::default(),
                &masks.flatten,
            );
            sharpen.apply_masked(&mut flat, LINK_DIM, &mut scratch, &masks.sharpen);
            let mut seen = 0;
            for j in 0..fb.len() {
                if !frustum.meets_sphere(Vec3::from(b.positions[j]), b.radii[j]) {
                    continue;
                }
                seen += 1;
                assert!(masks.visible[j / BLOCK_ROWS], "point {j} meets the view");
                for d in 0..LINK_DIM {
                    let (got, want) = (flat[j * LINK_DIM + d], whole[j * LINK_DIM + d]);
                    assert_eq!(
                        got.to_bits(),
                        want.to_bits(),
                        "point {j}, {d}: {got} vs {want}"
                    );
                }
            }
            assert!(seen > 0);
        }
    }

    #[test]
    fn a_view_of_nothing_needs_no_block() {
        let ib = plane_basis(4, 3);
        let fb = all(&ib);
        let op = FlattenOp::build(&ib, &fb, None).unwrap();
        let culling = FlatCulling::build(&fb, &op, None).unwrap();
        // Looking up, away from the square.
        let view = glam::camera::rh::view::look_at_mat4(
            Vec3::new(0.5, 0.5, 1.0),
            Vec3::new(0.5, 0.5, 2.0),
            Vec3::Y,
        );
        let frustum = Frustum::from_view_proj(
            &(glam::camera::rh::proj::directx::perspective(0.8, 1.0, 0.01, 10.0) * view),
        );
        let masks = culling.masks(&frustum, 0);
        assert!(masks.sharpen.is_empty());
        assert_eq!(masks.flatten, masks.visible);
        assert!(masks.visible.iter().all(|v| !v));
        // And a view of everything needs every block.
        let all_in = looking_down(0.5, 0.5, 3.0, 1.2);
        assert!(culling.visible(&all_in).iter().all(|&v| v));
    }
}
