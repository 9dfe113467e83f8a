//! The direct-to-indirect operator `S` (sections 3.1-3.3) rearranged for the run time:
//! receiver-major, copied once from the file's sender-major half floats ([`ArchivedLinks`]),
//! so that `i = S e` is computed per receiver in parallel.

use half::f16;
use mlt_format::links::{ArchivedLinks, LINK_DIM};

/// `S` receiver-major, copied once from the stored sender-major half floats (section 3.3's
/// `i = S e`, rearranged for the run time): each linked receiver gathers its senders' light,
/// so receivers are independent and computed in parallel with the same bits for any thread
/// count. The values stay half floats (22 bytes per link with the sender slot, against 40
/// decoded): the product reads each link once per frame and is bound by memory traffic, and a
/// half float's conversion to `f32` is exact, so the products are those of decoded values. On
/// CPUs with F16C eight of a link's nine values are converted in one instruction.
///
/// [`apply`](Self::apply) gives the same bits as [`ArchivedLinks::apply`] into a zeroed `i`:
/// each receiver sums the same products (`(e_s * scale_s) * value`) in ascending sender order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReceiverLinks {
    receivers: u32,
    /// Stored sender slots: global sender ids and scales.
    sender_ids: Vec<u32>,
    scales: Vec<f32>,
    /// Receivers with at least one link, ascending.
    receiver_ids: Vec<u32>,
    /// `receiver_ids.len() + 1` offsets into `slots`/`values`.
    offsets: Vec<u32>,
    /// Sender slot of each link, ascending within a receiver.
    slots: Vec<u32>,
    /// The (unscaled) link values, half-float bits.
    values: Vec<[u16; LINK_DIM]>,
}

/// The sender weights of a product: those of most rows, those of the rows of receivers
/// `0..m`, `m`, and the receivers below which rows are skipped (neither computed nor written).
type SenderWeights<'a> = (&'a [[f32; LINK_DIM]], &'a [[f32; LINK_DIM]], usize, usize);

/// Receivers per parallel task of [`ReceiverLinks::apply`].
const RECEIVER_CHUNK: usize = 1024;

impl ReceiverLinks {
    /// Transposes validated links (call [`ArchivedLinks::validate`] first).
    pub fn build(links: &ArchivedLinks) -> ReceiverLinks {
        Self::build_where(links, |_, _| true)
    }

    /// [`ReceiverLinks::build`] keeping only the links `(sender, receiver)` for which `keep`
    /// holds (the stored sender slots without a kept link are left out).
    pub fn build_where(links: &ArchivedLinks, keep: impl Fn(u32, u32) -> bool) -> ReceiverLinks {
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
        ReceiverLinks {
            receivers,
            sender_ids,
            scales,
            receiver_ids,
            offsets,
            slots,
            values,
        }
    }

    /// Links held.
    pub fn link_count(&self) -> usize {
        self.values.len()
    }

    /// Heap bytes held.
    pub fn bytes(&self) -> usize {
        4 * (self.sender_ids.len()
            + self.scales.len()
            + self.receiver_ids.len()
            + self.offsets.len()
            + self.slots.len())
            + 2 * LINK_DIM * self.values.len()
    }

    /// Receivers with at least one link, ascending (the only ones `S e` can light).
    pub fn receiver_ids(&self) -> &[u32] {
        &self.receiver_ids
    }

    /// `i = S e`: as [`ArchivedLinks::apply`] into a zeroed `i` (same skipping of senders whose
    /// largest channel is at most `threshold`, same result bits), but `i` is overwritten,
    /// receivers without links included. Returns the number of senders used.
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
    /// [`ArchivedLinks::apply`] into a zeroed vector, added to `i`. `e` needs entries only
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
        let w_first = w_first.as_deref().unwrap_or(&w);
        // Chunks of receivers own disjoint, consecutive ranges of `i` (receivers ascend): from
        // their first receiver to the next chunk's first, the first chunk from point 0.
        let rows = self.receiver_ids.partition_point(|&r| (r as usize) < n);
        let receivers = &self.receiver_ids[..rows];
        let chunks = receivers.len().div_ceil(RECEIVER_CHUNK);
        let mut parts = Vec::with_capacity(chunks.max(1));
        let mut rest = i;
        let mut at = 0usize;
        for c in 0..chunks {
            let end = if c + 1 < chunks {
                receivers[(c + 1) * RECEIVER_CHUNK] as usize
            } else {
                n
            };
            let (head, tail) = std::mem::take(&mut rest).split_at_mut((end - at) * LINK_DIM);
            parts.push((c, at, head));
            rest = tail;
            at = end;
        }
        if !ADD {
            rest.fill(0.0);
        }
        #[cfg(target_arch = "x86_64")]
        let f16c = std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("f16c");
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

