//! The direct-to-indirect operator `S` as stored (Lehtinen et al. 2008, sections 3.1-3.3).
//!
//! A link `S_ij` carries the vector irradiance at receiver `i`, per colour channel, due to unit
//! scalar irradiance in that channel at sender `j`: 9 values, `[c * 3 + d]` for channel `c` and
//! direction component `d`. Links are stored sender-major (all links of one sender together),
//! because the runtime walks only the senders whose direct light is non-zero (section 3.3).
//!
//! Values are stored as IEEE half floats scaled per sender: `value = f16 * scale_j`, where
//! `scale_j` is the largest magnitude among sender `j`'s values, so each value carries a
//! relative error of at most 2^-11 of its sender's largest value (about 5e-4; far below the
//! refinement threshold epsilon = 0.025). The bake measures and reports the actual maximum.

use half::f16;

use crate::error::FormatError;

/// Floats per link: 3 colour channels x 3 vector components.
pub const LINK_DIM: usize = 9;

/// A sparse sender-major link matrix.
#[derive(Clone, Debug, Default, PartialEq, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct Links {
    /// Number of receiver basis functions (global point indices `0..receivers`).
    pub receivers: u32,
    /// Number of sender basis functions (global point indices `0..senders`: the coarsest
    /// levels).
    pub senders: u32,
    /// Senders that have at least one link, ascending.
    pub sender_ids: Vec<u32>,
    /// `sender_ids.len() + 1` offsets into `receiver_ids`.
    pub offsets: Vec<u32>,
    /// Per stored sender: the scale of its half-float values.
    pub scales: Vec<f32>,
    /// Receiver of each link, ascending within a sender.
    pub receiver_ids: Vec<u32>,
    /// `LINK_DIM` half-float bit patterns per link.
    pub values: Vec<u16>,
}

/// One sender's links, in full precision, to be packed.
pub struct SenderLinks<'a> {
    pub sender: u32,
    /// `(receiver, value)` pairs, ascending by receiver.
    pub links: &'a [(u32, [f32; LINK_DIM])],
}

impl Links {
    /// Packs sender-major links; returns them and the largest absolute quantisation error.
    pub fn pack<'a>(
        receivers: u32,
        senders: u32,
        columns: impl IntoIterator<Item = SenderLinks<'a>>,
    ) -> (Links, f32) {
        let mut out = Links {
            receivers,
            senders,
            offsets: vec![0],
            ..Links::default()
        };
        let mut max_err = 0.0f32;
        for col in columns {
            if col.links.is_empty() {
                continue;
            }
            let scale = col
                .links
                .iter()
                .flat_map(|(_, v)| v.iter())
                .fold(0.0f32, |m, x| m.max(x.abs()));
            let inv = if scale > 0.0 { 1.0 / scale } else { 0.0 };
            out.sender_ids.push(col.sender);
            out.scales.push(scale);
            for (r, v) in col.links {
                out.receiver_ids.push(*r);
                for &x in v {
                    let h = f16::from_f32(x * inv);
                    max_err = max_err.max((h.to_f32() * scale - x).abs());
                    out.values.push(h.to_bits());
                }
            }
            out.offsets.push(out.receiver_ids.len() as u32);
        }
        (out, max_err)
    }

    pub fn link_count(&self) -> usize {
        self.receiver_ids.len()
    }

    /// Checks the invariants [`apply`](ArchivedLinks::apply) relies on.
    pub fn validate(&self) -> Result<(), FormatError> {
        check(
            self.receivers,
            self.senders,
            &self.sender_ids,
            &self.offsets,
            &self.scales,
            &self.receiver_ids,
            self.values.len(),
        )
    }

    /// Full-precision value of link `k` (for tests and statistics).
    pub fn value(&self, k: usize, sender_slot: usize) -> [f32; LINK_DIM] {
        let s = self.scales[sender_slot];
        std::array::from_fn(|d| f16::from_bits(self.values[k * LINK_DIM + d]).to_f32() * s)
    }
}

