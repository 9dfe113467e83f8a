//! The transport precomputation (section 3): T by adaptive refinement, then S by the Neumann
//! series, stored sender-major with its statistics (the paper's Table 1 and more).

use std::time::Instant;

use mlt_format::adjacency::{children, neighbors};
use mlt_format::links::{Links, SenderLinks, LINK_DIM};
use mlt_format::meta::{TransportMeta, TransportParams, TransportStats, TransportTimings};
use mlt_format::{IndexedBasis, Transport};
use mlt_scenes::RayCaster;

use crate::error::BakeError;
use crate::neumann::{series, spectral_radius, BounceReceivers, Row};
use crate::observer::Observer;
use crate::refine::{refine, ReceiverLinks, RefineSettings, RefineStats};

/// The result, with what the user should be told.
pub struct TransportOutput {
    pub transport: Transport,
    /// Always measured; stored in the file only when timings are recorded.
    pub timings: TransportTimings,
    pub warnings: Vec<String>,
}

/// Checks the transport parameters against the basis.
pub fn check_params(p: &TransportParams, levels: u32) -> Result<(), BakeError> {
    let bad = |m: String| Err(BakeError::InvalidParameter(m));
    if !(p.epsilon.is_finite() && p.epsilon >= 0.0) {
        return bad(format!(
            "epsilon must be finite and >= 0, got {}",
            p.epsilon
        ));
    }
    if !(p.bounce_epsilon.is_finite() && p.bounce_epsilon >= 0.0) {
        return bad(format!(
            "the bounce epsilon must be finite and >= 0, got {}",
            p.bounce_epsilon
        ));
    }
    if p.sender_levels == 0 || p.sender_levels > levels {
        return bad(format!(
            "sender levels must be 1..={levels} (the receiver levels), got {}",
            p.sender_levels
        ));
    }
    if p.bounces == 0 {
        return bad("bounces must be at least 1".into());
    }
    if p.gather_rays == 0 {
        return bad("gather rays must be at least 1".into());
    }
    Ok(())
}

/// Peak resident memory of this process, where the platform tells (Linux).
pub fn peak_rss_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<u64>().ok())
        })
        .map(|kb| kb * 1024)
        .unwrap_or(0)
}

/// Computes S for `ib` (in the current rayon pool; the result does not depend on its size).
pub fn compute_transport(
    ib: &IndexedBasis,
    caster: &dyn RayCaster,
    params: TransportParams,
    obs: &dyn Observer,
) -> Result<TransportOutput, BakeError> {
    check_params(&params, ib.levels() as u32)?;
    let (t, rstats, refine_s) = refine_t(ib, caster, &params, None, obs);
    finish_transport(ib, t, rstats, params, refine_s, obs)
}

/// The refinement of T (optionally only of the receivers marked in `needed`, for a shard);
/// returns T, its counts and the seconds it took.
pub fn refine_t(
    ib: &IndexedBasis,
    caster: &dyn RayCaster,
    params: &TransportParams,
    needed: Option<&[bool]>,
    obs: &dyn Observer,
) -> (ReceiverLinks, RefineStats, f64) {
    obs.stage("refinement of T");
    let t0 = Instant::now();
    let nb = neighbors(ib);
    let ch = children(ib);
    let settings = RefineSettings {
        epsilon: params.epsilon,
        sender_levels: params.sender_levels as usize,
        gather_rays: params.gather_rays,
        seed: params.seed,
    };
    let levels = ib.levels();
    let (t, rstats) = refine(ib, caster, &nb, &ch, &settings, needed, |l, n, kept| {
        obs.progress(l as u64 + 1, levels as u64);
        obs.done(
            &format!("receiver level {l}"),
            t0.elapsed().as_secs_f64(),
            &format!("{n} receivers refined, {kept} links kept"),
        );
    });
    let refine_s = t0.elapsed().as_secs_f64();
    obs.done(
        "refinement of T",
        refine_s,
        &format!("{} links, {} rays", t.link_count(), rstats.rays),
    );
    (t, rstats, refine_s)
}

