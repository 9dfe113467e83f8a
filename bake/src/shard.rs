//! Scale-out on an existing scheduler: `bake SCENE --shard I/N` computes T for one
//! deterministic share of the receivers, and `bake merge` combines the shards into the file a
//! single bake gives, byte for byte.
//!
//! Ownership: the coarsest receivers are split into `N` contiguous runs of a Morton (Z-order)
//! sort of their positions, so that a shard's region is compact; every finer receiver belongs
//! to the shard of its primary parent (the coarser-level function with the largest weight at
//! it; ties to the lower index; a point without parent falls to `index mod N`). A shard
//! processes the receivers it owns and, recomputed locally, every coarser receiver they
//! depend on: Eq. 17 reads the links of all coarser functions non-zero at a receiver, and the
//! refinement queue of a level depends on the previous level's results. Each receiver's result
//! depends only on its index, the seed and those coarser results, so the recomputed ones equal
//! the single bake's and the owned rows of all shards add up to its T exactly.
//!
//! Where the bake traces the level-0 receivers' later bounces (`--level0-paths`), the paths
//! end in T's expansion over every receiver, which no shard has: the merge traces them, with
//! the scene (`bake merge --scene SCENE`), from the merged T. The shard section's fields for
//! traced rows stay empty. The check of the light at the scene's camera (`camera_check`)
//! traces the scene too: a merge with the scene computes it from the merged T,
//! as the single bake does; one without leaves the file's `TCAM` section out.

use mlt_format::light_model::Light;
use mlt_format::links::LINK_DIM;
use mlt_format::shard::ShardSection;
use mlt_format::{BakeContents, IndexedBasis};
use mlt_scenes::RayCaster;

use crate::error::BakeError;
use crate::observer::Observer;
use crate::pipeline::flat_section;
use crate::refine::{ReceiverLinks, RefineStats};
use crate::transport::{
    finish_transport, trace_level0_bounces, traced_vertex, trim_levels, BouncePolicy, CheckScene,
};

/// Spreads the bits of a 10-bit integer three apart.
fn spread(mut x: u32) -> u32 {
    x &= 0x3ff;
    x = (x | (x << 16)) & 0x030000ff;
    x = (x | (x << 8)) & 0x0300f00f;
    x = (x | (x << 4)) & 0x030c30c3;
    (x | (x << 2)) & 0x09249249
}

/// The shard owning each point.
pub fn owners(ib: &IndexedBasis, count: u32) -> Vec<u32> {
    let b = &ib.basis;
    let mut owner = vec![0u32; b.len()];
    // Level 0: contiguous runs of the Morton order.
    let l0 = b.level_range(0);
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for j in l0.clone() {
        for a in 0..3 {
            lo[a] = lo[a].min(b.positions[j][a]);
            hi[a] = hi[a].max(b.positions[j][a]);
        }
    }
    let code = |p: [f32; 3]| {
        let q = |a: usize| {
            let ext = (hi[a] - lo[a]).max(f32::MIN_POSITIVE);
            (((p[a] - lo[a]) / ext).clamp(0.0, 1.0) * 1023.0) as u32
        };
        spread(q(0)) | (spread(q(1)) << 1) | (spread(q(2)) << 2)
    };
    let mut order: Vec<(u32, usize)> = l0.clone().map(|j| (code(b.positions[j]), j)).collect();
    order.sort_unstable();
    let n0 = order.len().max(1);
    for (rank, &(_, j)) in order.iter().enumerate() {
        owner[j] = (rank * count as usize / n0) as u32;
    }
    // Finer levels: the primary parent's shard.
    for l in 1..b.levels() {
        for i in b.level_range(l) {
            let mut best: Option<(f32, usize)> = None;
            ib.for_each_weight(l - 1, b.positions[i], b.normals[i], |k, w| {
                if best.is_none_or(|(bw, bk)| w > bw || (w == bw && k < bk)) {
                    best = Some((w, k));
                }
            });
            owner[i] = match best {
                Some((_, k)) => owner[k],
                None => i as u32 % count,
            };
        }
    }
    owner
}

