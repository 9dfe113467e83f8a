//! The direct-to-indirect operator `S` (sections 3.1-3.3) rearranged for the run time:
//! receiver-major, copied once from the file's sender-major half floats ([`ArchivedLinks`]),
//! so that `i = S e` is computed per receiver in parallel.

use half::f16;
use mlt_format::links::{ArchivedLinks, LINK_DIM};

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

/// The sender slot of each link: 16 bits where every stored sender slot fits in them (2 of a
/// link's 20 bytes instead of 4 of 22: the products are bound by reading the links), else 32.
#[derive(Clone, Debug, PartialEq)]
enum Slots {
    Narrow(Vec<u16>),
    Wide(Vec<u32>),
}

impl Default for Slots {
    fn default() -> Slots {
        Slots::Narrow(Vec::new())
    }
}

impl Slots {
    /// `slots` in 16 bits each where all fit, else as they are.
    fn new(slots: Vec<u32>) -> Slots {
        match slots.iter().map(|&s| u16::try_from(s)).collect() {
            Ok(narrow) => Slots::Narrow(narrow),
            Err(_) => Slots::Wide(slots),
        }
    }

    /// Bytes per slot.
    fn width(&self) -> usize {
        match self {
            Slots::Narrow(_) => 2,
            Slots::Wide(_) => 4,
        }
    }

    /// Heap bytes held.
    fn bytes(&self) -> usize {
        let len = match self {
            Slots::Narrow(s) => s.len(),
            Slots::Wide(s) => s.len(),
        };
        self.width() * len
    }
}

/// A sender slot as stored ([`Slots`]).
trait Slot: Copy {
    fn index(self) -> usize;
}

impl Slot for u16 {
    #[inline(always)]
    fn index(self) -> usize {
        self as usize
    }
}

impl Slot for u32 {
    #[inline(always)]
    fn index(self) -> usize {
        self as usize
    }
}

/// Rows summed [`GROUP`] at a time.
const GROUP: usize = 8;

/// The least share of a group's rows-times-senders that must hold links for its rows to be
/// grouped ([`Groups`]).
const GROUP_FILL: f64 = 0.75;

/// The first linked receivers' rows, [`GROUP`] consecutive rows at a time, stored over the
/// union of their senders with a zero wherever a row lacks the link. The coarsest receivers'
/// rows are nearly dense (every traced bounce reaches them from almost every sender: 99.5 %
/// of the senders on textured Sponza, 88 % of the Cornell box's links and 35 % of Sponza's
/// are in them), and a row read link by link costs a slot, two conversions and two weight
/// loads per link; a group reads one slot and one sender's weights for eight rows, and each
/// conversion and product covers the eight rows at once (about 5 instructions a link instead
/// of 14). Each row still sums its products in ascending sender order, one product then one
/// sum in `f32` per term, so its bits are the row format's: a missing link adds `w * 0 = ±0`,
/// which leaves any sum the same (a sum started at `+0` is never `-0`), for finite weights.
/// Groups are formed from the first row on while each holds at least [`GROUP_FILL`] of its
/// rows-times-senders; the rows after the first group that does not are kept row by row.
#[derive(Clone, Debug, Default, PartialEq)]
struct Groups {
    /// Rows grouped: the first `rows` linked receivers, a multiple of [`GROUP`].
    rows: usize,
    /// `rows / GROUP + 1` offsets into `slots`/`values`.
    offsets: Vec<u32>,
    /// Each group's senders (slots), ascending.
    slots: Slots,
    /// Per group sender, the nine values of each of the eight rows: element `d` of row `j`
    /// at `d * GROUP + j` (half-float bits, 0 where the row has no link).
    values: Vec<[u16; GROUP * LINK_DIM]>,
}

impl Groups {
    /// Groups the first rows of the row-format links (`offsets`, `slots`, `values` of every
    /// row), as many full groups from the first row on as hold at least `fill` of their
    /// rows-times-senders.
    fn build(offsets: &[u32], slots: &[u32], values: &[[u16; LINK_DIM]], fill: f64) -> Groups {
        let rows = offsets.len().saturating_sub(1);
        let mut groups = Groups {
            offsets: vec![0],
            ..Groups::default()
        };
        let (mut g_slots, mut g_values) = (Vec::new(), Vec::new());
        while groups.rows + GROUP <= rows {
            let q0 = groups.rows;
            let (a, b) = (offsets[q0] as usize, offsets[q0 + GROUP] as usize);
            let mut union: Vec<u32> = slots[a..b].to_vec();
            union.sort_unstable();
            union.dedup();
            if ((b - a) as f64) < fill * (GROUP * union.len()) as f64 {
                break;
            }
            let at = g_values.len();
            g_values.resize(at + union.len(), [0u16; GROUP * LINK_DIM]);
            for j in 0..GROUP {
                let q = q0 + j;
                let mut u = 0;
                for k in offsets[q] as usize..offsets[q + 1] as usize {
                    // Both ascend: the row's senders are a subset of the union.
                    while union[u] != slots[k] {
                        u += 1;
                    }
                    for d in 0..LINK_DIM {
                        g_values[at + u][d * GROUP + j] = values[k][d];
                    }
                }
            }
            g_slots.extend_from_slice(&union);
            groups.offsets.push(g_slots.len() as u32);
            groups.rows += GROUP;
        }
        groups.slots = Slots::new(g_slots);
        groups.values = g_values;
        groups
    }

    /// Heap bytes held.
    fn bytes(&self) -> usize {
        4 * self.offsets.len() + self.slots.bytes() + 2 * GROUP * LINK_DIM * self.values.len()
    }

