//! The first linked receivers' rows, nearly dense, stored over the union of their senders
//! [`GROUP`] rows at a time and summed eight rows at once ([`Groups`]), with the bits of the
//! rows summed one by one.

use mlt_format::links::LINK_DIM;

use super::kernels::group_sums;
use super::slots::Slots;
use super::weights::Weights;

/// Rows summed [`GROUP`] at a time.
pub(super) const GROUP: usize = 8;

/// The least share of a group's rows-times-senders that must hold links for its rows to be
/// grouped ([`Groups`]).
pub(super) const GROUP_FILL: f64 = 0.75;

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
pub(super) struct Groups {
    /// Rows grouped: the first `rows` linked receivers, a multiple of [`GROUP`].
    pub(super) rows: usize,
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
    pub(super) fn build(
        offsets: &[u32],
        slots: &[u32],
        values: &[[u16; LINK_DIM]],
        fill: f64,
    ) -> Groups {
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
    pub(super) fn bytes(&self) -> usize {
        4 * self.offsets.len() + self.slots.bytes() + 2 * GROUP * LINK_DIM * self.values.len()
    }

    /// The sums of group `g`'s eight rows over the weights `w[slot]`, each row's the
    /// bits of [`row_sum`](super::kernels::row_sum) over its own links.
    #[inline(always)]
    pub(super) fn sums<const F16C: bool>(&self, g: usize, w: &Weights) -> [[f32; LINK_DIM]; GROUP] {
        let k = self.offsets[g] as usize..self.offsets[g + 1] as usize;
        let values = &self.values[k.clone()];
        match &self.slots {
            Slots::Narrow(s) => group_sums::<F16C, u16>(&s[k], values, w),
            Slots::Wide(s) => group_sums::<F16C, u32>(&s[k], values, w),
        }
    }
}
