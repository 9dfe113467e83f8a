//! Per-cell lists of the sender levels' R-tree leaves: the gather's basis evaluation (Eq. 8 at
//! every hit of Eq. 16) without an R-tree descent per hit and level.
//!
//! A uniform grid covers the bounding box of every sender leaf. A cell's list holds, per sender
//! level, the leaves of that level's R-tree whose boxes overlap the cell (slightly enlarged), in
//! the tree's depth-first order. At a point `x` of the cell, [`SenderCells::for_each_weight`]
//! keeps the weights of the listed leaves whose box contains `x`. The four points of a leaf are
//! weighed side by side (SSE2 on x86-64) from a copy of the leaf laid out for that, and the box
//! test and the weights' signs become masks: a data-dependent branch per leaf and per point
//! cost more than weighing every listed leaf. An inner node's box is the exact union of its
//! items' boxes, so it contains every leaf box below it: the leaves an R-tree query enters are
//! exactly those whose own box contains `x`, visited in depth-first order. The list therefore
//! yields the same senders with the same weights in the same order as
//! [`IndexedBasis::for_each_weight`], and the Shepard sums (Eq. 2) and the accumulated links are
//! bit-identical.
//!
//! Lists are built on first use (a hit in the cell), so only cells on surfaces that rays reach
//! cost memory; the grid's size is capped.

use std::sync::OnceLock;

use mlt_format::kernel::SQUASH;
use mlt_format::rtree::LEAF_SIZE;
use mlt_format::shepard::MIN_WEIGHT_SUM;
use mlt_format::{Basis, IndexedBasis, RTree};

/// Where a cell's list entry keeps, above the leaf's index, the masks of the leaf's items
/// (one bit per item, [`LEAF_SIZE`] of them): whose weight may be non-zero in the cell, whose
/// clip planes must be tested there, and whose planes cut the whole cell.
const WEIGH_BITS: u32 = 32;
const TEST_BITS: u32 = 40;
const ALWAYS_BITS: u32 = 48;

/// The item mask of a list entry at `bits`.
#[inline(always)]
fn lanes(entry: u64, bits: u32) -> u32 {
    (entry >> bits) as u32 & 0xff
}

/// What a point's clip planes do in a cell ([`SenderCells::clip_in_box`]).
enum ClipInBox {
    Never,
    Always,
    Test,
}

/// Most cells along one axis (bounds the rounding of the cell index, see [`SenderCells::new`]).
const MAX_AXIS_CELLS: usize = 1024;
/// Most cells in all.
const MAX_CELLS: usize = 1 << 21;
/// Cell side as a fraction of the mean support radius of the finest sender level.
const CELL_PER_RADIUS: f32 = 0.2;

/// The grid of leaf lists over the sender levels `0..levels` of a basis.
pub struct SenderCells<'a> {
    ib: &'a IndexedBasis,
    levels: usize,
    lo: [f32; 3],
    hi: [f32; 3],
    cell: f32,
    inv_cell: f32,
    /// Absolute enlargement of a cell's box when its list is built, covering the rounding of
    /// the index computation.
    pad: f32,
    /// The largest coordinate magnitude of the grid's bounds.
    max_abs: f32,
    dims: [usize; 3],
    /// Per cell: `levels` end offsets (into the rest of the slice), then the leaves of every
    /// level, level by level: the leaf's index in `leaves` in the low 32 bits, and above them
    /// the masks of the leaf's items whose weight may be non-zero in the cell (the others are
    /// skipped), whose clip planes must be tested in it and whose planes cut all of it
    /// ([`WEIGH_BITS`], [`TEST_BITS`], [`ALWAYS_BITS`]).
    cells: Vec<OnceLock<Box<[u64]>>>,
    /// Per sender level, its R-tree's leaves in node order, packed ([`Leaf`]).
    leaves: Vec<Vec<Leaf>>,
    /// Per sender level and R-tree node, the node's index in `leaves` (leaves only).
    leaf_of_node: Vec<Vec<u32>>,
}