    /// The sums of group `g`'s eight rows over the weights `w[slot]`, each row's the
    /// bits of [`row_sum`] over its own links.
    #[inline(always)]
    fn sums<const F16C: bool>(&self, g: usize, w: &Weights) -> [[f32; LINK_DIM]; GROUP] {
        let k = self.offsets[g] as usize..self.offsets[g + 1] as usize;
        let values = &self.values[k.clone()];
        match &self.slots {
            Slots::Narrow(s) => group_sums::<F16C, u16>(&s[k], values, w),
            Slots::Wide(s) => group_sums::<F16C, u32>(&s[k], values, w),
        }
    }
}

/// The sender weights of a product: those of most rows, those of the rows of receivers
/// `0..m`, `m`, and the receivers below which rows are skipped (neither computed nor written).
type SenderWeights<'a> = (&'a Weights, &'a Weights, usize, usize);

/// The weights of a product's senders, by stored sender slot: per colour channel `e_s *
/// scale_s` (element `d` of a link is multiplied by channel `d / 3`), each rounded to
/// half-float precision (11 significant bits: a relative change of at most 2^-11, the
/// precision of the half-float links they multiply) and held as half floats: six bytes a
/// sender, so that the weights of a scene's senders stay in the first-level cache (textured
/// Sponza's 4,889 take 29 KB, against 176 KB as nine floats a sender), where each link's gather
/// of them finds them. Products and sums are `f32`, as before; each row's sum over the weights
/// divided by [`Weights::scale`] (a power of two that brings the largest into the half floats'
/// range) is multiplied by it at the end, which is exact, so a row's bits are those of its
/// sum over the rounded weights themselves, whatever the scale.
#[derive(Clone, Debug, PartialEq)]
struct Weights {
    /// The weights over `scale`, as `f32` (exactly the half floats): the portable sums' and
    /// the groups'.
    unscaled: Vec<[f32; 3]>,
    /// The same as half-float bits, three a sender, then three zeros that no slot names, so
    /// that the eight bytes from any sender's three are readable (the vector kernels load them
    /// as one four-float vector and leave its fourth float unused).
    half: Vec<u16>,
    /// The power of two each sum over `unscaled` is multiplied by.
    scale: f32,
}

impl Weights {
    /// The weights `w`, rounded (see [`Weights`]).
    fn new(w: &[[f32; 3]]) -> Weights {
        let scale = half_scale(w.as_flattened());
        let n = 3 * w.len();
        let mut half = vec![0u16; n + 3];
        let mut unscaled = vec![[0.0f32; 3]; w.len()];
        to_half(
            w.as_flattened(),
            1.0 / scale,
            &mut half[..n],
            unscaled.as_flattened_mut(),
        );
        Weights {
            unscaled,
            half,
            scale,
        }
    }

    /// Sender slot `s`'s weights (over the scale). Panics unless `s` names a sender.
    #[inline(always)]
    fn get(&self, s: usize) -> &[f32; 3] {
        &self.unscaled[s]
    }

    /// Sender slot `s`'s weights (over the scale) as four floats (the fourth is the next
    /// slot's, not to be used), with F16C. Panics unless `s` names a sender.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx,f16c")]
    #[inline]
    fn four(&self, s: usize) -> std::arch::x86_64::__m128 {
        use std::arch::x86_64::*;
        assert!(s < self.unscaled.len());
        // SAFETY: `s` names a sender (checked) and three zeros follow the senders' half
        // floats, so the 8 bytes from sender `s`'s first (6 of its own, 2 of the next) lie
        // within `self.half`; the pointer is derived from the whole slice's (an unaligned
        // load).
        unsafe { _mm_cvtph_ps(_mm_loadl_epi64(self.half.as_ptr().add(3 * s).cast())) }
    }
}

/// The power of two by which weights `w` are divided to be held as half floats: the largest
/// finite one in magnitude then lies in `[2^14, 2^15)`, below the half floats' largest
/// (65,504), so that each keeps its 11 significant bits down to `2^-24` of it (smaller ones
/// lose bits, as subnormal half floats, and below `2^-39` of it round to 0; `S e` skips
/// senders below `1e-4` of the brightest). 1 where none is finite and nonzero; never below the
/// smallest normal `f32`.
fn half_scale(w: &[f32]) -> f32 {
    let largest = w
        .iter()
        .filter(|x| x.is_finite())
        .fold(0.0f32, |m, x| m.max(x.abs()));
    if largest == 0.0 {
        return 1.0;
    }
    // `largest` lies in [2^k, 2^(k + 1)) (a subnormal counts as below 2^-126).
    let k = ((largest.to_bits() >> 23) as i32 - 127).max(-126);
    f32::from_bits((((k - 14).max(-126) + 127) as u32) << 23)
}

/// `half[k]` = `src[k] * inv` rounded to a half float (to nearest, ties to even), and
/// `widened[k]` its value as `f32` (exact). `inv` is a power of two, so `src[k] * inv` is the
/// exact quotient by its inverse. With F16C eight at a time (the same rounding).
fn to_half(src: &[f32], inv: f32, half: &mut [u16], widened: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if has_f16c_lanes() {
        // SAFETY: this CPU has AVX2 and F16C (checked), all `to_half_f16c` needs.
        unsafe { to_half_f16c(src, inv, half, widened) };
        return;
    }
    for ((&x, h), y) in src.iter().zip(half).zip(widened) {
        let v = f16::from_f32(x * inv);
        *h = v.to_bits();
        *y = v.to_f32();
    }
}

/// [`to_half`] with F16C.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,f16c")]
fn to_half_f16c(src: &[f32], inv: f32, half: &mut [u16], widened: &mut [f32]) {
    use std::arch::x86_64::*;
    let (s8, s_rest) = src.as_chunks::<8>();
    let (h8, h_rest) = half.as_chunks_mut::<8>();
    let (w8, w_rest) = widened.as_chunks_mut::<8>();
    for ((s, h), w) in s8.iter().zip(h8).zip(w8) {
        // SAFETY: `s` and `w` hold 8 `f32` (32 bytes), `h` 8 `u16` (16 bytes): unaligned
        // loads and stores within them.
        unsafe {
            let x = _mm256_mul_ps(_mm256_loadu_ps(s.as_ptr()), _mm256_set1_ps(inv));
            let bits = _mm256_cvtps_ph::<_MM_FROUND_TO_NEAREST_INT>(x);
            _mm_storeu_si128(h.as_mut_ptr().cast(), bits);
            _mm256_storeu_ps(w.as_mut_ptr(), _mm256_cvtph_ps(bits));
        }
    }
    for ((&x, h), y) in s_rest.iter().zip(h_rest).zip(w_rest) {
        let v = f16::from_f32(x * inv);
        *h = v.to_bits();
        *y = v.to_f32();
    }
}