/// From T to the stored S: the spectral-radius check, the Neumann series, sender-major
/// packing and the statistics. Deterministic in `t` and `rstats` (a merge of shards calls it
/// with the shards' T and gets the single bake's S).
pub fn finish_transport(
    ib: &IndexedBasis,
    t: ReceiverLinks,
    rstats: RefineStats,
    params: TransportParams,
    refine_s: f64,
    obs: &dyn Observer,
) -> Result<TransportOutput, BakeError> {
    let t_start = Instant::now();
    let mut warnings = Vec::new();
    let b = &ib.basis;
    let levels = ib.levels();
    let senders = b.level_offsets[params.sender_levels as usize] as usize;
    let receivers = b.len();
    obs.stage("indirect bounces");
    let t1 = Instant::now();
    let rho = spectral_radius(ib, &t);
    // At 1 - 1e-4 the series would need some 10^5 bounces; treat it as divergent.
    if rho.is_nan() || rho >= 1.0 - 1e-4 {
        return Err(BakeError::Divergent {
            spectral_radius: rho,
        });
    }
    let bounce_receivers = if params.bounces_on_all_receivers {
        BounceReceivers::All
    } else {
        BounceReceivers::Coarsest
    };
    let (extra, report) = series(
        ib,
        &t,
        senders,
        params.bounces,
        params.bounce_epsilon,
        bounce_receivers,
        |b, kept| {
            obs.done(
                &format!("bounce {b}"),
                t1.elapsed().as_secs_f64(),
                &format!("{kept} links above epsilon"),
            )
        },
    );
    let bounces_s = t1.elapsed().as_secs_f64();
    let first = report.sum_norm.first().copied().unwrap_or(0.0);
    let last = report.sum_norm.last().copied().unwrap_or(0.0);
    if !report.converged_early && params.bounces > 1 && first > 0.0 && last > 0.01 * first {
        // Bounce b adds about rho^(b-1) of the first; the rest of the series about
        // rho^B / (1 - rho) of it.
        let missing = rho.powi(report.bounces as i32) / (1.0 - rho);
        let more = ((0.01f64).ln() / rho.ln()).ceil() as i64 - report.bounces as i64;
        let w = format!(
            "the Neumann series has not converged after {} bounces: the last adds {:.1} % of the first, and the bounces left out carry about {:.0} % of it (spectral radius {rho:.3}); about {} more bounces would bring a bounce below 1 %",
            report.bounces,
            100.0 * last / first,
            100.0 * missing,
            more.max(1)
        );
        obs.warn(&w);
        warnings.push(w);
    }
    obs.done(
        "indirect bounces",
        bounces_s,
        &format!("{} bounces, spectral radius {rho:.3}", report.bounces),
    );

    // S = T + the bounces, regrouped sender-major: every link as (sender, receiver, value),
    // sorted; a receiver holds at most one T link and one bounce link per sender, summed
    // (float addition of two terms is commutative, so the order does not matter).
    let extra_links: usize = extra.iter().map(|r| r.len()).sum();
    let mut triples: Vec<(u32, u32, [f32; LINK_DIM])> =
        Vec::with_capacity(t.link_count() + extra_links);
    for (row, &r) in t.rows.iter().enumerate() {
        let (a, e) = (t.offsets[row] as usize, t.offsets[row + 1] as usize);
        for (s, v) in t.senders[a..e].iter().zip(&t.values[a..e]) {
            triples.push((*s, r, *v));
        }
        for (s, v) in extra.get(row).map(|x| &x[..]).unwrap_or(&[]) {
            triples.push((*s, r, *v));
        }
    }
    triples.sort_unstable_by_key(|&(s, r, _)| (s, r));
    let mut s_per_level = vec![0u64; levels];
    let mut columns: Vec<(u32, Row)> = Vec::new();
    for (s, r, v) in triples {
        match columns.last_mut() {
            Some((cs, col)) if *cs == s => match col.last_mut() {
                Some((cr, cv)) if *cr == r => {
                    for k in 0..LINK_DIM {
                        cv[k] += v[k];
                    }
                    continue;
                }
                _ => col.push((r, v)),
            },
            _ => columns.push((s, vec![(r, v)])),
        }
        s_per_level[b.level_of(r as usize)] += 1;
    }
    let (links, qerr) = Links::pack(
        receivers as u32,
        senders as u32,
        columns.iter().map(|(s, col)| SenderLinks {
            sender: *s,
            links: col,
        }),
    );
    let links_bytes = mlt_format::file::archived_len(&links)?;
    let basis_bytes = mlt_format::file::basis_archived_len(ib)?;

    let stats = TransportStats {
        links: links.link_count() as u64,
        potential_links: senders as u64 * receivers as u64,
        t_links: t.link_count() as u64,
        senders: senders as u64,
        receivers: receivers as u64,
        visibility_rays: rstats.rays,
        unsupported_hits: rstats.unsupported_hits,
        receivers_refined: rstats.receivers_refined,
        t_links_per_level: rstats.links_per_level,
        s_links_per_level: s_per_level,
        bounces: report.bounces,
        bounce_max_norm: report.max_norm,
        bounce_sum_norm: report.sum_norm,
        bounce_kept_sum_norm: report.kept_sum_norm,
        spectral_radius: rho,
        quantisation_error: qerr,
        basis_bytes,
        links_bytes,
    };
    let timings = TransportTimings {
        refine_s,
        bounces_s,
        total_s: refine_s + t_start.elapsed().as_secs_f64(),
        peak_rss_bytes: peak_rss_bytes(),
        threads: rayon::current_num_threads() as u32,
    };
    Ok(TransportOutput {
        transport: Transport {
            meta: TransportMeta {
                params,
                stats,
                timings: None,
            },
            links,
        },
        timings,
        warnings,
    })
}