/// One R-tree leaf as the weight evaluation reads it: its box, then its points (at most
/// [`LEAF_SIZE`], four) component by component, so that their four weights of Eq. 8 are
/// computed side by side, with no branch per point ([`Leaf::weights`]). Unused lanes have a
/// zero normal, hence zero weight, and the cell lists never name them.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(16))]
struct Leaf {
    /// The box's lower and upper corners (the fourth lane is padding, which keeps every
    /// field 16 bytes).
    lo: [f32; 4],
    hi: [f32; 4],
    px: [f32; 4],
    py: [f32; 4],
    pz: [f32; 4],
    nx: [f32; 4],
    ny: [f32; 4],
    nz: [f32; 4],
    /// `1 / r_j`.
    inv_radius: [f32; 4],
    /// Global point indices.
    j: [u32; 4],
}

// A leaf's points fill the four lanes of `Leaf`.
const _: () = assert!(LEAF_SIZE == 4);

impl Leaf {
    /// Leaf node `node` of `tree` over the points of `b`.
    fn new(b: &Basis, tree: &RTree, node: usize) -> Leaf {
        let (lo, hi) = (tree.node_min[node], tree.node_max[node]);
        let mut leaf = Leaf {
            lo: [lo[0], lo[1], lo[2], 0.0],
            hi: [hi[0], hi[1], hi[2], 0.0],
            px: [0.0; 4],
            py: [0.0; 4],
            pz: [0.0; 4],
            nx: [0.0; 4],
            ny: [0.0; 4],
            nz: [0.0; 4],
            inv_radius: [0.0; 4],
            j: [u32::MAX; 4],
        };
        let first = tree.node_first[node] as usize;
        let count = tree.node_count[node] as usize;
        for (k, &j) in tree.items[first..first + count].iter().enumerate() {
            let ju = j as usize;
            let (p, n) = (b.positions[ju], b.normals[ju]);
            (leaf.px[k], leaf.py[k], leaf.pz[k]) = (p[0], p[1], p[2]);
            (leaf.nx[k], leaf.ny[k], leaf.nz[k]) = (n[0], n[1], n[2]);
            leaf.inv_radius[k] = 1.0 / b.radii[ju];
            leaf.j[k] = j;
        }
        leaf
    }

    /// Whether the leaf's box contains `x` (`RTree::node_contains`: false for NaN), as a
    /// mask of all lanes or none, without a branch.
    #[inline(always)]
    fn contains_mask(&self, x: [f32; 3]) -> u32 {
        let inside = (0..3).fold(true, |all, a| {
            all & (x[a] >= self.lo[a]) & (x[a] <= self.hi[a])
        });
        0u32.wrapping_sub(u32::from(inside))
    }

    /// The weights `mlt_format::kernel::weight(x, n, x_j, n_j, r_j)` (Eq. 8) of the four
    /// lanes, with the same floating-point operations in the same order (the reciprocal of
    /// the radius precomputed; the radius is positive and finite in a validated basis), and
    /// the mask of the lanes whose weight is positive. With SSE2 (every x86-64 CPU) the four
    /// are computed at once by [`Leaf::weights_sse2`], which gives the same bits.
    #[inline(always)]
    fn weights(&self, x: [f32; 3], n: [f32; 3]) -> ([f32; 4], u32) {
        #[cfg(target_arch = "x86_64")]
        {
            self.weights_sse2(x, n)
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            self.weights_scalar(x, n)
        }
    }

    /// [`Leaf::weights`] one lane at a time ([`mlt_format::kernel::weight_inv_radius`]).
    #[cfg(any(test, not(target_arch = "x86_64")))]
    #[inline(always)]
    fn weights_scalar(&self, x: [f32; 3], n: [f32; 3]) -> ([f32; 4], u32) {
        let mut w = [0.0f32; 4];
        let mut positive = 0u32;
        for (k, wk) in w.iter_mut().enumerate() {
            let p = [self.px[k], self.py[k], self.pz[k]];
            let nj = [self.nx[k], self.ny[k], self.nz[k]];
            *wk = mlt_format::kernel::weight_inv_radius(x, n, p, nj, self.inv_radius[k]);
            positive |= u32::from(*wk > 0.0) << k;
        }
        (w, positive)
    }