/// `x` rounded as [`Weights`] rounds a weight of a product whose scale is `scale`.
#[cfg(test)]
fn rounded(x: f32, scale: f32) -> f32 {
    f16::from_f32(x / scale).to_f32() * scale
}

/// Most receivers per parallel task of the products ([`task_starts`]).
const RECEIVER_CHUNK: usize = 1024;

/// Links per parallel task of the products, at least ([`task_starts`]).
const CHUNK_LINKS: usize = 1 << 15;

/// The first row of each parallel task of the products over the rows of `offsets` (one more
/// than the rows), then the number of rows: a task ends after [`RECEIVER_CHUNK`] rows or once
/// it holds [`CHUNK_LINKS`] links, whichever comes first. The link count matters because the
/// rows are far from equal: the coarsest receivers' rows (the first, by index) hold most of
/// the links (nine tenths of the Cornell box's, a third of Sponza's), and tasks of a fixed
/// number of rows put them all in one task, which then takes most of the product's time
/// whatever the number of threads. Each row is summed alike in any task, so the split does
/// not change the result. Among the first `grouped` rows ([`Groups`]) a task starts only at
/// a group's first row, so it ends at the first group boundary past those limits.
fn task_starts(offsets: &[u32], grouped: usize) -> Vec<u32> {
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
        let receivers = links.receivers.to_native();
        let n = receivers as usize;
        // Per stored slot, its sender, scale and kept links `(receiver, index into values)`.
        let mut sender_ids = Vec::new();
        let mut scales = Vec::new();
        let mut kept: Vec<(u32, u32, usize)> = Vec::new(); // (receiver, new slot, link index)
        for slot in 0..links.sender_ids.len() {
            let s = links.sender_ids[slot].to_native();
            let (a, b) = (
                links.offsets[slot].to_native() as usize,
                links.offsets[slot + 1].to_native() as usize,
            );
            let new_slot = sender_ids.len() as u32;
            let before = kept.len();
            for k in a..b {
                let r = links.receiver_ids[k].to_native();
                if keep(s, r) {
                    kept.push((r, new_slot, k));
                }
            }
            if kept.len() > before {
                sender_ids.push(s);
                scales.push(links.scales[slot].to_native());
            }
        }
        let mut count = vec![0u32; n + 1];
        for &(r, _, _) in &kept {
            count[r as usize + 1] += 1;
        }
        let receiver_ids: Vec<u32> = (0..n)
            .filter(|&r| count[r + 1] > 0)
            .map(|r| r as u32)
            .collect();
        // Offsets per receiver (all of them) for the fill, then compacted.
        for r in 0..n {
            count[r + 1] += count[r];
        }
        let total = kept.len();
        let mut cursor = count.clone();
        let mut slots = vec![0u32; total];
        let mut values = vec![[0u16; LINK_DIM]; total];
        // `kept` is in slot order, so each receiver's links stay in ascending sender order.
        for &(r, slot, k) in &kept {
            let at = cursor[r as usize] as usize;
            cursor[r as usize] += 1;
            slots[at] = slot;
            let v = &links.values[k * LINK_DIM..(k + 1) * LINK_DIM];
            values[at] = std::array::from_fn(|d| v[d].to_native());
        }
        let mut offsets: Vec<u32> = receiver_ids.iter().map(|&r| count[r as usize]).collect();
        offsets.push(total as u32);
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

    /// The number of parallel tasks over the first `rows` rows.
    fn tasks(&self, rows: usize) -> usize {
        self.task_starts.split_last().map_or(0, |(_, starts)| {
            starts.partition_point(|&q| (q as usize) < rows)
        })
    }

    /// The rows of task `c` of those over the first `rows` rows.
    fn task_rows(&self, c: usize, rows: usize) -> std::ops::Range<usize> {
        self.task_starts[c] as usize..(self.task_starts[c + 1] as usize).min(rows)
    }

    /// Splits `buf` (9 floats per point of `0..n`) into the ranges of the parallel tasks over
    /// the first `rows` linked receivers: chunk `c` owns the points from its first receiver to
    /// the next chunk's first (the first chunk from point 0, the last to `n`), as `(c, first
    /// point, values)`; the points past the last chunk's range (none are linked) are returned.
    #[allow(clippy::type_complexity)]
    fn split_chunks<'b>(
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

    /// [`ReceiverLinks::chunk`] compiled with AVX2 and F16C ([`row_sum_f16c`]: no fused
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
    /// With `F16C` each row is summed by [`row_sum_f16c`], which the caller must have checked
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

/// One row's sum `sum_k w[slot_k] * value_k`, element by element in link order, each term a
/// product then a sum in `f32` (no fused multiply-add). With `F16C` (set only in code compiled
/// for and run on CPUs with AVX2 and F16C) by [`row_sum_f16c`], else by the scalar loop: the
/// same bits (the half floats' conversion is exact, and a vector lane's product and sum are
/// the scalar's).
#[inline(always)]
fn row_sum<const F16C: bool, S: Slot>(
    slots: &[S],
    values: &[[u16; LINK_DIM]],
    w: &Weights,
) -> [f32; LINK_DIM] {
    #[cfg(target_arch = "x86_64")]
    if F16C {
        // SAFETY: `F16C` is set only by `chunk_f16c`, which runs only on CPUs with AVX2 and
        // F16C (checked by its callers).
        return unsafe { row_sum_f16c(slots, values, w) };
    }
    let mut acc = [0.0f32; LINK_DIM];
    for (&slot, v) in slots.iter().zip(values) {
        let (ws, v) = (w.get(slot.index()), decode(v));
        for d in 0..LINK_DIM {
            acc[d] += ws[d / 3] * v[d];
        }
    }
    acc
}

/// The sums of a group's eight rows ([`Groups`]) over the weights `w`: per group sender (its
/// slot and its rows' values, element `d` of row `j` at `d * GROUP + j`), each row's element
/// gets one product then one sum in `f32`, in ascending sender order, as in [`row_sum`]. With
/// `F16C` (as in `row_sum`) by [`group_sums_f16c`]: the same bits.
#[inline(always)]
fn group_sums<const F16C: bool, S: Slot>(
    slots: &[S],
    values: &[[u16; GROUP * LINK_DIM]],
    w: &Weights,
) -> [[f32; LINK_DIM]; GROUP] {
    #[cfg(target_arch = "x86_64")]
    if F16C {
        // SAFETY: as in `row_sum`.
        return unsafe { group_sums_f16c(slots, values, w) };
    }
    let mut acc = [[0.0f32; LINK_DIM]; GROUP];
    for (&slot, v) in slots.iter().zip(values) {
        let ws = w.get(slot.index());
        for d in 0..LINK_DIM {
            for j in 0..GROUP {
                acc[j][d] += ws[d / 3] * f16::from_bits(v[d * GROUP + j]).to_f32();
            }
        }
    }
    acc
}

/// [`group_sums`] with AVX2 and F16C: element `d` of the eight rows converted, multiplied by
/// the sender's weight `d` and added at once (separate products and sums, as the scalar loop).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,f16c")]
#[inline]
fn group_sums_f16c<S: Slot>(
    slots: &[S],
    values: &[[u16; GROUP * LINK_DIM]],
    w: &Weights,
) -> [[f32; LINK_DIM]; GROUP] {
    use std::arch::x86_64::*;
    let mut acc = [_mm256_setzero_ps(); LINK_DIM];
    for (&slot, v) in slots.iter().zip(values) {
        let ws = w.get(slot.index());
        for (d, acc) in acc.iter_mut().enumerate() {
            // SAFETY: `v` holds 72 `u16`: the 16 bytes from element `8 d` (d < 9) are in
            // bounds (an unaligned load).
            let vd = unsafe { _mm_loadu_si128(v.as_ptr().add(d * GROUP).cast::<__m128i>()) };
            let prod = _mm256_mul_ps(_mm256_set1_ps(ws[d / 3]), _mm256_cvtph_ps(vd));
            *acc = _mm256_add_ps(*acc, prod);
        }
    }
    let mut by_element = [[0.0f32; GROUP]; LINK_DIM];
    for d in 0..LINK_DIM {
        // SAFETY: `by_element[d]` holds 8 `f32`, the 32 bytes stored (an unaligned store).
        unsafe { _mm256_storeu_ps(by_element[d].as_mut_ptr(), acc[d]) };
    }
    std::array::from_fn(|j| std::array::from_fn(|d| by_element[d][j]))
}

/// One link's values and sender `s`'s weights as vectors: elements 0-7 and elements 5-8 of
/// each (one instruction per load or conversion; [`unpack`] takes elements 5-8 from the
/// second). The weights are the sender's three channel weights spread to the elements they
/// multiply (`d / 3`) by one permute each.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,f16c")]
#[inline]
fn lanes(
    v: &[u16; LINK_DIM],
    w: &Weights,
    s: usize,
) -> (
    std::arch::x86_64::__m256,
    std::arch::x86_64::__m128,
    std::arch::x86_64::__m256,
    std::arch::x86_64::__m128,
) {
    use std::arch::x86_64::*;
    let q = w.four(s);
    // SAFETY: `v` holds 9 `u16`: the 16 bytes from `v[0]` and the 8 from `v[5]` are in
    // bounds (unaligned loads).
    let (v8, v9) = unsafe {
        let p = v.as_ptr();
        (
            _mm256_cvtph_ps(_mm_loadu_si128(p.cast::<__m128i>())),
            _mm_cvtph_ps(_mm_loadl_epi64(p.add(5).cast::<__m128i>())),
        )
    };
    (
        v8,
        v9,
        _mm256_permutevar8x32_ps(
            _mm256_castps128_ps256(q),
            _mm256_setr_epi32(0, 0, 0, 1, 1, 1, 2, 2),
        ),
        _mm_permutevar_ps(q, _mm_setr_epi32(1, 2, 2, 2)),
    )
}

/// Two accumulators of nine floats held as elements 0-7 and 5-8 (a row's, or a point's) as the
/// nine floats: elements 0-4 from the first, 5-8 from the second. (Elements 5-7 are in both;
/// taking them from the second keeps every lane of it in use, which keeps the compiler from
/// narrowing it to the ninth element alone, inserted into the low lane of a register it picks:
/// when that register holds an accumulator, each link's conversion waits for the previous
/// link's sum, and the product takes twice as long.)
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) fn unpack(
    acc8: std::arch::x86_64::__m256,
    acc4: std::arch::x86_64::__m128,
) -> [f32; LINK_DIM] {
    use std::arch::x86_64::*;
    let mut out = [0.0f32; LINK_DIM];
    // SAFETY: `out` holds 9 `f32`: the 32 bytes stored from its start and the 16 from its
    // sixth element are in bounds; the second store follows the first.
    unsafe {
        _mm256_storeu_ps(out.as_mut_ptr(), acc8);
        _mm_storeu_ps(out.as_mut_ptr().add(5), acc4);
    }
    out
}

