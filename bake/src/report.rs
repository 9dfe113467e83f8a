//! Human-readable summaries: the table printed after a bake and `bake info`.

use std::fmt::Write;

use mlt_format::file::FileInfo;
use mlt_format::meta::{
    CameraCheck, Meta, RefinementDrop, Timings, TransportMeta, TransportReport, TransportTimings,
};

fn hms(s: f64) -> String {
    if s >= 60.0 {
        format!("{}:{:04.1}", (s / 60.0).floor() as u64, s % 60.0)
    } else {
        format!("{s:.2} s")
    }
}

/// Bytes in MB (10^6), as the paper's Table 1.
pub fn mb(bytes: u64) -> String {
    format!("{:.2} MB", bytes as f64 / 1e6)
}

/// The statistics table printed at the end of a bake.
pub fn bake_table(meta: &Meta, timings: &Timings, file_bytes: u64) -> String {
    let s = &meta.stats;
    let p = &meta.params;
    let mut o = String::new();
    let _ = writeln!(o, "scene         {}", meta.scene.source);
    let _ = writeln!(
        o,
        "triangles     {} ({} degenerate dropped)",
        meta.scene.triangles, meta.scene.degenerate_dropped
    );
    let _ = writeln!(
        o,
        "levels        {}   R_coarse {:.5}   C {}..{}   seed {}",
        p.levels, p.coarse_radius, p.c_coarse, p.c_fine, p.seed
    );
    let _ = writeln!(
        o,
        "candidates    {} from {} particles; rays {}",
        s.candidates, s.particles, s.rays
    );
    let _ = writeln!(
        o,
        "level   points   disk R     support r  darts      disk-rej   hmd-rej   growth"
    );
    for (l, ls) in s.levels.iter().enumerate() {
        let _ = writeln!(
            o,
            "{l:>5} {:>8}   {:<9.5}  {:<9.5}  {:<9}  {:<9}  {:<8}  {}",
            ls.points,
            ls.disk_radius,
            ls.support_radius,
            ls.darts,
            ls.disk_rejected,
            ls.hmd_rejected,
            if l == 0 {
                "-".to_string()
            } else {
                format!("{:.2}x", ls.growth)
            }
        );
    }
    let _ = writeln!(
        o,
        "basis         {} points (level 0: {}), {} R-tree nodes",
        s.points,
        s.levels.first().map(|l| l.points).unwrap_or(0),
        s.rtree_nodes
    );
    if s.points_without_coarser_support > 0 {
        let _ = writeln!(
            o,
            "unsupported   {} finer points outside every coarser support",
            s.points_without_coarser_support
        );
    }
    let _ = writeln!(
        o,
        "time          total {} = load {} + bvh {} + candidates {} + poisson disk {} + r-trees {} + write {}  ({} threads)",
        hms(timings.total_s),
        hms(timings.load_s),
        hms(timings.bvh_s),
        hms(timings.candidates_s),
        hms(timings.poisson_s),
        hms(timings.rtrees_s),
        hms(timings.write_s),
        timings.threads
    );
    if timings.total_s > 0.0 {
        let _ = writeln!(
            o,
            "rays/s        {:.0} (placement: candidates and harmonic-mean-distance rays over their time)",
            s.rays as f64 / (timings.candidates_s + timings.poisson_s).max(1e-9)
        );
    }
    let _ = writeln!(o, "file          {}", mb(file_bytes));
    o
}