    /// [`Leaf::weights`] with SSE2, four lanes at once. Every operation is the scalar one per
    /// lane (products and sums in the same order, no fused multiply-add, a correctly rounded
    /// square root), and the branches become masks: a lane whose `c` is not above zero (also
    /// NaN) or whose `q` is not below one (also NaN) is zero, as the scalar code returns. For
    /// `0 <= r < 1` the kernel's polynomial `(2r - 3) r^2 + 1` is what `kernel` computes (at
    /// `r = 0` it is exactly one, `kernel`'s value there).
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn weights_sse2(&self, x: [f32; 3], n: [f32; 3]) -> ([f32; 4], u32) {
        use std::arch::x86_64::{
            __m128, _mm_add_ps, _mm_and_ps, _mm_cmpgt_ps, _mm_cmplt_ps, _mm_load_ps,
            _mm_movemask_ps, _mm_mul_ps, _mm_set1_ps, _mm_setzero_ps, _mm_sqrt_ps, _mm_sub_ps,
        };
        // SAFETY: SSE and SSE2 are part of every x86-64 CPU (the target's baseline), and each
        // `[f32; 4]` field of `Leaf` (16-byte aligned, `repr(C)`, every field 16 bytes) is
        // 16-byte aligned, as `_mm_load_ps` requires.
        unsafe {
            let (nx, ny, nz) = (
                _mm_load_ps(self.nx.as_ptr()),
                _mm_load_ps(self.ny.as_ptr()),
                _mm_load_ps(self.nz.as_ptr()),
            );
            let c = _mm_add_ps(
                _mm_add_ps(
                    _mm_mul_ps(_mm_set1_ps(n[0]), nx),
                    _mm_mul_ps(_mm_set1_ps(n[1]), ny),
                ),
                _mm_mul_ps(_mm_set1_ps(n[2]), nz),
            );
            let inv = _mm_load_ps(self.inv_radius.as_ptr());
            let v0 = _mm_mul_ps(
                _mm_sub_ps(_mm_set1_ps(x[0]), _mm_load_ps(self.px.as_ptr())),
                inv,
            );
            let v1 = _mm_mul_ps(
                _mm_sub_ps(_mm_set1_ps(x[1]), _mm_load_ps(self.py.as_ptr())),
                inv,
            );
            let v2 = _mm_mul_ps(
                _mm_sub_ps(_mm_set1_ps(x[2]), _mm_load_ps(self.pz.as_ptr())),
                inv,
            );
            let vn = _mm_add_ps(
                _mm_add_ps(_mm_mul_ps(v0, nx), _mm_mul_ps(v1, ny)),
                _mm_mul_ps(v2, nz),
            );
            let vv = _mm_add_ps(
                _mm_add_ps(_mm_mul_ps(v0, v0), _mm_mul_ps(v1, v1)),
                _mm_mul_ps(v2, v2),
            );
            let q = _mm_add_ps(vv, _mm_mul_ps(_mm_mul_ps(_mm_set1_ps(SQUASH), vn), vn));
            let zero = _mm_setzero_ps();
            let one = _mm_set1_ps(1.0);
            let inside = _mm_and_ps(_mm_cmpgt_ps(c, zero), _mm_cmplt_ps(q, one));
            let r = _mm_sqrt_ps(q);
            let k = _mm_add_ps(
                _mm_mul_ps(
                    _mm_mul_ps(
                        _mm_sub_ps(_mm_mul_ps(_mm_set1_ps(2.0), r), _mm_set1_ps(3.0)),
                        r,
                    ),
                    r,
                ),
                one,
            );
            let w = _mm_and_ps(inside, _mm_mul_ps(_mm_mul_ps(k, c), c));
            let positive = _mm_movemask_ps(_mm_cmpgt_ps(w, zero)) as u32;
            // `__m128` and `[f32; 4]` are the same 16 bytes, lane `k` at float `k`.
            (std::mem::transmute::<__m128, [f32; 4]>(w), positive)
        }
    }
}

