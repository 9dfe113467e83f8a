//! Adaptive computation of the single-bounce operator T (Lehtinen et al. 2008, section 3.2,
//! Fig. 5): receiver-centric refinement, one receiver level at a time so that all parent
//! links needed by Eq. 17 exist (or were judged negligible) before a child is processed.
//!
//! For each queued receiver: gather `T'_ij` from all senders (Eq. 16), subtract the parents'
//! contributions over all coarser receiver levels (Eq. 17), then keep a link when
//! - the sender is on the coarsest level and `||T_ij|| > epsilon`, or
//! - the sender is finer, `||T_ij|| > epsilon` and `max_k ||T_ij - T_ik|| > epsilon` over the
//!   sender's neighbours `k` (Appendix A: finer senders carry deviations from local averages,
//!   so similar links to neighbouring senders cancel),
//!
//! and, beyond that test, by the rules of the [`RefinePolicy`] ([`policy`]): the links a
//! coarsest receiver (which has no coarser level to represent what it drops) keeps outright,
//! the budgets by which the middle levels keep links that lean the same way, and the gather
//! rays of each level. When a link passed the paper's test, the receiver's children are queued
//! for the next level. Points that no coarser level supports are queued for their own level
//! regardless (otherwise their coefficient would stay zero).
//!
//! Refinement also sums, under uniform emission at the coarsest senders, the single-bounce light
//! of the links it drops at receivers whose children are not refined against that of all the
//! links it keeps ([`RefineStats::dropped_share`]), and per row the same under the file's light
//! (`drop_estimate`, stored in the file).
//!
//! The receivers of a level are processed in parallel; each one's result depends only on its
//! index, the seed and the coarser levels, so T is identical for any thread count.

pub mod policy;

use mlt_format::adjacency::Csr;
use mlt_format::links::LINK_DIM;
use mlt_format::shepard::MIN_WEIGHT_SUM;
use mlt_format::IndexedBasis;
use mlt_scenes::RayCaster;
use rayon::prelude::*;

use crate::drop_estimate::applied;
use crate::gather::{gather, link_distance, link_norm, GatherCounts, Scratch};
use crate::sender_cells::SenderCells;
pub use policy::{RefinePolicy, RefineRule};

/// Receiver-major links of T: one row per processed receiver.
#[derive(Clone, Debug, Default)]
pub struct ReceiverLinks {
    /// Global receiver index -> row, or `NONE`.
    pub row_of: Vec<u32>,
    /// Row -> global receiver index (ascending within a level; levels in order).
    pub rows: Vec<u32>,
    /// `rows.len() + 1` offsets into `senders`/`values`.
    pub offsets: Vec<u32>,
    pub senders: Vec<u32>,
    pub values: Vec<[f32; LINK_DIM]>,
    /// Per row: gather hits where a sender level had no support.
    pub unsupported: Vec<u64>,
    /// Per row: the visibility rays its gather cast (the refinement's budget rules give
    /// receivers different counts), so that a shard's total is that of its own rows.
    pub rays: Vec<u64>,
    /// Per row: the single-bounce vector irradiance that its gather found under the
    /// representative emission, before Eq. 17 and the keep rules (the reference of
    /// `drop_estimate`).
    pub gathered: Vec<[f32; LINK_DIM]>,
    /// The representative emission the rows were weighted by (3 floats per sender).
    pub emission: Vec<f32>,
    /// Bounces 2 and later of the level-0 receivers traced as paths (`path_bounces`), row `i`
    /// for receiver `i`; empty when the series computes them.
    pub bounce0: crate::neumann::Rows,
}

pub const NONE: u32 = u32::MAX;

impl ReceiverLinks {
    pub fn new(receivers: usize) -> ReceiverLinks {
        ReceiverLinks {
            row_of: vec![NONE; receivers],
            offsets: vec![0],
            ..Default::default()
        }
    }

    /// The links of receiver `i` (empty when it was not processed).
    pub fn row(&self, i: usize) -> (&[u32], &[[f32; LINK_DIM]]) {
        match self.row_of[i] {
            NONE => (&[], &[]),
            r => {
                let (a, b) = (
                    self.offsets[r as usize] as usize,
                    self.offsets[r as usize + 1] as usize,
                );
                (&self.senders[a..b], &self.values[a..b])
            }
        }
    }

