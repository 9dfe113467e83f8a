//! The rows a masked product computes: one flag per row, in storage order, and, derived from
//! them, one per block of [`BLOCK_ROWS`] rows, so that a block without a wanted row is
//! skipped whole (its table of columns is not even gathered).

use super::BLOCK_ROWS;

/// A set of rows of a product, by row and by block.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RowMask {
    rows: Vec<bool>,
    blocks: Vec<bool>,
    count: usize,
}

impl RowMask {
    /// The rows whose flag is set (`rows[r]` for row `r`).
    pub fn from_rows(rows: Vec<bool>) -> RowMask {
        let blocks = rows.chunks(BLOCK_ROWS).map(|b| b.contains(&true)).collect();
        let count = rows.iter().filter(|&&r| r).count();
        RowMask {
            rows,
            blocks,
            count,
        }
    }

    /// Every row of the blocks whose flag is set (`blocks[b]` for block `b`), of `rows` rows.
    /// Panics unless there is one flag per block.
    pub fn from_blocks(blocks: &[bool], rows: usize) -> RowMask {
        assert_eq!(
            blocks.len(),
            rows.div_ceil(BLOCK_ROWS),
            "one flag per block"
        );
        RowMask::from_rows((0..rows).map(|r| blocks[r / BLOCK_ROWS]).collect())
    }

    /// One flag per row.
    pub fn rows(&self) -> &[bool] {
        &self.rows
    }

    /// One flag per block: whether it holds a row of the set.
    pub fn blocks(&self) -> &[bool] {
        &self.blocks
    }

    /// Rows in the set.
    pub fn count(&self) -> usize {
        self.count
    }

    /// Rows of the blocks that hold a row of the set (what a product culled by whole blocks
    /// would compute).
    pub fn block_rows(&self) -> usize {
        self.blocks
            .iter()
            .enumerate()
            .filter(|(_, &b)| b)
            .map(|(b, _)| BLOCK_ROWS.min(self.rows.len() - b * BLOCK_ROWS))
            .sum()
    }

    /// The rows this set or `other` holds. Panics unless both have as many rows.
    pub fn union(&self, other: &RowMask) -> RowMask {
        self.zip_with(other, |a, b| a || b)
    }

    /// The rows this set holds and `other` does not. Panics unless both have as many rows.
    pub fn minus(&self, other: &RowMask) -> RowMask {
        self.zip_with(other, |a, b| a && !b)
    }

    /// The rows for which `f(in self, in other)` holds.
    fn zip_with(&self, other: &RowMask, f: impl Fn(bool, bool) -> bool) -> RowMask {
        assert_eq!(self.rows.len(), other.rows.len(), "masks of one product");
        RowMask::from_rows(
            self.rows
                .iter()
                .zip(&other.rows)
                .map(|(&a, &b)| f(a, b))
                .collect(),
        )
    }

    /// Whether `other` holds every row this one does.
    pub fn within(&self, other: &RowMask) -> bool {
        self.rows.len() == other.rows.len()
            && self.rows.iter().zip(&other.rows).all(|(&a, &b)| !a || b)
    }

    #[inline(always)]
    pub(super) fn row(&self, r: usize) -> bool {
        self.rows[r]
    }

    #[inline(always)]
    pub(super) fn block(&self, b: usize) -> bool {
        self.blocks[b]
    }

    /// Calls `f(start, end)` on each run of consecutive rows of the set within
    /// `first..first + len`.
    pub(super) fn runs(&self, first: usize, len: usize, mut f: impl FnMut(usize, usize)) {
        let mut r = first;
        let end = first + len;
        while r < end {
            if !self.rows[r] {
                r += 1;
                continue;
            }
            let start = r;
            while r < end && self.rows[r] {
                r += 1;
            }
            f(start, r);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_and_runs_follow_the_rows() {
        let n = 3 * BLOCK_ROWS + 5;
        let mut rows = vec![false; n];
        for r in [3, 4, 5, 9, 2 * BLOCK_ROWS + 1, n - 1] {
            rows[r] = true;
        }
        let m = RowMask::from_rows(rows);
        assert_eq!(m.blocks(), &[true, false, true, true]);
        assert_eq!(m.count(), 6);
        assert_eq!(m.block_rows(), 2 * BLOCK_ROWS + 5);
        let mut runs = Vec::new();
        m.runs(0, n, |a, b| runs.push((a, b)));
        assert_eq!(
            runs,
            [
                (3, 6),
                (9, 10),
                (2 * BLOCK_ROWS + 1, 2 * BLOCK_ROWS + 2),
                (n - 1, n)
            ]
        );
        runs.clear();
        m.runs(4, 6, |a, b| runs.push((a, b)));
        assert_eq!(runs, [(4, 6), (9, 10)]);
        let whole = RowMask::from_blocks(m.blocks(), n);
        assert!(m.within(&whole) && !whole.within(&m));
        assert_eq!(whole.count(), whole.block_rows());
        // Set algebra, row by row.
        let first = RowMask::from_blocks(&[true, false, false, false], n);
        let (both, rest) = (m.union(&first), m.minus(&first));
        assert_eq!(both.count(), BLOCK_ROWS + 2);
        assert_eq!(rest.count(), 2);
        assert_eq!(rest.blocks(), &[false, false, true, true]);
        assert!(m.within(&both) && first.within(&both) && rest.within(&m));
        assert_eq!(rest.union(&first), both);
        assert_eq!(m.minus(&m).count(), 0);
    }
}
