//! The direct-to-indirect operator `S` (sections 3.1-3.3) rearranged for the run time:
//! receiver-major, copied once from the file's sender-major half floats ([`ArchivedLinks`]),
//! so that `i = S e` is computed per receiver in parallel.
//!
//! - [`TransposedLinks`]: the receiver-major arrays before grouping, also what the viewer's GPU
//!   compute pass uploads;
//! - `weights`: the senders' weights of a product, rounded to and held as half floats;
//! - `slots`: a link's sender slot, 16 or 32 bits;
//! - `groups`: the nearly dense first rows, stored and summed eight at a time;
//! - `tasks`: the split of the rows into the products' parallel tasks;
//! - `kernels`: the row and group sums, scalar and with AVX2 and F16C.

mod groups;
mod kernels;
mod slots;
mod tasks;
#[cfg(test)]
mod tests;
mod transpose;
mod weights;

use mlt_format::links::{ArchivedLinks, LINK_DIM};

use groups::{Groups, GROUP, GROUP_FILL};
#[cfg(target_arch = "x86_64")]
use kernels::has_f16c_lanes;
use kernels::row_sum;
#[cfg(target_arch = "x86_64")]
pub(crate) use kernels::unpack;
use slots::Slots;
use tasks::task_starts;
pub use transpose::TransposedLinks;
use weights::{SenderWeights, Weights};

/// `S` receiver-major, copied once from the stored sender-major half floats (section 3.3's
/// `i = S e`, rearranged for the run time): each linked receiver gathers its senders' light,
/// so receivers are independent and computed in parallel with the same bits for any thread
/// count. The values stay half floats (20 bytes per link with a 16-bit sender slot, against 40
/// decoded): the product reads each link once per frame, and a half float's conversion to
/// `f32` is exact, so the products are those of decoded values. Each link also gathers its
/// sender's weights, which are held as half floats too (`Weights`) so that they stay in the
/// first-level cache: those gathers, not the links' memory traffic, bound the product. On
/// CPUs with AVX2 and F16C a link's values are converted, multiplied and summed eight and four
/// at a time (`row_sum_f16c`). The first rows, nearly dense (the coarsest receivers'), are held
/// and summed eight rows at a time instead (`Groups`), with the same bits.
///
/// [`apply`](Self::apply) is [`ArchivedLinks::apply`] into a zeroed `i` with each sender's
/// weights `e_s * scale_s` rounded to half-float precision (a relative change of at most
/// 2^-11 per weight, the precision of the links themselves; `Weights`, which says why): each
/// receiver sums the products `w_s * value` over the rounded weights in ascending sender
/// order, one product then one sum in `f32` per term, the bits of that sender-major product
/// over the same weights.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReceiverLinks {
    receivers: u32,
    /// Stored sender slots: global sender ids and scales.
    sender_ids: Vec<u32>,
    scales: Vec<f32>,
    /// Receivers with at least one link, ascending.
    receiver_ids: Vec<u32>,
    /// `receiver_ids.len() + 1` offsets of each row's links (those of the grouped rows
    /// included): the rows from `groups.rows` on hold theirs at `offsets[q] -
    /// offsets[groups.rows]` in `slots`/`values` (the grouped rows' links are in `groups`).
    offsets: Vec<u32>,
    /// The first rows, nearly dense, eight at a time ([`Groups`]).
    groups: Groups,
    /// Sender slot of each link of the other rows, ascending within a receiver.
    slots: Slots,
    /// The (unscaled) link values of the other rows, half-float bits.
    values: Vec<[u16; LINK_DIM]>,
    /// The first row of each parallel task of the products, ascending from 0, then the number
    /// of rows ([`task_starts`]).
    task_starts: Vec<u32>,
}

impl ReceiverLinks {
    /// Transposes validated links (call [`ArchivedLinks::validate`] first).
    pub fn build(links: &ArchivedLinks) -> ReceiverLinks {
        Self::build_where(links, |_, _| true)
    }