/// The receivers shard `index` must process: those it owns and, transitively, every coarser
/// function non-zero at one of them.
pub fn needed(ib: &IndexedBasis, owner: &[u32], index: u32) -> Vec<bool> {
    let b = &ib.basis;
    let mut need: Vec<bool> = owner.iter().map(|&o| o == index).collect();
    for l in (1..b.levels()).rev() {
        for i in b.level_range(l) {
            if !need[i] {
                continue;
            }
            for m in 0..l {
                ib.for_each_weight(m, b.positions[i], b.normals[i], |k, _| need[k] = true);
            }
        }
    }
    need
}

/// Packs the owned rows of a shard's T (with their rays and unsupported hits as the gathers
/// counted them, so that the merged totals are a single bake's).
pub fn shard_section(
    ib: &IndexedBasis,
    t: &ReceiverLinks,
    owner: &[u32],
    (index, count): (u32, u32),
    base_key: u64,
    params: mlt_format::meta::TransportParams,
    policy: BouncePolicy,
) -> ShardSection {
    let levels = ib.levels();
    let mut s = ShardSection {
        base_key,
        index,
        count,
        params,
        auto_bounces: policy.auto,
        bounce_tolerance: policy.tolerance,
        offsets: vec![0],
        emission: t.emission.clone(),
        receivers_refined: vec![0; levels],
        t_links_per_level: vec![0; levels],
        level0_paths: policy.level0_paths,
        bounce_offsets: vec![0],
        ..Default::default()
    };
    let mut owned: Vec<(u32, usize)> = t
        .rows
        .iter()
        .enumerate()
        .filter(|(_, &r)| owner[r as usize] == index)
        .map(|(row, &r)| (r, row))
        .collect();
    owned.sort_unstable();
    for (r, row) in owned {
        let (a, e) = (t.offsets[row] as usize, t.offsets[row + 1] as usize);
        let l = ib.basis.level_of(r as usize);
        s.receivers_refined[l] += 1;
        s.t_links_per_level[l] += (e - a) as u64;
        s.rays += t.rays[row];
        s.unsupported_hits += t.unsupported[row];
        s.rows.push(r);
        s.row_gathered.extend_from_slice(&t.gathered[row]);
        s.senders.extend_from_slice(&t.senders[a..e]);
        for v in &t.values[a..e] {
            s.values.extend_from_slice(v);
        }
        s.offsets.push(s.senders.len() as u32);
    }
    s
}