    /// Each stored sender's scaled light, repeated per vector component, so that a link
    /// multiplies it element by element (the same products as `ArchivedLinks::apply`); zero
    /// for senders at most `threshold` in every channel, the others counted in `used`.
    fn sender_weights(&self, e: &[f32], threshold: f32, used: &mut usize) -> Vec<[f32; LINK_DIM]> {
        self.sender_ids
            .iter()
            .zip(&self.scales)
            .map(|(&s, &scale)| {
                let s = s as usize;
                let es = [e[3 * s], e[3 * s + 1], e[3 * s + 2]];
                if es.iter().all(|x| x.abs() <= threshold) {
                    [0.0; LINK_DIM]
                } else {
                    *used += 1;
                    std::array::from_fn(|k| es[k / 3] * scale)
                }
            })
            .collect()
    }

    /// [`ReceiverLinks::chunk`] compiled with AVX2 and F16C: 8 of a link's 9 values converted
    /// and multiplied in one instruction each (no fused multiply-adds, so the same bits).
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
    /// With `F16C` the values are converted by [`decode_f16c`], which the caller must have
    /// checked the CPU for (only [`ReceiverLinks::chunk_f16c`] sets it).
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
        let qs = c * RECEIVER_CHUNK..((c + 1) * RECEIVER_CHUNK).min(rows);
        for q in qs {
            let point = receivers[q] as usize;
            if point < skip {
                continue;
            }
            let w = if point < m { w_first } else { w_rest };
            let r = point - first;
            let (a, b) = (self.offsets[q] as usize, self.offsets[q + 1] as usize);
            let mut acc = [0.0f32; LINK_DIM];
            for (&slot, v) in self.slots[a..b].iter().zip(&self.values[a..b]) {
                let ws = &w[slot as usize];
                #[cfg(target_arch = "x86_64")]
                let v = if F16C {
                    // SAFETY: `F16C` is set only by `chunk_f16c`, which runs only on CPUs with
                    // F16C (checked in `apply_impl`).
                    unsafe { decode_f16c(v) }
                } else {
                    decode(v)
                };
                #[cfg(not(target_arch = "x86_64"))]
                let v = decode(v);
                for d in 0..LINK_DIM {
                    acc[d] += ws[d] * v[d];
                }
            }
            let o = &mut out[r * LINK_DIM..(r + 1) * LINK_DIM];
            if ADD {
                for d in 0..LINK_DIM {
                    o[d] += acc[d];
                }
            } else {
                o.copy_from_slice(&acc);
            }
        }
    }
}

/// A link's half-float values as `f32` (exact).
#[inline(always)]
fn decode(v: &[u16; LINK_DIM]) -> [f32; LINK_DIM] {
    std::array::from_fn(|d| f16::from_bits(v[d]).to_f32())
}