    /// Appends the row of `receiver`, whose gather cast `rays` visibility rays and met
    /// `unsupported` hits without sender support.
    pub fn push_row(
        &mut self,
        receiver: u32,
        links: &[(u32, [f32; LINK_DIM])],
        (rays, unsupported): (u64, u64),
        gathered: [f32; LINK_DIM],
    ) {
        self.row_of[receiver as usize] = self.rows.len() as u32;
        self.rows.push(receiver);
        self.rays.push(rays);
        self.unsupported.push(unsupported);
        self.gathered.push(gathered);
        for (s, v) in links {
            self.senders.push(*s);
            self.values.push(*v);
        }
        self.offsets.push(self.senders.len() as u32);
    }

    pub fn link_count(&self) -> usize {
        self.senders.len()
    }
}

/// Parameters of the refinement.
#[derive(Clone, Copy, Debug)]
pub struct RefineSettings {
    pub epsilon: f32,
    pub sender_levels: usize,
    pub gather_rays: u32,
    pub seed: u64,
    /// The rules beyond Fig. 5's test.
    pub policy: RefinePolicy,
}

/// Counts per receiver level.
#[derive(Clone, Debug, Default)]
pub struct RefineStats {
    pub receivers_refined: Vec<u64>,
    pub links_per_level: Vec<u64>,
    pub rays: u64,
    pub unsupported_hits: u64,
    /// Per colour channel, the single-bounce light that T's kept links deliver, and that the
    /// links the keep rules of Fig. 5 dropped would have delivered, under uniform unit emission
    /// at the coarsest senders (the weighting of the bake's other error estimates): per
    /// processed receiver `i` of level `l`, the signed irradiance along its normal,
    /// `sum_j n_i . T_ij` over coarsest senders `j`, times the area its basis function covers
    /// (`R_l^2`, the level's disk radius squared), so that summed over the levels it
    /// approximates the integral of the hierarchical expansion. The dropped sum counts only
    /// the receivers whose children were not refined: a refined receiver's dropped links
    /// reappear in its children's differences (Eq. 17), which keep them or drop them again,
    /// so counting them at both levels would count the same light twice. See
    /// [`RefineStats::dropped_share`].
    pub kept_mass: [f64; 3],
    pub dropped_mass: [f64; 3],
}

impl RefineStats {
    /// The share of the single-bounce light that refinement dropped at epsilon,
    /// `d / (k + d)` of the signed sums above in the worst colour channel (negative when the
    /// dropped links would have taken light away). Dropped links of finer receivers are
    /// differences from the coarser levels' reconstruction (Eq. 17): where they share a sign
    /// the expansion is biased there, and the sum says by how much; where they only carry
    /// detail they cancel. Receivers that refinement never processed are not in it, nor the
    /// dropped links of refined receivers, which their children's differences carry on.
    pub fn dropped_share(&self) -> f64 {
        (0..3)
            .map(|c| {
                let all = self.kept_mass[c] + self.dropped_mass[c];
                if all > 0.0 {
                    self.dropped_mass[c] / all
                } else {
                    0.0
                }
            })
            .fold(0.0, |m: f64, d| if d.abs() > m.abs() { d } else { m })
    }
}

/// Per channel, `n . v_c` of a link `v` at a receiver of normal `n`.
fn along_normal(v: &[f32; LINK_DIM], n: [f32; 3]) -> [f64; 3] {
    std::array::from_fn(|c| (n[0] * v[3 * c] + n[1] * v[3 * c + 1] + n[2] * v[3 * c + 2]) as f64)
}

struct Processed {
    links: Vec<(u32, [f32; LINK_DIM])>,
    /// Whether a link passed the paper's test (forced coarsest links do not count): the
    /// receiver's children are refined.
    refine: bool,
    counts: GatherCounts,
    /// Per channel, the irradiance along the normal that the dropped links to coarsest
    /// senders would have delivered under unit emission ([`RefineStats::kept_mass`]).
    dropped: [f64; 3],
    /// The same for the kept links.
    kept: [f64; 3],
    /// The gathered single-bounce vector irradiance under the representative emission.
    gathered: [f32; LINK_DIM],
}