/// The transport part of the table printed after a bake (the paper's Table 1 and more).
pub fn transport_table(t: &TransportMeta, timings: Option<&TransportTimings>) -> String {
    let s = &t.stats;
    let p = &t.params;
    let mut o = String::new();
    let _ = writeln!(
        o,
        "transport     epsilon {} (bounces: {})  levels {}/{} (rcvr/sndr)  bounces {} (max {})  gather rays {}{}",
        p.epsilon,
        p.bounce_epsilon,
        p.receiver_levels,
        p.sender_levels,
        s.bounces,
        p.bounces,
        p.gather_rays,
        if p.bounces_on_all_receivers {
            ", bounces on all receivers"
        } else {
            ""
        }
    );
    let _ = writeln!(
        o,
        "links         {} in S ({:.4} % of {} potential), {} in T",
        s.links,
        100.0 * s.links as f64 / s.potential_links.max(1) as f64,
        s.potential_links,
        s.t_links
    );
    let _ = writeln!(
        o,
        "rays          {} visibility rays; {} gather hits without sender support",
        s.visibility_rays, s.unsupported_hits
    );
    let _ = writeln!(o, "rcvr level    refined     T links     S links");
    for l in 0..s.receivers_refined.len() {
        let _ = writeln!(
            o,
            "{l:>10}    {:<10}  {:<10}  {}",
            s.receivers_refined[l],
            s.t_links_per_level.get(l).copied().unwrap_or(0),
            s.s_links_per_level.get(l).copied().unwrap_or(0)
        );
    }
    let mut norms: Vec<String> = s
        .bounce_sum_norm
        .iter()
        .zip(&s.bounce_kept_sum_norm)
        .map(|(all, kept)| format!("{kept:.3} of {all:.3}"))
        .collect();
    if norms.len() > 10 {
        // A long (auto) series: the first bounces and the last.
        let n = norms.len();
        let last = norms.split_off(n - 2);
        norms.truncate(6);
        norms.push(format!("... ({} more) ...", n - 8));
        norms.extend(last);
    }
    let _ = writeln!(
        o,
        "bounces       spectral radius {:.4}; sum of link norms per bounce, kept of computed: {}",
        s.spectral_radius,
        norms.join(", ")
    );
    let _ = writeln!(
        o,
        "memory        basis {} + links {} = {} (f16 links, max quantisation error {:.2e})",
        mb(s.basis_bytes),
        mb(s.links_bytes),
        mb(s.basis_bytes + s.links_bytes),
        s.quantisation_error
    );
    if let Some(t) = timings {
        let _ = writeln!(
            o,
            "transport time refinement {} + bounces {} = {}; {:.0} rays/s; peak memory {}",
            hms(t.refine_s),
            hms(t.bounces_s),
            hms(t.total_s),
            s.visibility_rays as f64 / t.refine_s.max(1e-9),
            mb(t.peak_rss_bytes)
        );
    }
    o
}

/// How a signed shortfall of the baked light (reference minus baked, over the reference)
/// reads after "too": "dark" when the baked light is short, "bright" when it is over.
pub(crate) fn too_dark_or_bright(shortfall: f64) -> &'static str {
    if shortfall >= 0.0 {
        "dark"
    } else {
        "bright"
    }
}

fn signed_pct(x: f64) -> String {
    if x > 0.0 {
        format!("+{}", pct(x))
    } else if x < 0.0 {
        format!("-{}", pct(-x))
    } else {
        pct(x)
    }
}

fn pct(x: f64) -> String {
    if x == 0.0 {
        "0 %".into()
    } else if x < 1e-6 {
        // A tail like rho^40 is zero for every purpose; its exponent would only distract.
        "< 0.0001 %".into()
    } else if x < 1e-4 {
        format!("{:.4} %", 100.0 * x)
    } else {
        format!("{:.2} %", 100.0 * x)
    }
}

/// The error estimate's total: the `TRPT` total (series tail, bounce truncation, storage) plus
/// the magnitude of the indirect light's share at the scene's camera
/// ([`CameraCheck::share_all`], `TCAM`), which holds the links of T dropped, the bounces, the
/// direct light's projection and the basis' reconstruction where the camera looks; in a file
/// without that check, plus the magnitude of what refinement dropped at the receivers
/// ([`RefinementDrop::share`], `TDRP`).
pub fn estimate_total(
    r: &TransportReport,
    drop: Option<&RefinementDrop>,
    check: Option<&CameraCheck>,
) -> f64 {
    r.error.total
        + match (check, drop) {
            (Some(c), _) => c.share_all.abs(),
            (None, Some(d)) => d.share.abs(),
            (None, None) => 0.0,
        }
}

