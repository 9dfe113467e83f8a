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
    /// series chains them), and room for the rows they give for the level-0 receivers this
    /// shard owns: `bounce_rows` ascending, `bounce_offsets` (`bounce_rows.len() + 1`) into
    /// `bounce_senders`, `LINK_DIM` floats per link in `bounce_values`. The bake writes them
    /// empty (the paths need the whole of T, so `bake merge --scene` traces them); the merge
    /// ignores rows that a shard of an earlier build carried.
    pub level0_paths: u32,
    pub bounce_rows: Vec<u32>,
    pub bounce_offsets: Vec<u32>,
    pub bounce_senders: Vec<u32>,
    pub bounce_values: Vec<f32>,
}

impl ShardSection {
    /// The links of the `k`-th row of T held (receiver `rows[k]`); valid after
    /// [`ShardSection::validate`].
    pub fn row_links(&self, k: usize) -> impl Iterator<Item = (u32, [f32; LINK_DIM])> + '_ {
        links_at(&self.offsets, &self.senders, &self.values, k)
    }

    /// Checks the invariants a merge relies on against a basis of `points` points and
    /// `levels` levels.
    pub fn validate(&self, points: usize, levels: usize) -> Result<(), String> {
        if self.count == 0 || self.index >= self.count {
            return Err(format!(
                "shard {}/{} is not a valid share",
                self.index, self.count
            ));
        }
        if !offsets_fit(&self.offsets, self.rows.len(), &self.senders, &self.values)
            || self.row_gathered.len() != self.rows.len() * LINK_DIM
            || !self.emission.len().is_multiple_of(3)
        {
            return Err("row arrays are inconsistent".into());
        }
        if !offsets_fit(
            &self.bounce_offsets,
            self.bounce_rows.len(),
            &self.bounce_senders,
            &self.bounce_values,
        ) || self.bounce_rows.windows(2).any(|w| w[0] >= w[1])
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

/// Whether `offsets` delimits `rows` rows of `senders` with `LINK_DIM` floats of `values` each.
fn offsets_fit(offsets: &[u32], rows: usize, senders: &[u32], values: &[f32]) -> bool {
    offsets.len() == rows + 1
        && offsets.first() == Some(&0)
        && offsets.windows(2).all(|w| w[0] <= w[1])
        && offsets.last().map(|&o| o as usize) == Some(senders.len())
        && values.len() == senders.len() * LINK_DIM
}

/// Row `k`'s `(sender, value)` links of a row-major layout checked by [`offsets_fit`].
fn links_at<'a>(
    offsets: &[u32],
    senders: &'a [u32],
    values: &'a [f32],
    k: usize,
) -> impl Iterator<Item = (u32, [f32; LINK_DIM])> + 'a {
    let (a, e) = (offsets[k] as usize, offsets[k + 1] as usize);
    (a..e).map(move |j| {
        let mut v = [0.0f32; LINK_DIM];
        v.copy_from_slice(&values[j * LINK_DIM..(j + 1) * LINK_DIM]);
        (senders[j], v)
    })
}