/// Computes T adaptively. `neighbors` and `children` are the basis' adjacency
/// (see `mlt_format::adjacency`); `on_level(l, receivers, links)` reports progress. With
/// `needed`, only the receivers marked there are processed (a shard: its own receivers and
/// every coarser one they depend on, which makes their results those of the full run).
/// `emission` (3 floats per sender) weights each row's kept and dropped links for the
/// estimate of `drop_estimate`; it does not change T.
#[allow(clippy::too_many_arguments)]
pub fn refine(
    ib: &IndexedBasis,
    caster: &dyn RayCaster,
    neighbors: &Csr,
    children: &Csr,
    settings: &RefineSettings,
    needed: Option<&[bool]>,
    emission: &[f32],
    mut on_level: impl FnMut(usize, usize, usize),
) -> (ReceiverLinks, RefineStats) {
    let b = &ib.basis;
    let senders = b.level_offsets[settings.sender_levels] as usize;
    let sender_coarsest = b.level_offsets[1];
    let eps_ray = caster.ray_epsilon();
    let mut t = ReceiverLinks::new(b.len());
    t.emission = emission.to_vec();
    let mut stats = RefineStats::default();
    let mut queue: Vec<u32> = b.level_range(0).map(|i| i as u32).collect();
    let unreachable = unreachable_points(ib);
    let cells = SenderCells::new(ib, settings.sender_levels);
    for l in 0..b.levels() {
        if let Some(needed) = needed {
            queue.retain(|&i| needed[i as usize]);
        }
        let done: Vec<Processed> = queue
            .par_iter()
            .map_init(
                || Scratch::new(senders),
                |scratch, &i| {
                    process(
                        ib,
                        &cells,
                        caster,
                        &t,
                        neighbors,
                        settings,
                        emission,
                        sender_coarsest,
                        eps_ray,
                        l,
                        i as usize,
                        scratch,
                    )
                },
            )
            .collect();
        let mut next = Vec::new();
        let mut kept = 0u64;
        let area = (b.disk_radii[l] as f64).powi(2);
        for (&i, p) in queue.iter().zip(&done) {
            stats.rays += p.counts.rays;
            stats.unsupported_hits += p.counts.unsupported;
            kept += p.links.len() as u64;
            // A refined receiver's dropped links are in its children's differences (Eq. 17),
            // which keep them or drop them again: only a leaf's dropped links stay lost.
            let refined = p.refine && l + 1 < b.levels();
            for c in 0..3 {
                if !refined {
                    stats.dropped_mass[c] += area * p.dropped[c];
                }
                stats.kept_mass[c] += area * p.kept[c];
            }
            t.push_row(
                i,
                &p.links,
                (p.counts.rays, p.counts.unsupported),
                p.gathered,
            );
            if refined {
                next.extend_from_slice(children.row(i as usize));
            }
        }
        stats.receivers_refined.push(queue.len() as u64);
        stats.links_per_level.push(kept);
        on_level(l, queue.len(), kept as usize);
        if let Some(extra) = unreachable.get(l + 1) {
            next.extend_from_slice(extra);
        }
        next.sort_unstable();
        next.dedup();
        queue = next;
    }
    (t, stats)
}

/// Per level, the points where the next coarser level has no support: no receiver of that
/// level has them as children, so they are queued for their own level regardless (otherwise
/// they would never be computed, and their coefficient would stay zero: a black patch where
/// point placement left the coarser level sparse). Level 0 is empty (it is queued whole).
fn unreachable_points(ib: &IndexedBasis) -> Vec<Vec<u32>> {
    let b = &ib.basis;
    (0..b.levels())
        .map(|l| {
            if l == 0 {
                return Vec::new();
            }
            b.level_range(l)
                .into_par_iter()
                .filter(|&i| ib.weight_sum(l - 1, b.positions[i], b.normals[i]) <= MIN_WEIGHT_SUM)
                .map(|i| i as u32)
                .collect()
        })
        .collect()
}