/// The list of one cell (see [`SenderCells::cell_at`]).
#[derive(Clone, Copy)]
pub struct CellList<'c> {
    list: &'c [u64],
    levels: usize,
}

impl<'a> SenderCells<'a> {
    /// An empty grid (no lists built yet) over the leaves of levels `0..levels` of `ib`.
    pub fn new(ib: &'a IndexedBasis, levels: usize) -> SenderCells<'a> {
        let levels = levels.min(ib.levels());
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for t in &ib.trees[..levels] {
            if !t.is_empty() {
                for a in 0..3 {
                    lo[a] = lo[a].min(t.node_min[0][a]);
                    hi[a] = hi[a].max(t.node_max[0][a]);
                }
            }
        }
        let b = &ib.basis;
        if b.levels() == 0 {
            return SenderCells {
                ib,
                levels: 0,
                lo,
                hi,
                cell: 1.0,
                inv_cell: 1.0,
                pad: 0.0,
                max_abs: 0.0,
                dims: [1; 3],
                cells: Vec::new(),
                leaves: Vec::new(),
                leaf_of_node: Vec::new(),
            };
        }
        let finest = b.level_range(levels.max(1) - 1);
        let mean_r = if levels == 0 || finest.is_empty() {
            1.0
        } else {
            let s: f64 = b.radii[finest.clone()].iter().map(|&r| r as f64).sum();
            (s / finest.len() as f64) as f32
        };
        let extent: [f32; 3] = std::array::from_fn(|a| (hi[a] - lo[a]).max(0.0));
        let mut cell = (mean_r * CELL_PER_RADIUS).max(f32::MIN_POSITIVE);
        let dims_for = |cell: f32| -> [usize; 3] {
            std::array::from_fn(|a| ((extent[a] / cell).ceil() as usize).clamp(1, MAX_AXIS_CELLS))
        };
        let mut dims = dims_for(cell);
        while dims[0] * dims[1] * dims[2] > MAX_CELLS {
            cell *= 1.25;
            dims = dims_for(cell);
        }
        // Make the grid cover the extent when an axis hit the per-axis cap.
        for a in 0..3 {
            cell = cell.max(extent[a] / dims[a] as f32);
        }
        let max_abs = lo.iter().chain(&hi).fold(0.0f32, |m, &c| m.max(c.abs()));
        let pad = 0.01 * cell + 8.0 * f32::EPSILON * max_abs;
        let count = if lo[0] <= hi[0] {
            dims[0] * dims[1] * dims[2]
        } else {
            0
        };
        SenderCells {
            ib,
            levels,
            lo,
            hi,
            cell,
            inv_cell: 1.0 / cell,
            pad,
            max_abs,
            dims,
            cells: (0..count).map(|_| OnceLock::new()).collect(),
            leaves: ib.trees[..levels]
                .iter()
                .map(|t| {
                    (0..t.node_count())
                        .filter(|&node| t.node_count[node] > 0)
                        .map(|node| Leaf::new(b, t, node))
                        .collect()
                })
                .collect(),
            leaf_of_node: ib.trees[..levels]
                .iter()
                .map(|t| {
                    let mut next = 0u32;
                    (0..t.node_count())
                        .map(|node| {
                            let at = next;
                            next += u32::from(t.node_count[node] > 0);
                            at
                        })
                        .collect()
                })
                .collect(),
        }
    }

    /// The number of cells whose list has been built, and the entries they hold.
    pub fn built(&self) -> (usize, usize) {
        self.cells
            .iter()
            .filter_map(|c| c.get())
            .fold((0, 0), |(n, e), l| (n + 1, e + l.len()))
    }

    /// The list of the cell holding `x`; `None` outside every sender leaf (no level has
    /// support there) and for non-finite `x`.
    #[inline]
    pub fn cell_at(&self, x: [f32; 3]) -> Option<CellList<'_>> {
        let inside = (0..3).all(|a| x[a] >= self.lo[a] && x[a] <= self.hi[a]);
        if !inside || self.cells.is_empty() {
            return None;
        }
        let idx: [usize; 3] = std::array::from_fn(|a| {
            (((x[a] - self.lo[a]) * self.inv_cell) as usize).min(self.dims[a] - 1)
        });
        let c = (idx[2] * self.dims[1] + idx[1]) * self.dims[0] + idx[0];
        let list = self.cells[c].get_or_init(|| self.build_cell(idx));
        Some(CellList {
            list,
            levels: self.levels,
        })
    }