/// [`row_sum`] with AVX2 and F16C: a link's values converted, multiplied and added eight (and
/// four) at a time ([`lanes`]; separate products and sums, so each element's bits are the
/// scalar loop's).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,f16c")]
#[inline]
fn row_sum_f16c<S: Slot>(slots: &[S], values: &[[u16; LINK_DIM]], w: &Weights) -> [f32; LINK_DIM] {
    use std::arch::x86_64::*;
    let (mut acc8, mut acc9) = (_mm256_setzero_ps(), _mm_setzero_ps());
    for (&slot, v) in slots.iter().zip(values) {
        let (v8, v9, w8, w9) = lanes(v, w, slot.index());
        acc8 = _mm256_add_ps(acc8, _mm256_mul_ps(w8, v8));
        acc9 = _mm_add_ps(acc9, _mm_mul_ps(w9, v9));
    }
    unpack(acc8, acc9)
}

/// Whether this CPU has AVX2 and F16C, which the products' `_f16c` kernels are compiled for.
#[cfg(target_arch = "x86_64")]
fn has_f16c_lanes() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("f16c")
}

/// A link's half-float values as `f32` (exact).
#[inline(always)]
fn decode(v: &[u16; LINK_DIM]) -> [f32; LINK_DIM] {
    std::array::from_fn(|d| f16::from_bits(v[d]).to_f32())
}

