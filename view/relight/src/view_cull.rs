//! Flattening only what a view needs: the rows of the flattening operator and of the
//! sharpening steps (step 4 of [`crate::cpu`]) for the flat points whose functions a view
//! can splat, and those their sharpening reads.
//!
//! A renderer splats only the flat functions whose support sphere meets the view frustum, so
//! the other flat coefficients of a frame are never looked at. The flat points are stored in
//! Morton order and the products run in blocks of [`BLOCK_ROWS`] consecutive rows, so a block
//! is a compact patch of surface: each block gets the box that bounds its points' support
//! spheres, and only in the blocks whose box meets the frustum are the points' own spheres
//! tested. The sharpening steps `c_{k+1} = c_k + w_k (c_0 - W c_k)` couple neighbours through
//! `W`, so step `k` must compute its rows on the points that step `k + 1`'s rows read as well,
//! and the flattening product on those the first step reads: with `s` steps the rows needed
//! are the visible ones dilated `s` times by "reads a column of" in `W`'s rows. Every row
//! computed is computed as in the whole product (the same entries in the same order), so the
//! coefficients the view needs are the same bits as without culling. Blocks without a needed
//! row are skipped whole ([`RowMask`]).

use glam::Vec3;
use rayon::prelude::*;

use crate::flatten_op::{FlattenOp, RowMask, SharpenOp, BLOCK_ROWS};
use crate::frustum::Frustum;
use mlt_format::flat_basis::FlatBasis;

/// The flat points' support spheres, their blocks' boxes and the columns of `W`'s rows, built
/// once per flat basis.
#[derive(Clone, Debug, PartialEq)]
pub struct FlatCulling {
    /// Per flat point, its support sphere's centre and radius (a little enlarged, so that
    /// rounding can never reject a sphere that the renderer's sphere test keeps).
    centres: Vec<Vec3>,
    radii: Vec<f32>,
    /// Per block, the corners of the box bounding its points' spheres.
    lo: Vec<Vec3>,
    hi: Vec<Vec3>,
    /// `points + 1` offsets into `reads`, when there is a `W`.
    read_offsets: Vec<u32>,
    /// The flat points whose coefficients each row of `W` reads, row after row.
    reads: Vec<u32>,
    /// `points + 1` offsets into `readers`, when there is a `W`.
    reader_offsets: Vec<u32>,
    /// The rows of `W` that read each flat point's coefficient, point after point, each
    /// point's in ascending order: `reads` transposed, for dilating masks that hold most rows
    /// (see [`FlatCulling::dilate`]).
    readers: Vec<u32>,
}

/// The rows a view needs, per product.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewMasks {
    /// The flattening product's rows (`c_0`).
    pub flatten: RowMask,
    /// Sharpening step `k`'s rows (`c_{k+1}`), one mask per step.
    pub sharpen: Vec<RowMask>,
    /// The flat points whose functions may meet the view, one flag per point.
    pub visible: Vec<bool>,
}

impl ViewMasks {
    /// The rows either set of masks holds, product by product. Panics unless both are for
    /// as many sharpening steps and flat points.
    pub fn union(&self, other: &ViewMasks) -> ViewMasks {
        self.zip_with(other, RowMask::union, |a, b| a || b)
    }

    /// The rows these masks hold and `other` does not, product by product (what a view adds
    /// to what was computed for `other`). Panics as [`ViewMasks::union`] does.
    pub fn minus(&self, other: &ViewMasks) -> ViewMasks {
        self.zip_with(other, RowMask::minus, |a, b| a && !b)
    }

    /// `rows` on each product's masks and `flag` on the visible points.
    fn zip_with(
        &self,
        other: &ViewMasks,
        rows: fn(&RowMask, &RowMask) -> RowMask,
        flag: fn(bool, bool) -> bool,
    ) -> ViewMasks {
        assert_eq!(
            self.sharpen.len(),
            other.sharpen.len(),
            "masks of one pipeline"
        );
        assert_eq!(
            self.visible.len(),
            other.visible.len(),
            "masks of one flat basis"
        );
        ViewMasks {
            flatten: rows(&self.flatten, &other.flatten),
            sharpen: self
                .sharpen
                .iter()
                .zip(&other.sharpen)
                .map(|(a, b)| rows(a, b))
                .collect(),
            visible: self
                .visible
                .iter()
                .zip(&other.visible)
                .map(|(&a, &b)| flag(a, b))
                .collect(),
        }
    }

    /// Rows the flattening product computes.
    pub fn flatten_rows(&self) -> usize {
        self.flatten.count()
    }
}