    /// Calls `f(j, w_j(x, n))` for every basis function of sender level `l` with a positive
    /// weight (Eq. 8) at `(x, n)`, `x` inside `cell`; returns the sum of those weights. The
    /// same calls in the same order, and the same sum, as [`IndexedBasis::for_each_weight`].
    #[inline]
    pub fn for_each_weight(
        &self,
        cell: CellList<'_>,
        l: usize,
        x: [f32; 3],
        n: [f32; 3],
        mut f: impl FnMut(usize, f32),
    ) -> f32 {
        let leaves = &self.leaves[l];
        let start = if l == 0 {
            cell.levels
        } else {
            cell.levels + cell.list[l - 1] as usize
        };
        let end = cell.levels + cell.list[l] as usize;
        let entries = &cell.list[start..end];
        let (sum, cut) = Self::entry_weights(leaves, entries, self.ib, x, n, true, &mut f);
        if sum == 0.0 && cut {
            // As `IndexedBasis::for_each_weight`: unclipped where the clip leaves nothing.
            return Self::entry_weights(leaves, entries, self.ib, x, n, false, &mut f).0;
        }
        sum
    }

    /// Calls `f(j, w_j)` for the items of the list `entries` with a positive weight at
    /// `(x, n)`, less those the clip cuts when `clipped`; returns their weights' sum and
    /// whether the clip cut any.
    #[inline(always)]
    fn entry_weights(
        leaves: &[Leaf],
        entries: &[u64],
        ib: &IndexedBasis,
        x: [f32; 3],
        n: [f32; 3],
        clipped: bool,
        f: &mut impl FnMut(usize, f32),
    ) -> (f32, bool) {
        let (mut sum, mut cut) = (0.0f32, false);
        for &entry in entries {
            let leaf = &leaves[(entry & 0xffff_ffff) as usize];
            let (w, positive) = leaf.weights(x, n);
            let mut mask = lanes(entry, WEIGH_BITS) & positive & leaf.contains_mask(x);
            let (test, always) = if clipped {
                (lanes(entry, TEST_BITS), lanes(entry, ALWAYS_BITS))
            } else {
                (0, 0)
            };
            while mask != 0 {
                let k = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                let j = leaf.j[k] as usize;
                let bit = 1 << k;
                if always & bit != 0 || (test & bit != 0 && ib.clip.cuts(j, x)) {
                    cut = true;
                    continue;
                }
                sum += w[k];
                f(j, w[k]);
            }
        }
        (sum, cut)
    }

    /// Calls `f(j, scale * B_j(y, n))` for every basis function of levels `0..levels` with a
    /// positive weight at `(y, n)`, each level's weights normalised over that level (Eq. 2):
    /// the expansion of a hit's value in the hierarchy. `buf` holds one level's weights
    /// between the two passes. Returns how many of the levels have no support at `y`.
    #[inline]
    pub fn for_each_basis_value(
        &self,
        levels: usize,
        y: [f32; 3],
        n: [f32; 3],
        scale: f32,
        buf: &mut Vec<(u32, f32)>,
        mut f: impl FnMut(u32, f32),
    ) -> u64 {
        let Some(cell) = self.cell_at(y) else {
            return levels as u64;
        };
        let mut unsupported = 0;
        for l in 0..levels {
            buf.clear();
            let sum = self.for_each_weight(cell, l, y, n, |j, w| buf.push((j as u32, w)));
            if sum > MIN_WEIGHT_SUM {
                let inv = scale / sum;
                for &(j, w) in buf.iter() {
                    f(j, w * inv);
                }
            } else {
                unsupported += 1;
            }
        }
        unsupported
    }