    /// [`ReceiverLinks::build`] keeping only the links `(sender, receiver)` for which `keep`
    /// holds (the stored sender slots without a kept link are left out).
    pub fn build_where(links: &ArchivedLinks, keep: impl Fn(u32, u32) -> bool) -> ReceiverLinks {
        Self::build_filled(links, keep, GROUP_FILL)
    }

    /// [`ReceiverLinks::build_where`] grouping the first rows while each group holds at least
    /// `fill` of its rows-times-senders ([`Groups`]; 0 groups every full group).
    fn build_filled(
        links: &ArchivedLinks,
        keep: impl Fn(u32, u32) -> bool,
        fill: f64,
    ) -> ReceiverLinks {
        let TransposedLinks {
            receivers,
            sender_ids,
            scales,
            receiver_ids,
            offsets,
            mut slots,
            mut values,
        } = TransposedLinks::build(links, keep);
        let groups = Groups::build(&offsets, &slots, &values, fill);
        // The grouped rows' links are held in `groups` only.
        let grouped = offsets[groups.rows] as usize;
        slots.drain(..grouped);
        values.drain(..grouped);
        slots.shrink_to_fit();
        values.shrink_to_fit();
        ReceiverLinks {
            receivers,
            sender_ids,
            scales,
            receiver_ids,
            task_starts: task_starts(&offsets, groups.rows),
            offsets,
            groups,
            slots: Slots::new(slots),
            values,
        }
    }

    /// Links held.
    pub fn link_count(&self) -> usize {
        self.offsets.last().map_or(0, |&n| n as usize)
    }

    /// Links of the rows summed eight at a time (the nearly dense first rows, stored over
    /// their groups' senders with zeros where a row lacks a link).
    pub fn grouped_links(&self) -> usize {
        self.offsets
            .get(self.groups.rows)
            .map_or(0, |&n| n as usize)
    }

    /// Heap bytes held.
    pub fn bytes(&self) -> usize {
        4 * (self.sender_ids.len()
            + self.scales.len()
            + self.receiver_ids.len()
            + self.offsets.len()
            + self.task_starts.len())
            + self.slots.bytes()
            + 2 * LINK_DIM * self.values.len()
            + self.groups.bytes()
    }

    /// Receivers with at least one link, ascending (the only ones `S e` can light).
    pub fn receiver_ids(&self) -> &[u32] {
        &self.receiver_ids
    }

    /// `i = S e`: as [`ArchivedLinks::apply`] into a zeroed `i` (same skipping of senders whose
    /// largest channel is at most `threshold`) over the rounded sender weights (see
    /// [`ReceiverLinks`]), but `i` is overwritten, receivers without links included. Returns
    /// the number of senders used.
    ///
    /// Panics unless `e.len() >= 3 * senders` and `i.len() == 9 * receivers`.
    pub fn apply(&self, e: &[f32], threshold: f32, i: &mut [f32]) -> usize {
        self.apply_impl::<false>(e, None, 0, threshold, self.receivers as usize, i)
    }

    /// [`ReceiverLinks::apply`] with the rows of the first `m` receivers (points `0..m`)
    /// applied to `e_first` instead of `e`, in the same pass over the links: the level-0 rows
    /// get `S_0 e_first`, the others `S e`. Each row's bits are those of `apply` on the
    /// vector it gets. Returns the number of senders of `e` used.
    pub fn apply_split(
        &self,
        e: &[f32],
        e_first: &[f32],
        m: usize,
        threshold: f32,
        i: &mut [f32],
    ) -> usize {
        self.apply_impl::<false>(
            e,
            Some((e_first, m)),
            0,
            threshold,
            self.receivers as usize,
            i,
        )
    }