fn check(
    receivers: u32,
    senders: u32,
    sender_ids: &[u32],
    offsets: &[u32],
    scales: &[f32],
    receiver_ids: &[u32],
    values: usize,
) -> Result<(), FormatError> {
    let bad = |m: String| Err(FormatError::InvalidBasis(format!("links: {m}")));
    let n = sender_ids.len();
    if offsets.len() != n + 1 || scales.len() != n || offsets.first() != Some(&0) {
        return bad("offset or scale arrays do not match the senders".into());
    }
    if offsets.last().map(|&o| o as usize) != Some(receiver_ids.len())
        || values != receiver_ids.len() * LINK_DIM
    {
        return bad("link arrays differ in length".into());
    }
    if offsets.windows(2).any(|w| w[0] > w[1]) {
        return bad("offsets decrease".into());
    }
    if sender_ids.windows(2).any(|w| w[0] >= w[1])
        || sender_ids.last().is_some_and(|&s| s >= senders)
    {
        return bad("sender ids are not ascending or out of range".into());
    }
    if receiver_ids.iter().any(|&r| r >= receivers) {
        return bad("a receiver id is out of range".into());
    }
    if scales.iter().any(|s| !(s.is_finite() && *s >= 0.0)) {
        return bad("a scale is not finite".into());
    }
    Ok(())
}

impl ArchivedLinks {
    /// Checks the invariants [`apply`](Self::apply) relies on (call once after mapping).
    pub fn validate(&self) -> Result<(), FormatError> {
        let ids: Vec<u32> = self.sender_ids.iter().map(|v| v.to_native()).collect();
        let offs: Vec<u32> = self.offsets.iter().map(|v| v.to_native()).collect();
        let scales: Vec<f32> = self.scales.iter().map(|v| v.to_native()).collect();
        let recv: Vec<u32> = self.receiver_ids.iter().map(|v| v.to_native()).collect();
        check(
            self.receivers.to_native(),
            self.senders.to_native(),
            &ids,
            &offs,
            &scales,
            &recv,
            self.values.len(),
        )
    }

    pub fn link_count(&self) -> usize {
        self.receiver_ids.len()
    }

    /// `i += S e` (section 3.3), sender-major: `e` holds 3 floats (RGB scalar irradiance
    /// coefficients) per sender, `i` 9 floats per receiver. Senders whose largest channel is
    /// at most `threshold` are skipped. Returns the number of senders used.
    ///
    /// Requires a validated `self` and `e.len() >= 3 * senders`, `i.len() >= 9 * receivers`.
    pub fn apply(&self, e: &[f32], threshold: f32, i: &mut [f32]) -> usize {
        let mut used = 0;
        for (slot, sid) in self.sender_ids.iter().enumerate() {
            let s = sid.to_native() as usize;
            let es = [e[3 * s], e[3 * s + 1], e[3 * s + 2]];
            if es.iter().all(|x| x.abs() <= threshold) {
                continue;
            }
            used += 1;
            let scale = self.scales[slot].to_native();
            let w = [es[0] * scale, es[1] * scale, es[2] * scale];
            let (a, b) = (
                self.offsets[slot].to_native() as usize,
                self.offsets[slot + 1].to_native() as usize,
            );
            for k in a..b {
                let r = self.receiver_ids[k].to_native() as usize;
                let v = &self.values[k * LINK_DIM..(k + 1) * LINK_DIM];
                let out = &mut i[r * LINK_DIM..(r + 1) * LINK_DIM];
                for c in 0..3 {
                    for d in 0..3 {
                        out[c * 3 + d] += w[c] * f16::from_bits(v[c * 3 + d].to_native()).to_f32();
                    }
                }
            }
        }
        used
    }
}

/// `S` receiver-major in full precision, decoded once from the stored sender-major half
/// floats (section 3.3's `i = S e`, rearranged for the run time): each linked receiver gathers
/// its senders' light, so receivers are independent and computed in parallel with the same
/// bits for any thread count, and no half float is decoded per frame.
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
    /// The decoded (unscaled) link values.
    values: Vec<[f32; LINK_DIM]>,
}

/// Receivers per parallel task of [`ReceiverLinks::apply`].
const RECEIVER_CHUNK: usize = 1024;