#[allow(clippy::too_many_arguments)]
fn process(
    ib: &IndexedBasis,
    cells: &SenderCells,
    caster: &dyn RayCaster,
    t: &ReceiverLinks,
    neighbors: &Csr,
    settings: &RefineSettings,
    emission: &[f32],
    sender_coarsest: u32,
    eps_ray: f32,
    level: usize,
    i: usize,
    scratch: &mut Scratch,
) -> Processed {
    scratch.clear();
    let counts = gather(
        ib,
        cells,
        caster,
        i,
        settings.sender_levels,
        settings.policy.gather_rays_at(level, settings.gather_rays),
        settings.seed,
        eps_ray,
        scratch,
    );
    let (x, n) = (ib.basis.positions[i], ib.basis.normals[i]);
    let gathered = applied(scratch, emission);
    // Eq. 17: subtract what the coarser receiver levels already represent at p_i, using the
    // links they kept (discarded links are zero in the representation).
    // Whether any coarser level represents something here: only such receivers have budgets.
    let mut has_parent = false;
    for m in 0..level {
        has_parent |= ib.for_each_basis_value(m, x, n, |k, bk| {
            let (senders, values) = t.row(k);
            for (s, v) in senders.iter().zip(values) {
                scratch.add(*s, v, -bk);
            }
        });
    }
    // Keep rules of Fig. 5, in ascending sender order (canonical output).
    scratch.sort_touched();
    let touched = std::mem::take(&mut scratch.touched);
    let eps = settings.epsilon;
    let policy = &settings.policy;
    let mut links = Vec::new();
    let mut refine = false;
    let mut dropped = [0.0f64; 3];
    let mut lose = |j: u32, v: &[f32; LINK_DIM]| {
        if j < sender_coarsest {
            for (d, a) in dropped.iter_mut().zip(along_normal(v, n)) {
                *d += a;
            }
        }
    };
    for &j in &touched {
        let v = scratch.get(j);
        let norm = link_norm(v);
        let kept_by_rule = if norm <= eps {
            // The base of the hierarchy (`RefinePolicy::keeps_base_link`).
            norm > 0.0 && policy.keeps_base_link(level, j < sender_coarsest)
        } else {
            let keep = j < sender_coarsest
                || neighbors
                    .row(j as usize)
                    .iter()
                    .any(|&k| link_distance(v, scratch.get(k)) > eps)
                || neighbors.row(j as usize).is_empty();
            refine |= keep;
            keep
        };
        if kept_by_rule {
            links.push((j, *v));
        } else {
            lose(j, v);
        }
    }
    // The budgets (`RefinePolicy`): of the links Fig. 5 dropped, keep all but the smallest
    // whose norms sum to at most the budget; those to coarsest senders at levels 1 to 3
    // (`keeps_budget`), those to finer senders at levels 2 and 3 (`keeps_finer_budget`).
    let contact = policy.at_contact(counts.near, counts.rays);
    let budgets = [
        (policy.keeps_budget(level, contact, ib.levels()), false, eps),
        (
            policy.keeps_finer_budget(level),
            true,
            eps * policy.finer_budget_factor,
        ),
    ];
    for (on, finer, budget) in budgets {
        if !(on && has_parent) {
            continue;
        }
        let mut candidates: Vec<(f32, u32)> = touched
            .iter()
            .filter(|&&j| (j >= sender_coarsest) == finer)
            .filter(|&&j| !finer || policy.budget_sampled(scratch.hits(j)))
            .filter(|&&j| links.binary_search_by_key(&j, |(s, _)| *s).is_err())
            .map(|&j| (link_norm(scratch.get(j)), j))
            .filter(|(norm, _)| *norm > 0.0)
            .collect();
        candidates.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut sum = 0.0f32;
        let mut cut = 0;
        for (k, (norm, _)) in candidates.iter().enumerate() {
            if sum + norm > budget {
                break;
            }
            sum += norm;
            cut = k + 1;
        }
        for &(_, j) in &candidates[cut..] {
            let v = *scratch.get(j);
            if !finer {
                // Counted as dropped above (the sums see coarsest senders only); kept after all.
                for (d, a) in dropped.iter_mut().zip(along_normal(&v, n)) {
                    *d -= a;
                }
            }
            links.push((j, v));
        }
        links.sort_unstable_by_key(|(s, _)| *s);
    }
    scratch.touched = touched;
    let mut kept = [0.0f64; 3];
    for (j, v) in &links {
        if *j < sender_coarsest {
            for (k, a) in kept.iter_mut().zip(along_normal(v, n)) {
                *k += a;
            }
        }
    }
    Processed {
        links,
        refine,
        counts,
        dropped,
        kept,
        gathered,
    }
}