    /// [`ReceiverLinks::apply`] on the rows of the first `m` receivers only (points `0..m`,
    /// whose rows come first): `i` holds `9 m` floats and is overwritten; the same bits as
    /// those rows of [`ReceiverLinks::apply`]. Panics unless `i.len() == 9 m` and `m` is at
    /// most the number of receivers.
    pub fn apply_first(&self, e: &[f32], threshold: f32, m: usize, i: &mut [f32]) -> usize {
        assert!(m <= self.receivers as usize);
        self.apply_impl::<false>(e, None, 0, threshold, m, i)
    }

    /// `i += S e` over the receivers with links (the others are left as they are), each
    /// receiver's sum formed first, in ascending sender order, then added: the same bits as
    /// [`ReceiverLinks::apply`] into a zeroed vector, added to `i`. `e` needs entries only
    /// for the senders held. Returns the number of senders used.
    pub fn apply_add(&self, e: &[f32], threshold: f32, i: &mut [f32]) -> usize {
        self.apply_impl::<true>(e, None, 0, threshold, self.receivers as usize, i)
    }

    /// [`ReceiverLinks::apply_add`] over the rows of receivers `m` and above only (points
    /// `m..`; the rows of points `0..m` are neither computed nor written): each of those rows'
    /// bits are `apply_add`'s. Panics unless `i` holds 9 floats per receiver.
    pub fn apply_add_from(&self, e: &[f32], threshold: f32, m: usize, i: &mut [f32]) -> usize {
        self.apply_impl::<true>(e, None, m, threshold, self.receivers as usize, i)
    }

    /// `i (+)= S e` over the rows of the receivers `skip..n`; with `first = (e_first, m)` the
    /// rows of receivers `0..m` use `e_first` instead.
    fn apply_impl<const ADD: bool>(
        &self,
        e: &[f32],
        first: Option<(&[f32], usize)>,
        skip: usize,
        threshold: f32,
        n: usize,
        i: &mut [f32],
    ) -> usize {
        use rayon::prelude::*;
        assert_eq!(i.len(), n * LINK_DIM);
        let mut used = 0;
        let w = self.sender_weights(e, threshold, &mut used);
        let (w_first, m) = match first {
            Some((e_first, m)) => (Some(self.sender_weights(e_first, threshold, &mut 0)), m),
            None => (None, 0),
        };
        let w_first = w_first.as_ref().unwrap_or(&w);
        // Chunks of receivers own disjoint, consecutive ranges of `i` (receivers ascend): from
        // their first receiver to the next chunk's first, the first chunk from point 0.
        let rows = self.receiver_ids.partition_point(|&r| (r as usize) < n);
        let (parts, rest) = self.split_chunks(rows, n, i);
        if !ADD {
            rest.fill(0.0);
        }
        #[cfg(target_arch = "x86_64")]
        let f16c = has_f16c_lanes();
        parts.into_par_iter().for_each(|(c, first, out)| {
            #[cfg(target_arch = "x86_64")]
            if f16c {
                // SAFETY: this CPU has AVX2 and F16C (checked above), the only requirement for
                // calling a function compiled with them.
                unsafe { self.chunk_f16c::<ADD>((&w, w_first, m, skip), c, rows, first, out) };
                return;
            }
            self.chunk::<ADD, false>((&w, w_first, m, skip), c, rows, first, out);
        });
        used
    }

    /// Each stored sender's scaled light per channel, `e_s * scale_s` (which multiplies the
    /// three elements of a link's channel, as in `ArchivedLinks::apply`), rounded ([`Weights`]); zero
    /// for senders at most `threshold` in every channel, the others counted in `used`.
    fn sender_weights(&self, e: &[f32], threshold: f32, used: &mut usize) -> Weights {
        let w: Vec<[f32; 3]> = self
            .sender_ids
            .iter()
            .zip(&self.scales)
            .map(|(&s, &scale)| {
                let s = s as usize;
                let es = [e[3 * s], e[3 * s + 1], e[3 * s + 2]];
                if es.iter().all(|x| x.abs() <= threshold) {
                    [0.0; 3]
                } else {
                    *used += 1;
                    es.map(|x| x * scale)
                }
            })
            .collect();
        Weights::new(&w)
    }