impl ReceiverLinks {
    /// Transposes validated links (call [`ArchivedLinks::validate`] first).
    pub fn build(links: &ArchivedLinks) -> ReceiverLinks {
        let receivers = links.receivers.to_native();
        let n = receivers as usize;
        let mut count = vec![0u32; n + 1];
        for r in links.receiver_ids.iter() {
            count[r.to_native() as usize + 1] += 1;
        }
        let receiver_ids: Vec<u32> = (0..n)
            .filter(|&r| count[r + 1] > 0)
            .map(|r| r as u32)
            .collect();
        // Offsets per receiver (all of them) for the fill, then compacted.
        for r in 0..n {
            count[r + 1] += count[r];
        }
        let total = links.receiver_ids.len();
        let mut cursor = count.clone();
        let mut slots = vec![0u32; total];
        let mut values = vec![[0.0f32; LINK_DIM]; total];
        for slot in 0..links.sender_ids.len() {
            let (a, b) = (
                links.offsets[slot].to_native() as usize,
                links.offsets[slot + 1].to_native() as usize,
            );
            for k in a..b {
                let r = links.receiver_ids[k].to_native() as usize;
                let at = cursor[r] as usize;
                cursor[r] += 1;
                slots[at] = slot as u32;
                let v = &links.values[k * LINK_DIM..(k + 1) * LINK_DIM];
                values[at] = std::array::from_fn(|d| f16::from_bits(v[d].to_native()).to_f32());
            }
        }
        let mut offsets: Vec<u32> = receiver_ids.iter().map(|&r| count[r as usize]).collect();
        offsets.push(total as u32);
        ReceiverLinks {
            receivers,
            sender_ids: links.sender_ids.iter().map(|s| s.to_native()).collect(),
            scales: links.scales.iter().map(|s| s.to_native()).collect(),
            receiver_ids,
            offsets,
            slots,
            values,
        }
    }

    /// Heap bytes held.
    pub fn bytes(&self) -> usize {
        4 * (self.sender_ids.len()
            + self.scales.len()
            + self.receiver_ids.len()
            + self.offsets.len()
            + self.slots.len())
            + 4 * LINK_DIM * self.values.len()
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
        use rayon::prelude::*;
        let n = self.receivers as usize;
        assert_eq!(i.len(), n * LINK_DIM);
        let mut used = 0;
        // Each stored sender's scaled light, repeated per vector component, so that a link
        // multiplies it element by element (the same products as `ArchivedLinks::apply`).
        let w: Vec<[f32; LINK_DIM]> = self
            .sender_ids
            .iter()
            .zip(&self.scales)
            .map(|(&s, &scale)| {
                let s = s as usize;
                let es = [e[3 * s], e[3 * s + 1], e[3 * s + 2]];
                if es.iter().all(|x| x.abs() <= threshold) {
                    [0.0; LINK_DIM]
                } else {
                    used += 1;
                    std::array::from_fn(|k| es[k / 3] * scale)
                }
            })
            .collect();
        // Chunks of receivers own disjoint, consecutive ranges of `i` (receivers ascend): from
        // their first receiver to the next chunk's first, the first chunk from point 0.
        let receivers = &self.receiver_ids;
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
        rest.fill(0.0);
        #[cfg(target_arch = "x86_64")]
        let avx2 = std::arch::is_x86_feature_detected!("avx2");
        parts.into_par_iter().for_each(|(c, first, out)| {
            #[cfg(target_arch = "x86_64")]
            if avx2 {
                // SAFETY: this CPU has AVX2 (checked above), the only requirement for calling
                // a function compiled with it.
                unsafe { self.chunk_avx2(&w, c, first, out) };
                return;
            }
            self.chunk(&w, c, first, out);
        });
        used
    }