#[cfg(test)]
mod tests {
    use super::*;
    use mlt_format::links::{Links, SenderLinks};
    use rkyv::rancor;

    /// Six senders, twelve linked receivers of 14, mixed signs.
    fn sample_links() -> Links {
        let cols: Vec<Vec<(u32, [f32; 9])>> = (0..6u32)
            .map(|s| {
                (0..12u32)
                    .filter(|r| (r + s) % 3 != 0)
                    .map(|r| {
                        let v = std::array::from_fn(|d| {
                            ((s * 31 + r * 7 + d as u32) as f32 * 0.37).sin() * (1.0 + s as f32)
                        });
                        (r, v)
                    })
                    .collect()
            })
            .collect();
        let (l, _) = Links::pack(
            14,
            6,
            cols.iter().enumerate().map(|(s, c)| SenderLinks {
                sender: s as u32,
                links: c,
            }),
        );
        l
    }

    /// [`sample_links`] archived.
    fn sample_bytes() -> rkyv::util::AlignedVec {
        rkyv::to_bytes::<rancor::Error>(&sample_links()).unwrap()
    }

    /// The links of `bytes`, validated.
    fn validated(bytes: &[u8]) -> &ArchivedLinks {
        let a = rkyv::access::<ArchivedLinks, rancor::Error>(bytes).unwrap();
        a.validate().unwrap();
        a
    }

    /// RGB light for the six senders of [`sample_links`].
    fn sample_emission() -> Vec<f32> {
        (0..18).map(|k| 0.3 + (k as f32 * 1.3).cos()).collect()
    }

    /// The links of `a` as built (the sample's rows too sparse to group), and with every full
    /// group of rows grouped: the products must give the same bits from both.
    fn presets(a: &ArchivedLinks) -> [ReceiverLinks; 2] {
        let grouped = ReceiverLinks::build_filled(a, |_, _| true, 0.0);
        assert_eq!(
            grouped.groups.rows,
            GROUP * (grouped.receiver_ids.len() / GROUP)
        );
        [ReceiverLinks::build(a), grouped]
    }

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// `i += S e` sender-major, as [`ArchivedLinks::apply`] (each receiver's terms added in
    /// ascending sender order, senders at most `threshold` in every channel skipped), over the
    /// sender weights `e_s * scale_s` rounded as [`Weights`] rounds them; with `abs`, the sum
    /// of the terms' magnitudes instead. Returns the number of senders used.
    fn sender_major(
        a: &ArchivedLinks,
        e: &[f32],
        threshold: f32,
        abs: bool,
        i: &mut [f32],
    ) -> usize {
        let slots = a.sender_ids.len();
        let mut used = 0;
        let w: Vec<[f32; 3]> = (0..slots)
            .map(|slot| {
                let s = a.sender_ids[slot].to_native() as usize;
                let es = [e[3 * s], e[3 * s + 1], e[3 * s + 2]];
                if es.iter().all(|x| x.abs() <= threshold) {
                    [0.0; 3]
                } else {
                    used += 1;
                    es.map(|x| x * a.scales[slot].to_native())
                }
            })
            .collect();
        let scale = half_scale(w.as_flattened());
        for (slot, w) in w.iter().enumerate() {
            let w = w.map(|x| rounded(x, scale));
            for k in a.offsets[slot].to_native() as usize..a.offsets[slot + 1].to_native() as usize
            {
                let r = a.receiver_ids[k].to_native() as usize;
                for d in 0..LINK_DIM {
                    let v = f16::from_bits(a.values[k * LINK_DIM + d].to_native()).to_f32();
                    let term = w[d / 3] * v;
                    i[r * LINK_DIM + d] += if abs { term.abs() } else { term };
                }
            }
        }
        used
    }

    /// [`sender_major`] over the rounded weights, into a zeroed vector.
    fn rounded_apply(a: &ArchivedLinks, e: &[f32], threshold: f32, i: &mut [f32]) -> usize {
        sender_major(a, e, threshold, false, i)
    }

