//! `S` receiver-major as plain arrays: the stored sender-major links transposed, each
//! receiver's links in ascending sender order.

use mlt_format::links::{ArchivedLinks, LINK_DIM};

/// The links of a file receiver-major: receiver `receiver_ids[q]` (ascending, those with a
/// link) has links `offsets[q]..offsets[q + 1]`, each with a sender slot (`slots`, ascending
/// within a row; slot `s` is sender point `sender_ids[s]` with scale `scales[s]`) and nine
/// half-float values (`values`, RGB-major: element `d` is multiplied by the sender's channel
/// `d / 3` times its scale), so that `i_r = sum_k values[k] * scale_s * e_s` per channel.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TransposedLinks {
    /// Receiver points of the file (those without links included).
    pub receivers: u32,
    pub sender_ids: Vec<u32>,
    pub scales: Vec<f32>,
    pub receiver_ids: Vec<u32>,
    /// `receiver_ids.len() + 1` offsets into `slots` and `values`.
    pub offsets: Vec<u32>,
    pub slots: Vec<u32>,
    pub values: Vec<[u16; LINK_DIM]>,
}

impl TransposedLinks {
    /// Transposes validated links (call [`ArchivedLinks::validate`] first), keeping only the
    /// links `(sender, receiver)` for which `keep` holds (the stored sender slots without a
    /// kept link are left out).
    pub fn build(links: &ArchivedLinks, keep: impl Fn(u32, u32) -> bool) -> TransposedLinks {
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
        TransposedLinks {
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
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    /// True without links.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }
}