impl FlatCulling {
    /// The spheres and blocks of `flat` and, with `sharpen`, `W`'s columns; `None` where the
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
        let centres: Vec<Vec3> = b.positions[..points].iter().map(|&p| p.into()).collect();
        let radii: Vec<f32> = centres
            .iter()
            .zip(&b.radii[..points])
            .map(|(c, &r)| r * (1.0 + 1e-4) + 1e-5 * c.abs().max_element())
            .collect();
        let (mut lo, mut hi) = (Vec::with_capacity(blocks), Vec::with_capacity(blocks));
        for block in 0..blocks {
            let (mut l, mut h) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
            for j in block * BLOCK_ROWS..((block + 1) * BLOCK_ROWS).min(points) {
                l = l.min(centres[j] - radii[j]);
                h = h.max(centres[j] + radii[j]);
            }
            lo.push(l);
            hi.push(h);
        }
        let (mut read_offsets, mut reads) = (Vec::new(), Vec::new());
        let (mut reader_offsets, mut readers) = (Vec::new(), Vec::new());
        if let Some(parts) = w.map(FlattenOp::parts) {
            // The column of each entry of row `j` of `W`, row after row.
            let row_cols = |j: usize| {
                let block = j / BLOCK_ROWS;
                let cols = &parts.block_cols
                    [parts.block_offsets[block] as usize..parts.block_offsets[block + 1] as usize];
                parts.entries[parts.row_offsets[j] as usize..parts.row_offsets[j + 1] as usize]
                    .iter()
                    .map(move |&e| cols[(e & 0xffff) as usize])
            };
            read_offsets.reserve(points + 1);
            read_offsets.push(0u32);
            for j in 0..points {
                reads.extend(row_cols(j));
                read_offsets.push(reads.len() as u32);
            }
            // Transposed by counting: readers of each column in ascending row order.
            let mut counts = vec![0u32; points + 1];
            for &k in &reads {
                counts[k as usize + 1] += 1;
            }
            for k in 0..points {
                counts[k + 1] += counts[k];
            }
            reader_offsets = counts;
            let mut next = reader_offsets.clone();
            readers = vec![0u32; reads.len()];
            for j in 0..points {
                for &k in &reads[read_offsets[j] as usize..read_offsets[j + 1] as usize] {
                    readers[next[k as usize] as usize] = j as u32;
                    next[k as usize] += 1;
                }
            }
        }
        Some(FlatCulling {
            centres,
            radii,
            lo,
            hi,
            read_offsets,
            reads,
            reader_offsets,
            readers,
        })
    }

    /// Number of blocks.
    pub fn blocks(&self) -> usize {
        self.lo.len()
    }

    /// The flat points whose support spheres may meet `frustum`, one flag per point.
    pub fn visible(&self, frustum: &Frustum) -> Vec<bool> {
        let mut visible = vec![false; self.centres.len()];
        visible
            .par_chunks_mut(BLOCK_ROWS)
            .enumerate()
            .with_min_len(8)
            .for_each(|(block, out)| {
                if !frustum.meets_box(self.lo[block], self.hi[block]) {
                    return;
                }
                // A block wholly inside: every point's centre is, so its sphere meets the view
                // (the radii's margin covers the rounding of the corner test).
                if frustum.contains_box(self.lo[block], self.hi[block]) {
                    out.fill(true);
                    return;
                }
                let at = block * BLOCK_ROWS;
                for (k, v) in out.iter_mut().enumerate() {
                    *v = frustum.meets_sphere(self.centres[at + k], self.radii[at + k]);
                }
            });
        visible
    }

    /// `next` dilated by `W`: the rows `next` holds and every row a row of `next` reads. A
    /// mask that holds few rows scatters through their reads; one that holds most gathers,
    /// row by row, whether a row of `next` reads it (in parallel, stopping at the first), so
    /// that the work follows the smaller side. Both give the same mask.
    fn dilate(&self, next: &[bool]) -> Vec<bool> {
        let held = next.iter().filter(|&&m| m).count();
        if 2 * held < next.len() {
            self.dilate_scatter(next)
        } else {
            self.dilate_gather(next)
        }
    }

    fn dilate_scatter(&self, next: &[bool]) -> Vec<bool> {
        // A row's own coefficient is read by its step whether or not `W` holds it.
        let mut wider = next.to_vec();
        for (j, _) in next.iter().enumerate().filter(|(_, &m)| m) {
            for &k in &self.reads[self.read_offsets[j] as usize..self.read_offsets[j + 1] as usize]
            {
                wider[k as usize] = true;
            }
        }
        wider
    }

    fn dilate_gather(&self, next: &[bool]) -> Vec<bool> {
        (0..next.len())
            .into_par_iter()
            .with_min_len(1024)
            .map(|k| {
                next[k]
                    || self.readers
                        [self.reader_offsets[k] as usize..self.reader_offsets[k + 1] as usize]
                        .iter()
                        .any(|&j| next[j as usize])
            })
            .collect()
    }

    /// The rows each product computes for `frustum` when `steps` sharpening steps follow
    /// the flattening (0: none). Panics when `steps` is above 0 and `W`'s columns were not
    /// given to [`FlatCulling::build`].
    pub fn masks(&self, frustum: &Frustum, steps: usize) -> ViewMasks {
        self.masks_for(self.visible(frustum), steps)
    }

    /// [`FlatCulling::masks`] for the flat points `visible` flags (one per point) instead of
    /// those a frustum meets. Dilation distributes over unions, so the masks of the points a
    /// new view adds to earlier views', joined to the earlier views' masks, are the masks of
    /// all the views: a camera move dilates only what it adds.
    pub fn masks_for(&self, visible: Vec<bool>, steps: usize) -> ViewMasks {
        assert!(
            steps == 0 || !self.reader_offsets.is_empty(),
            "sharpening steps without W's structure"
        );
        assert_eq!(visible.len(), self.centres.len(), "one flag per flat point");
        let mut rows = vec![visible.clone()];
        for _ in 0..steps {
            let wider = self.dilate(rows.last().expect("one mask at least"));
            rows.push(wider);
        }
        // `rows` holds the last step's rows first, the flattening's last.
        rows.reverse();
        let mut masks = rows.into_iter().map(RowMask::from_rows);
        let flatten = masks.next().expect("one mask at least");
        ViewMasks {
            flatten,
            sharpen: masks.collect(),
            visible,
        }
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

    /// The operators and culling of a flat basis on every point of a plane's hierarchy, with
    /// coefficients `alpha` of a smooth function and their whole sharpened product.
    struct Plane {
        fb: FlatBasis,
        op: FlattenOp,
        sharpen: SharpenOp,
        culling: FlatCulling,
        alpha: Vec<f32>,
        whole: Vec<f32>,
    }

    /// Flat point `j`'s coefficients in `flat` are those in `whole`, bit for bit.
    fn assert_point_bits(flat: &[f32], whole: &[f32], j: usize) {
        for d in 0..LINK_DIM {
            let (got, want) = (flat[j * LINK_DIM + d], whole[j * LINK_DIM + d]);
            assert_eq!(
                got.to_bits(),
                want.to_bits(),
                "point {j}, {d}: {got} vs {want}"
            );
        }
    }

    fn plane() -> Plane {
        let ib = plane_basis(6, 3);
        let fb = all(&ib);
        let op = FlattenOp::build(&ib, &fb, None).unwrap();
        let sharpen = SharpenOp::build(&fb).unwrap();
        let culling = FlatCulling::build(&fb, &op, Some(&sharpen)).unwrap();
        let alpha = coefficients(&ib, LINK_DIM);
        let mut whole = vec![0.0; fb.len() * LINK_DIM];
        op.apply(&alpha, LINK_DIM, &mut whole, &mut FlattenScratch::default());
        sharpen.apply(&mut whole, LINK_DIM, &mut SharpenScratch::default());
        Plane {
            fb,
            op,
            sharpen,
            culling,
            alpha,
            whole,
        }
    }

    #[test]
    fn the_view_needs_the_same_bits_as_the_whole_product() {
        let Plane {
            fb,
            op,
            sharpen,
            culling,
            alpha,
            whole,
        } = plane();
        assert!(culling.blocks() > 12, "{}", culling.blocks());
        let b = &fb.ib.basis;
        let mut inside = 0;
        for (x, y, h) in [
            (0.2, 0.3, 0.1),
            (0.8, 0.5, 0.1),
            (0.5, 0.5, 0.05),
            (0.5, 0.5, 0.4),
        ] {
            let frustum = looking_down(x, y, h, 0.8);
            let masks = culling.masks(&frustum, sharpen.steps());
            assert_eq!(masks.sharpen.len(), sharpen.steps());
            // Each product needs at least what the next one does, and the view not all.
            assert!(masks
                .sharpen
                .iter()
                .zip(std::iter::once(&masks.flatten).chain(&masks.sharpen))
                .all(|(next, before)| next.within(before)));
            let last = masks.sharpen.last().expect("steps");
            assert_eq!(last.rows(), masks.visible.as_slice());
            // Blocks wholly inside are taken whole: the same points as testing each sphere.
            inside += (0..culling.blocks())
                .filter(|&k| frustum.contains_box(culling.lo[k], culling.hi[k]))
                .count();
            for j in 0..fb.len() {
                let own = frustum.meets_sphere(culling.centres[j], culling.radii[j]);
                assert_eq!(masks.visible[j], own, "point {j}");
            }
            let rows = masks.flatten_rows();
            assert!(rows < fb.len() && last.count() > 0, "{rows}");
            // Rows, not whole blocks: fewer rows than the blocks hold.
            assert!(rows < masks.flatten.block_rows(), "{rows}");
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
                assert!(masks.visible[j], "point {j} meets the view");
                assert_point_bits(&flat, &whole, j);
            }
            assert!(seen > 0);
        }
        assert!(inside > 0, "no block wholly inside a view");
    }

    /// A second view under the same coefficients computes only the rows it adds, into the
    /// buffers the first view's products left, and its rows come out as the whole product's,
    /// bit for bit; a third view, covered by the two, adds nothing.
    #[test]
    fn a_second_view_adds_only_its_own_rows_with_the_same_bits() {
        let Plane {
            fb,
            op,
            sharpen,
            culling,
            alpha,
            whole,
        } = plane();
        let steps = sharpen.steps();
        let first = culling.masks(&looking_down(0.3, 0.3, 0.1, 0.8), steps);
        let second = culling.masks(&looking_down(0.45, 0.35, 0.1, 0.8), steps);
        let mut flat = vec![f32::NAN; fb.len() * LINK_DIM];
        let (mut scratch, mut fs) = (SharpenScratch::default(), FlattenScratch::default());
        op.apply_masked(&alpha, LINK_DIM, &mut flat, &mut fs, &first.flatten);
        sharpen.apply_masked(&mut flat, LINK_DIM, &mut scratch, &first.sharpen);
        let added = second.minus(&first);
        // The views overlap: some rows are new, not all.
        assert!(added.flatten.count() > 0 && added.flatten.count() < second.flatten.count());
        op.apply_masked(
            &alpha,
            LINK_DIM,
            scratch.original_mut(),
            &mut fs,
            &added.flatten,
        );
        sharpen.extend_masked(&mut flat, LINK_DIM, &mut scratch, &added.sharpen);
        let both = first.union(&second);
        // Dilation distributes over unions: the points the second view adds, dilated alone and
        // joined to the first view's masks, give the masks of both views.
        let adds = added.visible.clone();
        assert!(adds.iter().any(|&a| a));
        assert_eq!(first.union(&culling.masks_for(adds, steps)), both);
        for j in (0..fb.len()).filter(|&j| both.visible[j]) {
            assert_point_bits(&flat, &whole, j);
        }
        // Within both views: nothing to add.
        let inside = culling.masks(&looking_down(0.4, 0.33, 0.05, 0.3), steps);
        assert!(inside.flatten.minus(&both.flatten).count() == 0);
        assert!(inside
            .sharpen
            .iter()
            .zip(&both.sharpen)
            .all(|(n, d)| n.within(d)));
    }

    /// The scatter through `W`'s rows and the gather through its columns dilate alike, on
    /// masks that hold few rows and most (the two sides of [`FlatCulling::dilate`]'s choice),
    /// and every row a held row reads is in the result, and nothing else.
    #[test]
    fn both_dilations_give_the_same_rows() {
        let Plane { fb, culling, .. } = plane();
        let n = fb.len();
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        for density in [0.01, 0.1, 0.45, 0.55, 0.9, 0.99] {
            let mask: Vec<bool> = (0..n)
                .map(|_| {
                    state = state
                        .wrapping_mul(6_364_136_223_846_793_005)
                        .wrapping_add(1_442_695_040_888_963_407);
                    ((state >> 11) as f64 / (1u64 << 53) as f64) < density
                })
                .collect();
            let scatter = culling.dilate_scatter(&mask);
            assert_eq!(scatter, culling.dilate_gather(&mask), "density {density}");
            assert_eq!(scatter, culling.dilate(&mask), "density {density}");
            // The definition, row by row.
            let mut want = mask.clone();
            for j in (0..n).filter(|&j| mask[j]) {
                let r = culling.read_offsets[j] as usize..culling.read_offsets[j + 1] as usize;
                for &k in &culling.reads[r] {
                    want[k as usize] = true;
                }
            }
            assert_eq!(scatter, want);
            let (held, wider) = (
                mask.iter().filter(|&&m| m).count(),
                scatter.iter().filter(|&&m| m).count(),
            );
            assert!(wider > held || held == n, "{density}: {held} -> {wider}");
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
        assert_eq!(masks.flatten.rows(), masks.visible.as_slice());
        assert!(masks.visible.iter().all(|v| !v));
        // And a view of everything needs every block.
        let all_in = looking_down(0.5, 0.5, 3.0, 1.2);
        assert!(culling.visible(&all_in).iter().all(|&v| v));
    }
}