    #[test]
    fn receiver_major_gives_the_bits_of_the_sender_major_product_over_the_rounded_weights() {
        let bytes = sample_bytes();
        let a = validated(&bytes);
        let e = sample_emission();
        let mut e_dark = e.clone();
        e_dark[6..9].copy_from_slice(&[1e-3, -1e-3, 0.0]);
        let [plain, grouped] = presets(a);
        assert_eq!((plain.groups.rows, grouped.groups.rows), (0, 8));
        assert_eq!(plain.link_count(), grouped.link_count());
        for (rl, (e, threshold, senders)) in [&plain, &grouped]
            .into_iter()
            .flat_map(|rl| [(rl, (&e, 0.0, 6)), (rl, (&e_dark, 0.01, 5))])
        {
            assert_eq!(rl.receiver_ids(), (0..12).collect::<Vec<u32>>().as_slice());
            let mut want = vec![0.0f32; 14 * 9];
            assert_eq!(rounded_apply(a, e, threshold, &mut want), senders);
            let mut got = vec![f32::NAN; 14 * 9];
            assert_eq!(rl.apply(e, threshold, &mut got), senders);
            assert_eq!(bits(&got), bits(&want));
            assert!(got[12 * 9..].iter().all(|&x| x == 0.0));
            // Within the weights' rounding of the exact product: each term moves by at most
            // 2^-11 of itself.
            let mut exact = vec![0.0f32; 14 * 9];
            assert_eq!(a.apply(e, threshold, &mut exact), senders);
            let mut magnitude = vec![0.0f32; 14 * 9];
            sender_major(a, e, threshold, true, &mut magnitude);
            for k in 0..14 * 9 {
                let bound = magnitude[k] * (2f32.powi(-11) + 1e-5) + 1e-30;
                assert!(
                    (got[k] - exact[k]).abs() <= bound,
                    "{k}: {} {}",
                    got[k],
                    exact[k]
                );
            }
            assert!(got != exact, "the weights are rounded");
        }
    }

    #[test]
    fn weights_are_rounded_to_eleven_bits_whatever_their_scale() {
        // The largest finite weight lands in [2^14, 2^15) (infinities and NaNs aside).
        for largest in [1e-30f32, 3.0e-5, 1.0, 1.5, 2.0, 65504.0, 1e20, 3e38] {
            let s = half_scale(&[largest, -0.5 * largest, f32::INFINITY, f32::NAN]);
            assert_eq!(s.to_bits() & 0x007f_ffff, 0, "a power of two: {s}");
            let q = largest / s;
            assert!((16384.0..32768.0).contains(&q), "{largest}: {q}");
        }
        assert_eq!(half_scale(&[0.0, -0.0]), 1.0);
        assert_eq!(half_scale(&[]), 1.0);
        // Each weight moves by at most 2^-11 of itself down to 2^-24 of the largest, and the
        // same whatever the largest (the rounding does not depend on the scale).
        let w: Vec<f32> = (0..2000)
            .map(|k| (k as f32 * 0.77).sin() * 10f32.powf(-(k % 8) as f32))
            .collect();
        let (s1, s2) = (half_scale(&w), half_scale(&[w[0], 4.0]));
        for &x in w.iter().filter(|x| x.abs() >= 4.0 * 2f32.powi(-24)) {
            let r = rounded(x, s1);
            assert!((r - x).abs() <= x.abs() * 2f32.powi(-11), "{x} -> {r}");
            assert_eq!(r.to_bits(), rounded(x, s2).to_bits(), "{x}");
        }
        // `Weights` holds those, its half floats and their values agreeing, with three zeros
        // after the last sender; the vector conversion rounds as the scalar one (ties among
        // these: multiples of 2^-11 and odd multiples of 2^-12 near 1).
        let mut w3: Vec<[f32; 3]> = w.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        w3.push([
            1.0 + 2f32.powi(-11),
            1.0 + 3.0 * 2f32.powi(-11),
            -(1.0 + 2f32.powi(-11)),
        ]);
        let weights = Weights::new(&w3);
        assert_eq!(weights.scale, half_scale(w3.as_flattened()));
        assert_eq!(weights.half.len(), 3 * w3.len() + 3);
        assert!(weights.half[3 * w3.len()..].iter().all(|&h| h == 0));
        for (s, w) in w3.iter().enumerate() {
            for (c, &x) in w.iter().enumerate() {
                let h = weights.half[3 * s + c];
                assert_eq!(f16::from_bits(h).to_f32(), weights.get(s)[c]);
                assert_eq!(
                    h,
                    f16::from_f32(x / weights.scale).to_bits(),
                    "sender {s} channel {c}"
                );
                assert_eq!(
                    (weights.get(s)[c] * weights.scale).to_bits(),
                    rounded(x, weights.scale).to_bits()
                );
            }
        }
    }

    #[test]
    fn slots_take_16_bits_where_all_fit_and_the_products_keep_their_bits_either_way() {
        assert_eq!(
            Slots::new(vec![0, 7, 65535]),
            Slots::Narrow(vec![0, 7, 65535])
        );
        assert_eq!(Slots::new(vec![0, 65536]), Slots::Wide(vec![0, 65536]));
        let bytes = sample_bytes();
        let rl = ReceiverLinks::build(validated(&bytes));
        let Slots::Narrow(narrow) = &rl.slots else {
            panic!("six senders take 16-bit slots");
        };
        let wide = ReceiverLinks {
            slots: Slots::Wide(narrow.iter().map(|&s| s as u32).collect()),
            ..rl.clone()
        };
        assert_eq!(wide.bytes(), rl.bytes() + 2 * rl.link_count());
        let e = sample_emission();
        for links in [&rl, &wide] {
            let mut want = vec![0.0f32; 14 * 9];
            rounded_apply(validated(&bytes), &e, 0.0, &mut want);
            let mut got = vec![f32::NAN; 14 * 9];
            links.apply(&e, 0.0, &mut got);
            assert_eq!(bits(&got), bits(&want));
        }
    }