    /// [`ReceiverLinks::chunk`] compiled with AVX2 and F16C ([`row_sum_f16c`](kernels::row_sum_f16c): no fused
    /// multiply-adds, so the same bits).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,f16c")]
    fn chunk_f16c<const ADD: bool>(
        &self,
        w: SenderWeights<'_>,
        c: usize,
        rows: usize,
        first: usize,
        out: &mut [f32],
    ) {
        self.chunk::<ADD, true>(w, c, rows, first, out);
    }

    /// The receivers of chunk `c` (of the first `rows` linked receivers) into `out` (added
    /// to it with `ADD`), which starts at point `first`; receivers below `w.2` use the
    /// weights `w.1`, the others `w.0`; receivers below `w.3` are skipped.
    /// With `F16C` each row is summed by [`row_sum_f16c`](kernels::row_sum_f16c), which the caller must have checked
    /// the CPU for (only [`ReceiverLinks::chunk_f16c`] sets it).
    #[inline(always)]
    fn chunk<const ADD: bool, const F16C: bool>(
        &self,
        (w_rest, w_first, m, skip): SenderWeights<'_>,
        c: usize,
        rows: usize,
        first: usize,
        out: &mut [f32],
    ) {
        let receivers = &self.receiver_ids;
        if !ADD {
            out.fill(0.0);
        }
        // A row's sum over the weights `w` (over their scale) to its place, times the scale.
        let write = |out: &mut [f32], r: usize, acc: &[f32; LINK_DIM], w: &Weights| {
            let o = &mut out[r * LINK_DIM..(r + 1) * LINK_DIM];
            for d in 0..LINK_DIM {
                if ADD {
                    o[d] += acc[d] * w.scale;
                } else {
                    o[d] = acc[d] * w.scale;
                }
            }
        };
        let qs = self.task_rows(c, rows);
        let mut q = qs.start;
        // The grouped rows: a task starts at a group's first row, and may end inside one only
        // at `rows`. A group whose rows take both weight vectors is summed over each.
        while q < qs.end.min(self.groups.rows) {
            let group = q..(q + GROUP).min(qs.end);
            let points = || group.clone().map(|q| receivers[q] as usize);
            for (w, first_rows) in [(w_first, true), (w_rest, false)] {
                let takes = |p: usize| p >= skip && (p < m) == first_rows;
                if !points().any(takes) {
                    continue;
                }
                let sums = self.groups.sums::<F16C>(q / GROUP, w);
                for (j, point) in points().enumerate() {
                    if takes(point) {
                        write(out, point - first, &sums[j], w);
                    }
                }
            }
            q += GROUP;
        }
        for (q, &point) in receivers.iter().enumerate().take(qs.end).skip(q) {
            let point = point as usize;
            if point < skip {
                continue;
            }
            let w = if point < m { w_first } else { w_rest };
            let acc = self.row_sum::<F16C>(self.links_of(q), w);
            write(out, point - first, &acc, w);
        }
    }

    /// Where the links of row `q` (from the grouped rows on) are in `slots`/`values`.
    #[inline(always)]
    fn links_of(&self, q: usize) -> std::ops::Range<usize> {
        let base = self.grouped_links();
        self.offsets[q] as usize - base..self.offsets[q + 1] as usize - base
    }

    /// [`row_sum`] of links `k` (a row's), whatever the width of their slots.
    #[inline(always)]
    fn row_sum<const F16C: bool>(&self, k: std::ops::Range<usize>, w: &Weights) -> [f32; LINK_DIM] {
        let values = &self.values[k.clone()];
        match &self.slots {
            Slots::Narrow(s) => row_sum::<F16C, u16>(&s[k], values, w),
            Slots::Wide(s) => row_sum::<F16C, u32>(&s[k], values, w),
        }
    }
}
