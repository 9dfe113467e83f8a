//! The `TSHD` section of a shard file: one share of the single-bounce operator T, computed by
//! `bake SCENE --shard I/N`, to be combined by `bake merge` into the file a single bake gives.

use crate::links::LINK_DIM;
use crate::meta::TransportParams;

/// A shard's rows of T (full precision) and its share of the refinement's counts.
#[derive(Clone, Debug, Default, PartialEq, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct ShardSection {
    /// The input key of the complete bake the shards add up to.
    pub base_key: u64,
    pub index: u32,
    pub count: u32,
    pub params: TransportParams,
    /// How `bake merge` runs the Neumann series (format 1.4 and later): `--bounces auto`
    /// (with `params.bounces` the cap) or the fixed count, and the fraction of the indirect
    /// light the series may leave out.
    pub auto_bounces: bool,
    pub bounce_tolerance: f64,
    /// Receivers this shard owns and processed, ascending.
    pub rows: Vec<u32>,
    /// `rows.len() + 1` offsets into `senders`.
    pub offsets: Vec<u32>,
    pub senders: Vec<u32>,
    /// `LINK_DIM` floats per link.
    pub values: Vec<f32>,
    /// Per receiver level, over the owned receivers: receivers processed and links kept.
    pub receivers_refined: Vec<u64>,
    pub t_links_per_level: Vec<u64>,
    pub rays: u64,
    pub unsupported_hits: u64,
    /// Per row (format 1.5 and later), the single-bounce vector irradiance its gather found
    /// under the representative emission (`LINK_DIM` floats per row), and that emission (3
    /// floats per sender): what the merge needs for [`crate::meta::RefinementDrop`].
    pub row_gathered: Vec<f32>,
    pub emission: Vec<f32>,
    /// Paths per level-0 receiver for its bounces 2 and later (format 1.7 and later; 0: the
    /// series chains them), and the rows they gave for the level-0 receivers this shard owns:
    /// `bounce_rows` ascending, `bounce_offsets` (`bounce_rows.len() + 1`) into
    /// `bounce_senders`, `LINK_DIM` floats per link in `bounce_values`.
    pub level0_paths: u32,
    pub bounce_rows: Vec<u32>,
    pub bounce_offsets: Vec<u32>,
    pub bounce_senders: Vec<u32>,
    pub bounce_values: Vec<f32>,
}

impl ShardSection {
    /// Checks the invariants a merge relies on against a basis of `points` points and
    /// `levels` levels.
    pub fn validate(&self, points: usize, levels: usize) -> Result<(), String> {
        if self.count == 0 || self.index >= self.count {
            return Err(format!(
                "shard {}/{} is not a valid share",
                self.index, self.count
            ));
        }
        if self.offsets.len() != self.rows.len() + 1
            || self.offsets.first() != Some(&0)
            || self.offsets.windows(2).any(|w| w[0] > w[1])
            || self.offsets.last().map(|&o| o as usize) != Some(self.senders.len())
            || self.values.len() != self.senders.len() * LINK_DIM
            || self.row_gathered.len() != self.rows.len() * LINK_DIM
            || !self.emission.len().is_multiple_of(3)
        {
            return Err("row arrays are inconsistent".into());
        }
        if self.bounce_offsets.len() != self.bounce_rows.len() + 1
            || self.bounce_offsets.first() != Some(&0)
            || self.bounce_offsets.windows(2).any(|w| w[0] > w[1])
            || self.bounce_offsets.last().map(|&o| o as usize) != Some(self.bounce_senders.len())
            || self.bounce_values.len() != self.bounce_senders.len() * LINK_DIM
            || self.bounce_rows.windows(2).any(|w| w[0] >= w[1])
            || self.bounce_rows.iter().any(|&r| r as usize >= points)
        {
            return Err("path-traced bounce rows are inconsistent".into());
        }
        if self.rows.windows(2).any(|w| w[0] >= w[1])
            || self.rows.iter().any(|&r| r as usize >= points)
        {
            return Err("rows are not ascending receiver indices".into());
        }
        if self.receivers_refined.len() != levels || self.t_links_per_level.len() != levels {
            return Err("per-level counts do not match the levels".into());
        }
        if !(self.bounce_tolerance > 0.0 && self.bounce_tolerance < 1.0) {
            return Err(format!(
                "bounce tolerance {} is not a fraction in (0, 1)",
                self.bounce_tolerance
            ));
        }
        Ok(())
    }
}
