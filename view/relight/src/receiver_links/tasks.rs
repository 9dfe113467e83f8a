//! The split of a product's rows into parallel tasks: each task ends after a number of rows or
//! of links, whichever comes first ([`task_starts`]), and owns a consecutive range of the
//! output.

use mlt_format::links::LINK_DIM;

use super::groups::GROUP;
use super::ReceiverLinks;

/// Most receivers per parallel task of the products ([`task_starts`]).
pub(super) const RECEIVER_CHUNK: usize = 1024;

/// Links per parallel task of the products, at least ([`task_starts`]).
pub(super) const CHUNK_LINKS: usize = 1 << 15;

/// The first row of each parallel task of the products over the rows of `offsets` (one more
/// than the rows), then the number of rows: a task ends after [`RECEIVER_CHUNK`] rows or once
/// it holds [`CHUNK_LINKS`] links, whichever comes first. The link count matters because the
/// rows are far from equal: the coarsest receivers' rows (the first, by index) hold most of
/// the links (nine tenths of the Cornell box's, a third of Sponza's), and tasks of a fixed
/// number of rows put them all in one task, which then takes most of the product's time
/// whatever the number of threads. Each row is summed alike in any task, so the split does
/// not change the result. Among the first `grouped` rows ([`Groups`](super::groups::Groups)) a task starts only at
/// a group's first row, so it ends at the first group boundary past those limits.
pub(super) fn task_starts(offsets: &[u32], grouped: usize) -> Vec<u32> {
    let rows = offsets.len().saturating_sub(1);
    let mut starts = vec![0u32];
    let mut at = 0usize;
    for q in 1..rows {
        if q < grouped && q % GROUP != 0 {
            continue;
        }
        if q - at >= RECEIVER_CHUNK || (offsets[q] - offsets[at]) as usize >= CHUNK_LINKS {
            starts.push(q as u32);
            at = q;
        }
    }
    starts.push(rows as u32);
    starts
}

impl ReceiverLinks {
    /// The number of parallel tasks over the first `rows` rows.
    pub(super) fn tasks(&self, rows: usize) -> usize {
        self.task_starts.split_last().map_or(0, |(_, starts)| {
            starts.partition_point(|&q| (q as usize) < rows)
        })
    }

    /// The rows of task `c` of those over the first `rows` rows.
    pub(super) fn task_rows(&self, c: usize, rows: usize) -> std::ops::Range<usize> {
        self.task_starts[c] as usize..(self.task_starts[c + 1] as usize).min(rows)
    }

    /// Splits `buf` (9 floats per point of `0..n`) into the ranges of the parallel tasks over
    /// the first `rows` linked receivers: chunk `c` owns the points from its first receiver to
    /// the next chunk's first (the first chunk from point 0, the last to `n`), as `(c, first
    /// point, values)`; the points past the last chunk's range (none are linked) are returned.
    #[allow(clippy::type_complexity)]
    pub(super) fn split_chunks<'b>(
        &self,
        rows: usize,
        n: usize,
        buf: &'b mut [f32],
    ) -> (Vec<(usize, usize, &'b mut [f32])>, &'b mut [f32]) {
        let receivers = &self.receiver_ids[..rows];
        let chunks = self.tasks(rows);
        let mut parts = Vec::with_capacity(chunks.max(1));
        let mut rest = buf;
        let mut at = 0usize;
        for c in 0..chunks {
            let end = if c + 1 < chunks {
                receivers[self.task_starts[c + 1] as usize] as usize
            } else {
                n
            };
            let (head, tail) = std::mem::take(&mut rest).split_at_mut((end - at) * LINK_DIM);
            parts.push((c, at, head));
            rest = tail;
            at = end;
        }
        (parts, rest)
    }
}