    fn build_cell(&self, idx: [usize; 3]) -> Box<[u64]> {
        let qlo: [f32; 3] =
            std::array::from_fn(|a| self.lo[a] + idx[a] as f32 * self.cell - self.pad);
        let qhi: [f32; 3] =
            std::array::from_fn(|a| self.lo[a] + (idx[a] + 1) as f32 * self.cell + self.pad);
        let mut out = vec![0u64; self.levels];
        let mut leaves = Vec::new();
        for l in 0..self.levels {
            let tree = &self.ib.trees[l];
            leaves.clear();
            leaves_overlapping(tree, qlo, qhi, &mut leaves);
            for &node in &leaves {
                let first = tree.node_first[node as usize] as usize;
                let count = tree.node_count[node as usize] as usize;
                let (mut mask, mut test, mut always) = (0u64, 0u64, 0u64);
                for (k, &j) in tree.items[first..first + count].iter().enumerate() {
                    if self.may_weigh(j as usize, qlo, qhi) {
                        mask |= 1 << k;
                        match self.clip_in_box(j as usize, qlo, qhi) {
                            ClipInBox::Never => {}
                            ClipInBox::Always => always |= 1 << k,
                            ClipInBox::Test => test |= 1 << k,
                        }
                    }
                }
                if mask != 0 {
                    out.push(
                        self.leaf_of_node[l][node as usize] as u64
                            | mask << WEIGH_BITS
                            | test << TEST_BITS
                            | always << ALWAYS_BITS,
                    );
                }
            }
            out[l] = (out.len() - self.levels) as u64;
        }
        out.into_boxed_slice()
    }

    /// Whether point `j`'s clip planes cut nothing in the box `[qlo, qhi]`, all of it, or
    /// some of it (to be tested per point). A plane's three linear functions take their
    /// extremes over the box at its corners; a margin over the rounding of their evaluation in
    /// f32 makes "nothing" and "all" exact for the points of the box, so that the lists give the
    /// same weights as [`IndexedBasis::for_each_weight`].
    fn clip_in_box(&self, j: usize, qlo: [f32; 3], qhi: [f32; 3]) -> ClipInBox {
        let planes = self.ib.clip.planes_of(j);
        if planes.is_empty() {
            return ClipInBox::Never;
        }
        let range = |f: &[f32; 4]| {
            let (mut lo, mut hi) = (f[3] as f64, f[3] as f64);
            let mut scale = (f[3] as f64).abs();
            for a in 0..3 {
                let (p, q) = (f[a] as f64 * qlo[a] as f64, f[a] as f64 * qhi[a] as f64);
                lo += p.min(q);
                hi += p.max(q);
                scale += p.abs().max(q.abs());
            }
            let margin = 16.0 * f32::EPSILON as f64 * (scale + self.max_abs as f64);
            (lo - margin, hi + margin)
        };
        let mut never = true;
        for c in planes {
            let (p, e0, e1) = (range(&c.plane), range(&c.edge0), range(&c.edge1));
            if p.1 < 0.0 && e0.0 >= 0.0 && e1.0 >= 0.0 {
                return ClipInBox::Always;
            }
            never &= p.0 >= 0.0 || e0.1 < 0.0 || e1.1 < 0.0;
        }
        if never {
            ClipInBox::Never
        } else {
            ClipInBox::Test
        }
    }