/// Combines shard files into the contents a single bake gives. Each shard comes with the name
/// an error calls it by (its file): a set with a shard missing, given twice, of another bake or
/// not a shard at all is refused, naming the files and the shard indices. `caster` is the
/// scene's, needed (and then required) only where the shards' bake traces the level-0 bounces
/// (`--level0-paths`): those paths end in the whole of T, which no shard has.
pub fn merge(
    named: Vec<(String, BakeContents)>,
    caster: Option<&dyn RayCaster>,
    obs: &dyn Observer,
) -> Result<BakeContents, BakeError> {
    let bad = |m: String| Err(BakeError::Merge(m));
    let Some((name0, first)) = named.first() else {
        return bad("no shards given".into());
    };
    let Some(s0) = &first.shard else {
        return bad(format!("{name0} is not a shard (no TSHD section)"));
    };
    let count = s0.count as usize;
    let mut holder: Vec<Option<&str>> = vec![None; count];
    for (name, c) in &named {
        let Some(s) = &c.shard else {
            return bad(format!("{name} is not a shard (no TSHD section)"));
        };
        if s.count as usize != count
            || s.base_key != s0.base_key
            || s.params != s0.params
            || (s.auto_bounces, s.bounce_tolerance, s.level0_paths)
                != (s0.auto_bounces, s0.bounce_tolerance, s0.level0_paths)
        {
            return bad(format!(
                "{name} (shard {}/{}) belongs to another bake than {name0} (input key {:016x}, \
                 expected {:016x})",
                s.index, s.count, s.base_key, s0.base_key
            ));
        }
        if c.meta != first.meta || c.basis != first.basis {
            return bad(format!(
                "{name} (shard {}/{}) has another basis than {name0}",
                s.index, s.count
            ));
        }
        let Some(slot) = holder.get_mut(s.index as usize) else {
            return bad(format!("{name} says it is shard {}/{}", s.index, s.count));
        };
        if let Some(other) = slot.replace(name) {
            return bad(format!(
                "shard {}/{} is given twice: {other} and {name}",
                s.index, s.count
            ));
        }
    }
    let missing: Vec<String> = (0..count)
        .filter(|&i| holder[i].is_none())
        .map(|i| format!("{i}/{count}"))
        .collect();
    if !missing.is_empty() {
        return bad(format!(
            "{} shards given, {count} needed: shard {} missing (bake each with --shard I/{count})",
            named.len(),
            missing.join(", ")
        ));
    }
    let shards: Vec<&BakeContents> = named.iter().map(|(_, c)| c).collect();
    let ib = &first.basis;
    let levels = ib.levels();
    // T: every owned row, in receiver order (levels are contiguous index ranges, so this is
    // the single bake's level-by-level order).
    let mut rows: Vec<(u32, usize, usize)> = Vec::new();
    let mut rstats = RefineStats {
        receivers_refined: vec![0; levels],
        links_per_level: vec![0; levels],
        ..Default::default()
    };
    for (k, c) in shards.iter().enumerate() {
        let Some(s) = &c.shard else { continue };
        for (row, &r) in s.rows.iter().enumerate() {
            rows.push((r, k, row));
        }
        for l in 0..levels {
            rstats.receivers_refined[l] += s.receivers_refined[l];
            rstats.links_per_level[l] += s.t_links_per_level[l];
        }
        rstats.rays += s.rays;
        rstats.unsupported_hits += s.unsupported_hits;
    }
    rows.sort_unstable();
    if rows.windows(2).any(|w| w[0].0 == w[1].0) {
        return bad("two shards hold the same receiver".into());
    }
    let mut t = ReceiverLinks::new(ib.basis.len());
    t.emission = s0.emission.clone();
    let mut links = Vec::new();
    for (r, k, row) in rows {
        let Some(s) = &shards[k].shard else { continue };
        links.clear();
        links.extend(s.row_links(row));
        // Per-row unsupported counts are only needed by shards; the totals are in rstats.
        let mut gathered = [0.0f32; LINK_DIM];
        gathered.copy_from_slice(&s.row_gathered[LINK_DIM * row..LINK_DIM * (row + 1)]);
        t.push_row(r, &links, (0, 0), gathered);
    }
    let policy = BouncePolicy {
        auto: s0.auto_bounces,
        tolerance: s0.bounce_tolerance,
        level0_paths: s0.level0_paths,
    };
    // Traced level-0 bounces end in T's expansion over every receiver, which only the merge
    // has: it traces them here, as the single bake does after its refinement.
    if traced_vertex(&s0.params, policy) > 0 {
        let Some(caster) = caster else {
            return bad(format!(
                "the shards' bake traces the level-0 bounces (--level0-paths {}), which the \
                 merge computes from the whole of T: give the scene (bake merge --scene SCENE)",
                s0.level0_paths
            ));
        };
        trace_level0_bounces(ib, caster, &s0.params, policy, &mut t, obs);
    }
    // The check of the light at the camera traces the scene: only with it, as a single bake.
    let light = caster
        .map(|_| Light::from_info(&first.meta.light))
        .transpose()
        .map_err(|e| BakeError::Merge(format!("the shards' light: {e}")))?;
    let check = caster
        .zip(light.as_ref())
        .map(|(caster, light)| CheckScene {
            caster,
            camera: &first.meta.camera,
            light,
        });
    let out = finish_transport(ib, t, rstats, s0.params.clone(), policy, 0.0, check, obs)?;
    for w in &out.warnings {
        obs.warn(w);
    }
    let mut transport = out.transport;
    transport.meta.timings = None;
    let basis = trim_levels(&first.basis, out.levels_stored)?;
    let flat = flat_section(&basis, Some(&transport), obs)?;
    Ok(BakeContents {
        meta: first.meta.clone(),
        basis,
        transport: Some(transport),
        input_key: s0.base_key,
        shard: None,
        flat,
    })
}