/// The end of the bake's report: the bounce count chosen, the error it estimates it committed
/// to (with the light checked at the scene's camera, `TCAM`, and what refinement dropped
/// from T, `TDRP`, when the file has them), and what the file leaves out (the `TRPT` section).
pub fn estimate_table(
    r: &TransportReport,
    drop: Option<&RefinementDrop>,
    check: Option<&CameraCheck>,
) -> String {
    let e = &r.error;
    let l = &r.left_out;
    let mut o = String::new();
    let _ = writeln!(
        o,
        "series        {} bounces planned ({}{}), tolerance {}: {}",
        r.bounces_planned,
        r.bounce_mode,
        if r.bounce_mode == "auto" {
            format!(", cap {}", r.bounce_cap)
        } else {
            String::new()
        },
        pct(r.bounce_tolerance),
        if e.series_converged {
            "converged"
        } else {
            "NOT converged"
        }
    );
    let parts = format!(
        "series tail {} + bounce truncation {} + f16 storage {} (uniform emission)",
        pct(e.series_tail),
        pct(e.bounce_truncation),
        pct(e.quantisation)
    );
    let total = pct(estimate_total(r, drop, check));
    match (check, drop) {
        (Some(c), _) => {
            let _ = writeln!(
                o,
                "error est.    {total} of the indirect light = {parts} + indirect light at the camera {} +- {} (signed: the image is that much too {}; traced through {}x{} primary rays with {} paths each; the first bounce alone {} +- {} too {}: T's dropped links, the direct light's projection and the basis)",
                signed_pct(c.share_all),
                pct(c.std_error_all),
                too_dark_or_bright(c.share_all),
                c.width,
                c.height,
                c.rays,
                pct(c.share.abs()),
                pct(c.std_error),
                too_dark_or_bright(c.share)
            );
            if let Some(d) = drop {
                let _ = writeln!(
                    o,
                    "              links of T dropped, at the receivers: {} (under the {}; part of the camera's figure, not added)",
                    signed_pct(d.share),
                    d.emission
                );
            }
        }
        (None, Some(d)) => {
            let _ = writeln!(
                o,
                "error est.    {total} of the indirect light = {parts} + links of T dropped {} (signed, under the {}: the image is that much too {}); the basis' reconstruction error is not in it",
                signed_pct(d.share),
                d.emission,
                too_dark_or_bright(d.share)
            );
        }
        (None, None) => {
            let _ = writeln!(
                o,
                "error est.    {total} of the indirect light = {parts}; T's links dropped at epsilon and the basis' reconstruction error are not in it",
            );
        }
    }
    let linked: Vec<String> = l
        .receivers_linked_per_level
        .iter()
        .zip(&l.receivers_refined_per_level)
        .map(|(k, r)| format!("{k}/{r}"))
        .collect();
    let _ = writeln!(
        o,
        "left out      levels stored {} of {} ({} of {} points, {} saved); receivers with links / refined per level: {}",
        l.levels_stored,
        l.levels_placed,
        l.points_stored,
        l.points_placed,
        mb(l.level_bytes_saved),
        linked.join(", ")
    );
    let _ = writeln!(
        o,
        "              senders with links {} of {}; links {} stored vs {} dense",
        l.senders_linked,
        l.senders,
        mb(l.links_bytes),
        mb(l.dense_links_bytes)
    );
    o
}

/// `bake info`.
pub fn info_text(info: &FileInfo) -> String {
    let m = &info.meta;
    let mut o = String::new();
    let _ = writeln!(o, "file          {} ({})", info.path, mb(info.file_bytes));
    let _ = writeln!(
        o,
        "format        {}   written by {}",
        info.format_version, m.tool
    );
    let _ = writeln!(
        o,
        "scene         {}   hash {:016x}   {} triangles   scale {}",
        m.scene.source, m.scene.content_hash, m.scene.triangles, m.scene.scale
    );
    let _ = writeln!(o, "viewpoint     {:?}", m.scene.viewpoint);
    let _ = writeln!(
        o,
        "camera        {:?} -> {:?}  fovy {}  {}x{}",
        m.camera.position, m.camera.target, m.camera.fovy_deg, m.camera.width, m.camera.height
    );
    let _ = writeln!(
        o,
        "light         {} at {:?}, intensity {:?} W/sr",
        m.light.kind, m.light.position, m.light.intensity
    );
    let p = &m.params;
    let _ = writeln!(
        o,
        "parameters    levels {}  R_coarse {:.5}{}  F_squash {}  C {}..{}  misses {}  hmd {} rays x {}R, reject < {:.4}R  particles {} bounces (skip {})  seed {}",
        p.levels,
        p.coarse_radius,
        p.coarse_count_target.map(|k| format!(" (target {k} level-0 points)")).unwrap_or_default(),
        p.f_squash,
        p.c_coarse,
        p.c_fine,
        p.max_misses,
        p.hmd_rays,
        p.hmd_range,
        p.hmd_reject,
        p.particle_bounces,
        p.skipped_bounces,
        p.seed
    );
    let _ = writeln!(o, "points        {}", info.points);
    let _ = writeln!(o, "level   points   disk R     support r");
    for l in &info.levels {
        let _ = writeln!(
            o,
            "{:>5} {:>8}   {:<9.5}  {:<9.5}",
            l.level, l.points, l.disk_radius, l.support_radius
        );
    }
    let _ = writeln!(o, "section  offset      stored       raw          zstd");
    for s in &info.sections {
        let _ = writeln!(
            o,
            "{:<8} {:<11} {:<12} {:<12} {}",
            s.tag, s.offset, s.stored_bytes, s.raw_bytes, s.compressed
        );
    }
    if let Some(t) = &m.timings {
        let _ = writeln!(
            o,
            "recorded time total {} ({} threads)",
            hms(t.total_s),
            t.threads
        );
    }
    match &info.transport {
        Some(t) => o.push_str(&transport_table(t, t.timings.as_ref())),
        None => o.push_str("transport     none (basis only)\n"),
    }
    if let Some(r) = &info.report {
        o.push_str(&estimate_table(
            r,
            info.refinement_drop.as_ref(),
            info.camera_check.as_ref(),
        ));
    }
    if let Some(b) = &info.bounce_method {
        let _ = writeln!(
            o,
            "level 0's later bounces traced as paths ending in T: {} per receiver, bounces 2 to {} (--level0-paths)",
            b.level0_paths, b.max_vertex
        );
    }
    o
}