    /// [`ReceiverLinks::chunk`] compiled with AVX2 (8 of a link's 9 products in one
    /// instruction; no fused multiply-adds, so the same bits).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn chunk_avx2(&self, w: &[[f32; LINK_DIM]], c: usize, first: usize, out: &mut [f32]) {
        self.chunk(w, c, first, out);
    }

    /// The receivers of chunk `c` into `out`, which starts at point `first`.
    #[inline(always)]
    fn chunk(&self, w: &[[f32; LINK_DIM]], c: usize, first: usize, out: &mut [f32]) {
        let receivers = &self.receiver_ids;
        out.fill(0.0);
        let qs = c * RECEIVER_CHUNK..((c + 1) * RECEIVER_CHUNK).min(receivers.len());
        for q in qs {
            let r = receivers[q] as usize - first;
            let (a, b) = (self.offsets[q] as usize, self.offsets[q + 1] as usize);
            let mut acc = [0.0f32; LINK_DIM];
            for (&slot, v) in self.slots[a..b].iter().zip(&self.values[a..b]) {
                let ws = &w[slot as usize];
                for d in 0..LINK_DIM {
                    acc[d] += ws[d] * v[d];
                }
            }
            out[r * LINK_DIM..(r + 1) * LINK_DIM].copy_from_slice(&acc);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rkyv::rancor;

    fn sample() -> (Links, f32) {
        let a = vec![
            (0u32, [0.5f32; 9]),
            (3, [-0.01, 0.02, 0.03, 0.0, 0.0, 0.0, 1.0, 0.2, 0.1]),
        ];
        let b = vec![(2u32, [1e-3f32; 9])];
        Links::pack(
            4,
            3,
            [
                SenderLinks {
                    sender: 0,
                    links: &a,
                },
                SenderLinks {
                    sender: 1,
                    links: &[],
                },
                SenderLinks {
                    sender: 2,
                    links: &b,
                },
            ],
        )
    }

    #[test]
    fn pack_quantises_within_half_float_precision() {
        let (l, err) = sample();
        l.validate().unwrap();
        assert_eq!(l.sender_ids, vec![0, 2]);
        assert_eq!(l.link_count(), 3);
        assert!(err <= 1.0 * 2f32.powi(-11), "{err}");
        let v = l.value(1, 0);
        assert!((v[6] - 1.0).abs() < 1e-3 && (v[0] + 0.01).abs() < 1e-3);
    }

    #[test]
    fn apply_is_sender_major_and_skips_dark_senders() {
        let (l, _) = sample();
        let bytes = rkyv::to_bytes::<rancor::Error>(&l).unwrap();
        let a = rkyv::access::<ArchivedLinks, rancor::Error>(&bytes).unwrap();
        a.validate().unwrap();
        let e = [2.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0];
        let mut i = vec![0.0f32; 4 * 9];
        let used = a.apply(&e, 0.0, &mut i);
        assert_eq!(used, 2);
        // Receiver 0 from sender 0: 0.5 * e_0 per channel.
        assert!((i[0] - 1.0).abs() < 1e-3 && (i[3] - 0.5).abs() < 1e-3 && i[6] == 0.0);
        // Receiver 2 from sender 2 only.
        assert!((i[2 * 9] - 1e-3).abs() < 1e-6);
        // A threshold above sender 2's light skips it.
        let mut j = vec![0.0f32; 4 * 9];
        assert_eq!(a.apply(&e, 1.5, &mut j), 1);
        assert_eq!(j[2 * 9], 0.0);
    }

    #[test]
    fn validate_rejects_out_of_range_ids() {
        let (mut l, _) = sample();
        l.receiver_ids[0] = 99;
        assert!(l.validate().is_err());
        let (mut l, _) = sample();
        l.sender_ids = vec![2, 0];
        assert!(l.validate().is_err());
        let (mut l, _) = sample();
        l.values.pop();
        assert!(l.validate().is_err());
    }

    #[test]
    fn receiver_major_gives_the_same_bits() {
        // Several senders per receiver, mixed signs, one skipped sender.
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
        let bytes = rkyv::to_bytes::<rancor::Error>(&l).unwrap();
        let a = rkyv::access::<ArchivedLinks, rancor::Error>(&bytes).unwrap();
        a.validate().unwrap();
        let rl = ReceiverLinks::build(a);
        assert_eq!(rl.receiver_ids(), (0..12).collect::<Vec<u32>>().as_slice());
        let e: Vec<f32> = (0..18).map(|k| 0.3 + (k as f32 * 1.3).cos()).collect();
        let mut e_dark = e.clone();
        e_dark[6..9].copy_from_slice(&[1e-3, -1e-3, 0.0]);
        for (e, threshold, senders) in [(&e, 0.0, 6), (&e_dark, 0.01, 5)] {
            let mut want = vec![0.0f32; 14 * 9];
            assert_eq!(a.apply(e, threshold, &mut want), senders);
            let mut got = vec![f32::NAN; 14 * 9];
            assert_eq!(rl.apply(e, threshold, &mut got), senders);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&got), bits(&want));
            assert!(got[12 * 9..].iter().all(|&x| x == 0.0));
        }
    }
}