    /// False only when the weight of point `j` (Eq. 8) is zero everywhere in the box
    /// `[qlo, qhi]`, as computed in f32: a lower bound of the squashed distance of Eq. 10 over
    /// the box, `|v|^2 + (2F + F^2) <v, n_j>^2` with `|v|` the distance to the box and
    /// `|<v, n_j>|` the least over it, exceeds the support radius by a margin that covers the
    /// rounding of the weight's evaluation (relative, and absolute in the coordinates).
    fn may_weigh(&self, j: usize, qlo: [f32; 3], qhi: [f32; 3]) -> bool {
        let b = &self.ib.basis;
        let (c, nj, r) = (b.positions[j], b.normals[j], b.radii[j] as f64);
        let mut dist2 = 0.0f64;
        let (mut vn_lo, mut vn_hi) = (0.0f64, 0.0f64);
        for a in 0..3 {
            let (lo, hi) = (qlo[a] as f64 - c[a] as f64, qhi[a] as f64 - c[a] as f64);
            let gap = (lo.max(0.0) + (-hi).max(0.0)).max(0.0);
            dist2 += gap * gap;
            let (p, q) = (lo * nj[a] as f64, hi * nj[a] as f64);
            vn_lo += p.min(q);
            vn_hi += p.max(q);
        }
        let vn_min = if vn_lo > 0.0 {
            vn_lo
        } else if vn_hi < 0.0 {
            -vn_hi
        } else {
            0.0
        };
        let squash = SQUASH as f64;
        let bound = (dist2 + squash * vn_min * vn_min).sqrt();
        let magnitude = c.iter().fold(self.max_abs, |m, &v| m.max(v.abs())) as f64;
        bound <= 1.01 * r + 16.0 * f32::EPSILON as f64 * magnitude
    }
}

