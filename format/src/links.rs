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
    /// Per hierarchical point of `points`: whether it receives a link
    /// ([`crate::flat_section::linked_flags`] of the receiver ids).
    pub fn linked_flags(&self, points: usize) -> Vec<bool> {
        crate::flat_section::linked_flags(points, self.receiver_ids.iter().map(|r| r.to_native()))
    }

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
}