/// [`decode`] with the first 8 values converted by one F16C instruction (exact, as the
/// software conversion).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx,f16c")]
#[inline]
fn decode_f16c(v: &[u16; LINK_DIM]) -> [f32; LINK_DIM] {
    use std::arch::x86_64::{__m128i, _mm256_cvtph_ps, _mm256_storeu_ps, _mm_loadu_si128};
    let mut x = [0.0f32; LINK_DIM];
    // SAFETY: `v` holds 9 `u16`, so the 16 bytes from its start are in bounds (an unaligned
    // load); `x` holds 9 `f32`, so the 32 bytes stored from its start are in bounds.
    unsafe {
        let lo = _mm_loadu_si128(v.as_ptr().cast::<__m128i>());
        _mm256_storeu_ps(x.as_mut_ptr(), _mm256_cvtph_ps(lo));
    }
    x[LINK_DIM - 1] = f16::from_bits(v[LINK_DIM - 1]).to_f32();
    x
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

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    #[test]
    fn receiver_major_gives_the_same_bits() {
        let bytes = sample_bytes();
        let a = validated(&bytes);
        let rl = ReceiverLinks::build(a);
        assert_eq!(rl.receiver_ids(), (0..12).collect::<Vec<u32>>().as_slice());
        let e = sample_emission();
        let mut e_dark = e.clone();
        e_dark[6..9].copy_from_slice(&[1e-3, -1e-3, 0.0]);
        for (e, threshold, senders) in [(&e, 0.0, 6), (&e_dark, 0.01, 5)] {
            let mut want = vec![0.0f32; 14 * 9];
            assert_eq!(a.apply(e, threshold, &mut want), senders);
            let mut got = vec![f32::NAN; 14 * 9];
            assert_eq!(rl.apply(e, threshold, &mut got), senders);
            assert_eq!(bits(&got), bits(&want));
            assert!(got[12 * 9..].iter().all(|&x| x == 0.0));
        }
    }

    #[test]
    fn the_f16c_conversion_gives_the_bits_of_the_software_one() {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("f16c") {
            // Every half float but the NaNs (whose payloads the two may treat differently;
            // validated links hold none), nine to a link, in each of the nine places.
            let all: Vec<u16> = (0..=u16::MAX)
                .filter(|&h| !f16::from_bits(h).is_nan())
                .collect();
            for shift in 0..LINK_DIM {
                for chunk in all[shift..].chunks_exact(LINK_DIM) {
                    let v: [u16; LINK_DIM] = std::array::from_fn(|d| chunk[d]);
                    // SAFETY: this CPU has F16C (checked above).
                    let fast = unsafe { decode_f16c(&v) };
                    assert_eq!(fast.map(f32::to_bits), decode(&v).map(f32::to_bits));
                }
            }
        }
    }

    #[test]
    fn the_first_rows_alone_give_the_bits_of_the_full_product() {
        let bytes = sample_bytes();
        let a = validated(&bytes);
        let rl = ReceiverLinks::build(a);
        let e = sample_emission();
        let mut full = vec![0.0f32; 14 * 9];
        rl.apply(&e, 0.0, &mut full);
        for m in [0, 1, 5, 12, 14] {
            let mut first = vec![f32::NAN; m * 9];
            assert_eq!(rl.apply_first(&e, 0.0, m, &mut first), 6);
            assert_eq!(bits(&first), bits(&full[..m * 9]), "first {m}");
        }
    }

    #[test]
    fn the_rows_from_m_on_are_added_with_the_bits_of_the_added_product_and_the_rest_untouched() {
        let bytes = sample_bytes();
        let a = validated(&bytes);
        let rl = ReceiverLinks::build(a);
        let e = sample_emission();
        let start: Vec<f32> = (0..14 * 9).map(|k| (k as f32 * 0.37).cos()).collect();
        let mut all = start.clone();
        rl.apply_add(&e, 0.0, &mut all);
        for m in [0, 1, 5, 12, 14] {
            let mut got = start.clone();
            rl.apply_add_from(&e, 0.0, m, &mut got);
            assert_eq!(bits(&got[..m * 9]), bits(&start[..m * 9]), "below {m}");
            assert_eq!(bits(&got[m * 9..]), bits(&all[m * 9..]), "from {m}");
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
        for m in [0, 1, 5, 12, 14] {
            let mut got = vec![f32::NAN; 14 * 9];
            assert_eq!(rl.apply_split(&e, &e_first, m, 0.01, &mut got), 6);
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
        let rl = ReceiverLinks::build_where(a, |s, r| s < 3 && r >= 4);
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
        a.apply(&dark, 0.0, &mut product);
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