/// Appends the leaves of `tree` whose boxes overlap `[qlo, qhi]`, in depth-first order (left
/// child first), pruning subtrees whose boxes do not overlap.
fn leaves_overlapping(tree: &RTree, qlo: [f32; 3], qhi: [f32; 3], out: &mut Vec<u32>) {
    if tree.is_empty() {
        return;
    }
    let mut stack = Vec::new();
    let mut node = 0usize;
    loop {
        let (lo, hi) = (tree.node_min[node], tree.node_max[node]);
        if (0..3).all(|a| lo[a] <= qhi[a] && hi[a] >= qlo[a]) {
            if tree.node_count[node] > 0 {
                out.push(node as u32);
            } else {
                stack.push(tree.node_first[node]);
                node += 1;
                continue;
            }
        }
        match stack.pop() {
            Some(next) => node = next as usize,
            None => return,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mlt_format::Basis;

    /// Three levels of points on two crossing planes and a sphere, with normals that vary,
    /// coarse to fine (4x the points per level), supports overlapping like a bake's.
    fn basis() -> IndexedBasis {
        let mut b = Basis::default();
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut rnd = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        b.level_offsets.push(0);
        for (l, count) in [40usize, 160, 640].into_iter().enumerate() {
            let r_disk = 1.5 / (1 << l) as f32;
            for k in 0..count {
                let (u, v) = (rnd() * 10.0 - 5.0, rnd() * 10.0 - 5.0);
                let (p, n) = match k % 3 {
                    0 => ([u, v, 0.0], [0.0, 0.0, 1.0]),
                    1 => ([u, 0.0, v], [0.0, 1.0, 0.0]),
                    _ => {
                        let d = glam::Vec3::new(u, v, rnd() - 0.5).normalize();
                        ((d * 3.0).to_array(), (-d).to_array())
                    }
                };
                b.positions.push(p);
                b.normals.push(n);
                b.radii.push(r_disk * (1.5 + rnd()));
            }
            b.level_offsets.push(b.positions.len() as u32);
            b.disk_radii.push(r_disk);
        }
        IndexedBasis::build(b).unwrap()
    }

    /// A fixed stream of uniform numbers in `[0, 1)` (a linear congruential generator).
    fn uniform(mut state: u32) -> impl FnMut() -> f32 {
        move || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 8) as f32 / (1u32 << 24) as f32
        }
    }

    #[test]
    fn cells_yield_the_rtree_senders_and_weights_in_its_order() {
        let ib = basis();
        let cells = SenderCells::new(&ib, 3);
        let mut rnd = uniform(99u32);
        let mut nonzero = 0usize;
        for q in 0..3000 {
            // Points on the planes and sphere (where hits are), and anywhere in space.
            let (u, v) = (rnd() * 12.0 - 6.0, rnd() * 12.0 - 6.0);
            let (x, n) = match q % 4 {
                0 => ([u, v, 0.0], [0.0, 0.0, 1.0]),
                1 => ([u, 0.0, v], [0.0, -1.0, 0.0]),
                2 => {
                    let d = glam::Vec3::new(u, v, 1.0).normalize();
                    ((d * 3.0).to_array(), (-d).to_array())
                }
                _ => {
                    let n = glam::Vec3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5).normalize();
                    ([u, v, rnd() * 8.0 - 4.0], n.to_array())
                }
            };
            let cell = cells.cell_at(x);
            for l in 0..3 {
                let mut want = Vec::new();
                let want_sum = ib.for_each_weight(l, x, n, |j, w| want.push((j, w.to_bits())));
                let mut got = Vec::new();
                let got_sum = match cell {
                    Some(c) => cells.for_each_weight(c, l, x, n, |j, w| got.push((j, w.to_bits()))),
                    None => 0.0,
                };
                assert_eq!(got, want, "query {q} level {l}");
                assert_eq!(got_sum.to_bits(), want_sum.to_bits(), "query {q} level {l}");
                nonzero += want.len();
            }
        }
        assert!(nonzero > 10_000, "{nonzero}");
        let (built, entries) = cells.built();
        assert!(built > 0 && entries > built * 3, "{built} {entries}");
        // Outside every support and for NaN: no cell.
        assert!(cells.cell_at([100.0, 0.0, 0.0]).is_none());
        assert!(cells.cell_at([f32::NAN, 0.0, 0.0]).is_none());
    }

    #[test]
    fn a_leaf_weighs_its_points_as_the_kernel_does_bit_for_bit() {
        // Every leaf of three levels against points near and inside the supports, on and off
        // the surfaces, with normals facing and turned away, and NaN: the side-by-side weights
        // are the scalar ones and `kernel::weight`'s, bit for bit, and the positive mask marks
        // exactly the positive ones.
        let ib = basis();
        let b = &ib.basis;
        let mut rnd = uniform(7u32);
        let mut positive_seen = 0usize;
        for tree in &ib.trees {
            for node in (0..tree.node_count()).filter(|&k| tree.node_count[k] > 0) {
                let leaf = Leaf::new(b, tree, node);
                let first = tree.node_first[node] as usize;
                let count = tree.node_count[node] as usize;
                for q in 0..40 {
                    let c = leaf.j[q % count] as usize;
                    let p = b.positions[c];
                    let r = b.radii[c];
                    let mut x: [f32; 3] =
                        std::array::from_fn(|a| p[a] + (rnd() - 0.5) * 2.0 * r * 1.1);
                    let mut n = glam::Vec3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5)
                        .normalize()
                        .to_array();
                    match q % 8 {
                        0 => n = b.normals[c],
                        1 => x = p,
                        2 => x[1] = f32::NAN,
                        3 => n[0] = f32::NAN,
                        _ => {}
                    }
                    let (got, positive) = leaf.weights(x, n);
                    let (scalar, scalar_positive) = leaf.weights_scalar(x, n);
                    assert_eq!(
                        got.map(f32::to_bits),
                        scalar.map(f32::to_bits),
                        "{node} {q}"
                    );
                    assert_eq!(positive, scalar_positive);
                    for (k, &g) in got.iter().enumerate() {
                        let want = if k < count {
                            let j = tree.items[first + k] as usize;
                            assert_eq!(leaf.j[k] as usize, j);
                            mlt_format::kernel::weight(
                                x,
                                n,
                                b.positions[j],
                                b.normals[j],
                                b.radii[j],
                            )
                        } else {
                            0.0
                        };
                        assert_eq!(g.to_bits(), want.to_bits(), "{node} {q} {k}");
                        assert_eq!(positive >> k & 1 == 1, want > 0.0);
                        positive_seen += usize::from(want > 0.0);
                    }
                }
            }
        }
        assert!(positive_seen > 1000, "{positive_seen}");
    }

    #[test]
    fn an_empty_basis_has_no_cells() {
        let b = Basis {
            level_offsets: vec![0],
            ..Basis::default()
        };
        let ib = IndexedBasis::build(b).unwrap();
        let cells = SenderCells::new(&ib, 0);
        assert!(cells.cell_at([0.0; 3]).is_none());
    }
}