    #[test]
    fn the_f16c_row_sums_give_the_bits_of_the_scalar_ones() {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("f16c")
        {
            // Every half float but the NaNs (whose payloads the two conversions may treat
            // differently; validated links hold none), nine to a link, in each of the nine
            // places, three links to a row over seven senders' weights.
            let all: Vec<u16> = (0..=u16::MAX)
                .filter(|&h| !f16::from_bits(h).is_nan())
                .collect();
            let weights = |phase: f32| -> Weights {
                let w: Vec<[f32; 3]> = (0..7)
                    .map(|s| {
                        std::array::from_fn(|k| ((s * 3 + k) as f32 * 0.37 + phase).sin() * 3.0)
                    })
                    .collect();
                Weights::new(&w)
            };
            let w = weights(0.0);
            // Overflowing sums may give NaNs, whose payloads depend on operand order.
            let same = |a: [f32; LINK_DIM], b: [f32; LINK_DIM]| {
                a.iter()
                    .zip(&b)
                    .all(|(x, y)| x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()))
            };
            for shift in 0..LINK_DIM {
                let values: Vec<[u16; LINK_DIM]> = all[shift..]
                    .chunks_exact(LINK_DIM)
                    .map(|c| std::array::from_fn(|d| c[d]))
                    .collect();
                let slots: Vec<u16> = (0..values.len()).map(|k| (k * 5 % 7) as u16).collect();
                for k in (0..values.len() - 3).step_by(3) {
                    let (sl, vl) = (&slots[k..k + 3], &values[k..k + 3]);
                    // SAFETY: this CPU has AVX2 and F16C (checked above).
                    let fast = unsafe { row_sum_f16c(sl, vl, &w) };
                    assert!(same(fast, row_sum::<false, _>(sl, vl, &w)), "{fast:?}");
                }
            }
        }
    }

    #[test]
    fn a_group_gives_each_row_the_bits_of_its_own_links_summed_alone() {
        // Every finite half float (the infinite ones times a missing link's zero would give
        // NaNs; validated links hold none) spread over groups of 40 senders, about a third of
        // each row's links missing (zeros in the group), ±0 values among the present ones.
        let all: Vec<u16> = (0..=u16::MAX)
            .filter(|&h| f16::from_bits(h).is_finite())
            .collect();
        let w: Vec<[f32; 3]> = (0..40)
            .map(|s| std::array::from_fn(|k| ((s * 3 + k) as f32 * 0.61).cos() * 2.5))
            .collect();
        let w = Weights::new(&w);
        let present = |u: usize, j: usize| (u * 7 + j * 3) % 10 < 7;
        let slots: Vec<u16> = (0..40u16).collect();
        for chunk in all.chunks_exact(40 * GROUP * LINK_DIM) {
            let values: Vec<[u16; GROUP * LINK_DIM]> = chunk
                .chunks_exact(GROUP * LINK_DIM)
                .enumerate()
                .map(|(u, c)| std::array::from_fn(|k| if present(u, k % GROUP) { c[k] } else { 0 }))
                .collect();
            let slow = group_sums::<false, u16>(&slots, &values, &w);
            #[cfg(target_arch = "x86_64")]
            if has_f16c_lanes() {
                // SAFETY: this CPU has AVX2 and F16C (checked).
                let fast = unsafe { group_sums_f16c(&slots, &values, &w) };
                assert_eq!(
                    fast.map(|r| r.map(f32::to_bits)),
                    slow.map(|r| r.map(f32::to_bits))
                );
            }
            for (j, got) in slow.iter().enumerate() {
                let (row_slots, row_values): (Vec<u16>, Vec<[u16; LINK_DIM]>) = (0..40)
                    .filter(|&u| present(u, j))
                    .map(|u| (u as u16, std::array::from_fn(|d| values[u][d * GROUP + j])))
                    .unzip();
                let want = row_sum::<false, u16>(&row_slots, &row_values, &w);
                assert_eq!(got.map(f32::to_bits), want.map(f32::to_bits), "row {j}");
            }
        }
    }

    #[test]
    fn the_first_rows_alone_give_the_bits_of_the_full_product() {
        let bytes = sample_bytes();
        let a = validated(&bytes);
        let e = sample_emission();
        let mut full = vec![0.0f32; 14 * 9];
        ReceiverLinks::build(a).apply(&e, 0.0, &mut full);
        for (rl, m) in presets(a)
            .iter()
            .flat_map(|rl| [0, 1, 5, 12, 14].map(|m| (rl, m)))
        {
            let mut first = vec![f32::NAN; m * 9];
            assert_eq!(rl.apply_first(&e, 0.0, m, &mut first), 6);
            assert_eq!(bits(&first), bits(&full[..m * 9]), "first {m}");
        }
    }

    #[test]
    fn the_rows_from_m_on_are_added_with_the_bits_of_the_added_product_and_the_rest_untouched() {
        let bytes = sample_bytes();
        let a = validated(&bytes);
        let e = sample_emission();
        let start: Vec<f32> = (0..14 * 9).map(|k| (k as f32 * 0.37).cos()).collect();
        let mut all = start.clone();
        ReceiverLinks::build(a).apply_add(&e, 0.0, &mut all);
        for (rl, m) in presets(a)
            .iter()
            .flat_map(|rl| [0, 1, 5, 12, 14].map(|m| (rl, m)))
        {
            let mut got = start.clone();
            rl.apply_add_from(&e, 0.0, m, &mut got);
            assert_eq!(bits(&got[..m * 9]), bits(&start[..m * 9]), "below {m}");
            assert_eq!(bits(&got[m * 9..]), bits(&all[m * 9..]), "from {m}");
        }
    }

    #[test]
    fn tasks_split_the_heavy_rows_and_leave_every_row_its_bits() {
        // 3,000 senders reach the first 24 of 5,000 receivers (3,000 links each, as level 0's
        // rows do) and a few of the rest each (light rows); 76 receivers have no link.
        let (n, senders) = (5_000u32, 3_000u32);
        let cols: Vec<Vec<(u32, [f32; 9])>> = (0..senders)
            .map(|s| {
                (0..n)
                    .filter(|&r| r < 24 || (r >= 100 && (r * 7 + s) % 97 == 0))
                    .map(|r| {
                        let v = std::array::from_fn(|d| {
                            ((s * 13 + r * 5 + d as u32) as f32 * 0.11).sin()
                        });
                        (r, v)
                    })
                    .collect()
            })
            .collect();
        let (links, _) = Links::pack(
            n,
            senders,
            cols.iter().enumerate().map(|(s, c)| SenderLinks {
                sender: s as u32,
                links: c,
            }),
        );
        let bytes = rkyv::to_bytes::<rancor::Error>(&links).unwrap();
        let a = validated(&bytes);
        let e: Vec<f32> = (0..senders as usize * 3)
            .map(|k| 0.5 + (k as f32 * 0.37).cos())
            .collect();
        let mut want = vec![0.0f32; n as usize * 9];
        rounded_apply(a, &e, 0.0, &mut want);
        // Row by row, and with the dense heavy rows grouped (as built): three groups.
        let plain = ReceiverLinks::build_filled(a, |_, _| true, f64::INFINITY);
        for (rl, grouped, heavy_tasks) in [(plain, 0, 3), (ReceiverLinks::build(a), 24, 2)] {
            assert_eq!(rl.groups.rows, grouped);
            let rows = rl.receiver_ids.len();
            assert!(rows > 2 * RECEIVER_CHUNK, "{rows}");
            // The tasks cover the rows in order; each holds at most RECEIVER_CHUNK rows, and
            // fewer than CHUNK_LINKS links before its last row (its last group's first row
            // among the grouped rows, where tasks start only at a group's first row).
            let starts = &rl.task_starts;
            assert_eq!((starts[0], *starts.last().unwrap()), (0, rows as u32));
            assert!(starts.windows(2).all(|w| w[0] < w[1]));
            for w in starts.windows(2) {
                let (q0, q1) = (w[0] as usize, w[1] as usize);
                assert!(q0 >= grouped || q0 % GROUP == 0, "{q0}");
                let last = if q1 <= grouped { q1 - GROUP } else { q1 - 1 };
                assert!(q1 - q0 <= RECEIVER_CHUNK);
                assert!(((rl.offsets[last] - rl.offsets[q0]) as usize) < CHUNK_LINKS);
            }
            // The heavy rows (72,000 links) are spread over three tasks (eleven rows each),
            // or two when grouped (16 and 8 rows)...
            assert_eq!(rl.tasks(24), heavy_tasks);
            assert_eq!(rl.tasks(0), 0);
            assert_eq!(rl.tasks(rows), starts.len() - 1);
            // ...and every product gives the sender-major product's bits, for any thread count.
            for threads in [1, 2, 3] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let got = pool.install(|| {
                    let mut got = vec![f32::NAN; n as usize * 9];
                    rl.apply(&e, 0.0, &mut got);
                    got
                });
                assert_eq!(bits(&got), bits(&want), "{threads} threads");
            }
            // A split product over the same tasks: the rows below `m` (20: inside the last
            // group) on `e`, the others on `2 e`, which doubles their sums exactly.
            let e2: Vec<f32> = e.iter().map(|v| 2.0 * v).collect();
            for m in [20, 50] {
                let mut got = vec![f32::NAN; want.len()];
                rl.apply_split(&e2, &e, m, 0.0, &mut got);
                let mut expect = want.clone();
                expect[m * 9..].iter_mut().for_each(|v| *v *= 2.0);
                assert_eq!(bits(&got), bits(&expect), "m {m}");
            }
        }
    }

    #[test]
    fn a_split_product_gives_each_row_the_bits_of_the_product_of_its_vector() {
        let bytes = sample_bytes();
        let a = validated(&bytes);
        let rl = ReceiverLinks::build(a);
        let e = sample_emission();
        let mut e_first: Vec<f32> = (0..18).map(|k| -0.2 + (k as f32 * 0.7).sin()).collect();
        // A sender dark in `e_first` only: skipped there, used for the other rows.
        e_first[3..6].copy_from_slice(&[1e-3, 0.0, -1e-3]);
        let (mut plain, mut other) = (vec![0.0f32; 14 * 9], vec![0.0f32; 14 * 9]);
        rl.apply(&e, 0.01, &mut plain);
        rl.apply(&e_first, 0.01, &mut other);
        for (links, m) in presets(a)
            .iter()
            .flat_map(|rl| [0, 1, 5, 8, 12, 14].map(|m| (rl, m)))
        {
            let mut got = vec![f32::NAN; 14 * 9];
            assert_eq!(links.apply_split(&e, &e_first, m, 0.01, &mut got), 6);
            assert_eq!(bits(&got[..m * 9]), bits(&other[..m * 9]), "first {m}");
            assert_eq!(bits(&got[m * 9..]), bits(&plain[m * 9..]), "rest {m}");
        }
    }

    #[test]
    fn a_filtered_product_added_gives_the_bits_of_the_full_product_of_the_kept_links() {
        // Keep senders 0-2 and receivers from 4 on: the added product must equal the full
        // product of the same links (senders 3-5 dark, receivers below 4 not written) formed
        // on its own and then added, bit for bit.
        let bytes = sample_bytes();
        let a = validated(&bytes);
        let keep = |s: u32, r: u32| s < 3 && r >= 4;
        for rl in [
            ReceiverLinks::build_where(a, keep),
            ReceiverLinks::build_filled(a, keep, 0.0),
        ] {
            assert!(rl.receiver_ids().iter().all(|&r| r >= 4));
            assert_eq!(
                rl.link_count(),
                (0..3u32)
                    .map(|s| (4..12u32).filter(|r| (r + s) % 3 != 0).count())
                    .sum::<usize>()
            );
            let e = sample_emission();
            let mut dark = e.clone();
            dark[9..].fill(0.0);
            let mut product = vec![0.0f32; 14 * 9];
            rounded_apply(a, &dark, 0.0, &mut product);
            let start: Vec<f32> = (0..14 * 9).map(|k| (k as f32 * 0.71).sin()).collect();
            let mut want = start.clone();
            for (k, w) in want.iter_mut().enumerate().skip(4 * 9) {
                *w += product[k];
            }
            let mut got = start.clone();
            // Only the kept senders' entries are read.
            assert_eq!(rl.apply_add(&e[..9], 0.0, &mut got), 3);
            assert_eq!(bits(&got), bits(&want));
        }
    }
}
