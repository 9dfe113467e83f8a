//! The bake: scene to basis file contents.

use std::time::Instant;

use glam::Vec3;
use mlt_format::flat_section::{linked_flags, FlatSection};
use mlt_format::light::LightDesc;
use mlt_format::meta::{
    BasisParams, BasisStats, CameraInfo, LevelStats, LightInfo, Meta, SceneInfo, Timings,
    TransportParams, TransportTimings,
};
use mlt_format::shard::ShardSection;
use mlt_format::shepard::MIN_WEIGHT_SUM;
use mlt_format::{BakeContents, IndexedBasis, Transport};
use mlt_scenes::{LightKind, RayCaster, Scene};

use crate::candidates::CandidatePool;
use crate::coverage::{coverage_fills, with_fills};
use crate::error::BakeError;
use crate::observer::Observer;
use crate::occluders::clip_supports;
use crate::params::{bounce_policy, manifest_options, resolve, resolve_transport, BakeOptions};
use crate::placement::{find_coarse_radius, level_line, place, Coarse, LevelPlan};
use crate::poisson::DartSettings;
use crate::rng::mix64;
use crate::shard::{needed, owners, shard_section};
use crate::transport::{check_params, compute_transport, refine_t, trim_levels, BouncePolicy};

/// The tool name and version recorded in files.
pub fn tool_version() -> String {
    format!("mlt-bake {}", env!("CARGO_PKG_VERSION"))
}

/// The tool recorded in a file made with `opts`: [`tool_version`], followed by the refinement
/// rules turned off when a diagnostic bake turned any off, so that such a file says so.
pub fn tool_description(opts: &BakeOptions) -> String {
    if opts.refine_off.is_empty() || opts.basis_only {
        tool_version()
    } else {
        format!(
            "{} (refinement rules off: {})",
            tool_version(),
            refine_off_names(opts).join(",")
        )
    }
}

/// The names of the refinement rules `opts` turns off.
fn refine_off_names(opts: &BakeOptions) -> Vec<&'static str> {
    opts.refine_off.iter().map(|r| r.name()).collect()
}

/// What a bake produced.
pub struct BakeOutput {
    pub contents: BakeContents,
    /// Always taken; stored in the file only with `record_timings`.
    pub timings: Timings,
    pub transport_timings: Option<TransportTimings>,
    pub warnings: Vec<String>,
}

/// The input key of a bake: xxh3-64 of everything its file depends on: the tool version, the
/// scene's identity and content hash (mesh, material and texture bytes, manifest), its default
/// camera and light, and every resolved parameter. Equal keys mean byte-identical files.
pub fn input_key(scene: &Scene, opts: &BakeOptions) -> Result<u64, BakeError> {
    Ok(Resolved::new(scene, opts)?.key)
}

/// The options over the scene manifest's, resolved and checked, with the input key.
struct Resolved {
    opts: BakeOptions,
    params: BasisParams,
    coarse: Coarse,
    transport: TransportParams,
    policy: BouncePolicy,
    key: u64,
}

impl Resolved {
    fn new(scene: &Scene, opts: &BakeOptions) -> Result<Resolved, BakeError> {
        let opts = opts.or(&manifest_options(scene)?);
        let (params, coarse) = resolve(&opts)?;
        let transport = resolve_transport(&opts, &params);
        let policy = bounce_policy(&opts)?;
        let key = key_of(scene, &opts, &params, &transport, &policy);
        Ok(Resolved {
            opts,
            params,
            coarse,
            transport,
            policy,
            key,
        })
    }
}

/// [`input_key`] from parameters already resolved.
fn key_of(
    scene: &Scene,
    opts: &BakeOptions,
    params: &BasisParams,
    transport: &TransportParams,
    policy: &BouncePolicy,
) -> u64 {
    let transport = (!opts.basis_only).then_some(transport);
    let policy = (!opts.basis_only).then_some([
        if policy.auto { 1.0 } else { 0.0 },
        policy.tolerance,
        policy.level0_paths as f64,
    ]);
    let description = serde_json::json!({
        "tool": tool_version(),
        "format": [mlt_format::container::VERSION_MAJOR, mlt_format::container::VERSION_MINOR],
        "source": scene.source,
        "content_hash": scene.content_hash,
        "scale": scene.scale,
        "viewpoint": scene.viewpoint.to_array(),
        "camera": scene.camera,
        "light": scene.light,
        "basis": params,
        "transport": transport,
        "bounce_policy": policy,
        "record_timings": opts.record_timings,
        "compress": opts.compress,
    });
    let mut description = description;
    if !opts.refine_off.is_empty() {
        // Only when set, so that the default bakes' keys stay what they were.
        description["refine_off"] = serde_json::json!(refine_off_names(opts));
    }
    if opts.no_support_clip {
        description["no_support_clip"] = serde_json::json!(true);
    }
    xxhash_rust::xxh3::xxh3_64(description.to_string().as_bytes())
}

/// Bakes a loaded scene (in the current rayon pool; results do not depend on its size). The
/// options go over the scene manifest's `[bake]` table.
pub fn bake_scene(
    scene: &Scene,
    opts: &BakeOptions,
    obs: &dyn Observer,
) -> Result<BakeOutput, BakeError> {
    let t_total = Instant::now();
    let mut warnings = scene.warnings.clone();
    if let Some((index, count)) = opts.shard {
        if count == 0 || index >= count {
            return Err(BakeError::InvalidParameter(format!(
                "shard {index}/{count}: the index must be below the count"
            )));
        }
    }
    let Resolved {
        opts,
        mut params,
        coarse,
        transport: transport_params,
        policy,
        key,
    } = Resolved::new(scene, opts)?;
    if !opts.basis_only {
        // Refuse bad transport parameters before spending time on the basis.
        check_params(&transport_params, params.levels)?;
        if !opts.refine_off.is_empty() {
            warnings.push(format!(
                "refinement rules turned off (a diagnostic bake, not for use): {}",
                refine_off_names(&opts).join(", ")
            ));
        }
    }
    if !opts.basis_only {
        // An albedo of 1 or more: refused before any work (the bounces would not converge).
        warnings.extend(crate::albedo::check_albedo(scene)?);
    }
    let viewpoint = scene.viewpoint;
    if !viewpoint.is_finite() {
        return Err(BakeError::BadViewpoint {
            scene: scene.source.clone(),
            viewpoint: viewpoint.to_array(),
        });
    }

    obs.stage("ray-casting structure");
    let t = Instant::now();
    let caster = scene.build_caster();
    let bvh_s = t.elapsed().as_secs_f64();
    obs.done(
        "ray-casting structure",
        bvh_s,
        &format!("{} triangles", scene.triangle_count()),
    );

    // Every level: the senders, so that light is not emitted behind a wall, and the
    // receivers, so that their reconstruction (and the flat basis built on them) does not
    // show it there.
    let clip_levels = if opts.no_support_clip {
        0
    } else {
        params.levels as usize
    };
    let basis = place_basis(
        scene,
        caster.as_ref(),
        &mut params,
        (coarse, clip_levels),
        obs,
        &mut warnings,
    )?;

    let camera = camera_info(scene);
    let stage = transport_stage(
        basis.ib,
        caster.as_ref(),
        (&scene.light, &camera),
        &opts,
        transport_params,
        policy,
        key,
        obs,
    )?;
    warnings.extend(stage.warnings);
    let flat = flat_section(&stage.ib, stage.transport.as_ref(), obs)?;

    let timings = Timings {
        load_s: 0.0,
        bvh_s,
        candidates_s: basis.candidates_s,
        poisson_s: basis.poisson_s,
        rtrees_s: basis.rtrees_s,
        write_s: 0.0,
        total_s: t_total.elapsed().as_secs_f64(),
        threads: rayon::current_num_threads() as u32,
    };
    let meta = Meta {
        tool: tool_description(&opts),
        scene: scene_info(scene, caster.as_ref()),
        camera,
        light: light_info(scene),
        params,
        stats: basis.stats,
        timings: opts.record_timings.then_some(timings.clone()),
    };
    Ok(BakeOutput {
        contents: BakeContents {
            meta,
            basis: stage.ib,
            transport: stage.transport,
            input_key: stage.file_key,
            shard: stage.shard,
            flat,
        },
        timings,
        transport_timings: stage.timings,
        warnings,
    })
}

/// The `FLT2` section of a file with transport: the one-level flat basis on `ib` for the
/// receivers of `transport`'s links, which the viewer would otherwise build when it opens
/// the file. `None` without transport.
pub fn flat_section(
    ib: &IndexedBasis,
    transport: Option<&Transport>,
    obs: &dyn Observer,
) -> Result<Option<FlatSection>, BakeError> {
    let Some(t) = transport else {
        return Ok(None);
    };
    let t0 = Instant::now();
    let linked = linked_flags(ib.basis.len(), t.links.receiver_ids.iter().copied());
    let section = FlatSection::build(ib, &linked)?;
    obs.done(
        "flat basis",
        t0.elapsed().as_secs_f64(),
        &format!(
            "{} of {} points in the one-level basis",
            section.source.len(),
            ib.basis.len()
        ),
    );
    Ok(Some(section))
}

/// What the transport stage gave: the basis to store (finer levels without a link of S left
/// out), S or a shard of T, the file's input key, and the stage's timings and warnings.
struct TransportStage {
    ib: IndexedBasis,
    transport: Option<Transport>,
    shard: Option<ShardSection>,
    file_key: u64,
    timings: Option<TransportTimings>,
    warnings: Vec<String>,
}

/// The transport (section 3): none for a basis-only bake, T's rows of one shard for a shard
/// bake (whose file key mixes in the shard), else S. `light` is the representative emission
/// of the estimate of what refinement drops (`drop_estimate`); with `camera`, the scene's
/// camera, it is also what the light is checked under (`camera_check`).
#[allow(clippy::too_many_arguments)]
fn transport_stage(
    mut ib: IndexedBasis,
    caster: &dyn RayCaster,
    (light, camera): (&LightDesc, &CameraInfo),
    opts: &BakeOptions,
    transport_params: TransportParams,
    policy: BouncePolicy,
    key: u64,
    obs: &dyn Observer,
) -> Result<TransportStage, BakeError> {
    let mut transport = None;
    let mut shard = None;
    let mut file_key = key;
    let mut timings = None;
    let mut warnings = Vec::new();
    if let (false, Some((index, count))) = (opts.basis_only, opts.shard) {
        let owner = owners(&ib, count);
        let need = needed(&ib, &owner, index);
        // No traced level-0 bounces here: their paths end in the whole of T, so the merge
        // traces them (`shard::merge`).
        let refine = opts.refine_policy();
        let (t, _, _) = refine_t(
            &ib,
            caster,
            &transport_params,
            &refine,
            light,
            Some(&need),
            obs,
        )?;
        shard = Some(shard_section(
            &ib,
            &t,
            &owner,
            (index, count),
            key,
            transport_params,
            policy,
        ));
        file_key = mix64(key ^ mix64(((index as u64) << 32) | count as u64));
    } else if !opts.basis_only {
        let out = compute_transport(
            &ib,
            caster,
            (transport_params, &opts.refine_policy()),
            policy,
            light,
            camera,
            obs,
        )?;
        warnings = out.warnings;
        if out.levels_stored < ib.levels() {
            let placed = ib.levels();
            ib = trim_levels(&ib, out.levels_stored)?;
            obs.done(
                "levels left out",
                0.0,
                &format!(
                    "receiver levels {}..{placed} hold no link of S and are not stored",
                    out.levels_stored
                ),
            );
        }
        let mut t = out.transport;
        if opts.record_timings {
            t.meta.timings = Some(out.timings.clone());
        }
        timings = Some(out.timings);
        transport = Some(t);
    }
    Ok(TransportStage {
        ib,
        transport,
        shard,
        file_key,
        timings,
        warnings,
    })
}

/// The placed and indexed basis, with its statistics and timings.
struct PlacedBasis {
    ib: IndexedBasis,
    stats: BasisStats,
    candidates_s: f64,
    poisson_s: f64,
    rtrees_s: f64,
}

/// Point placement (section 2.3): importance candidates from the viewpoint, the coarse radius,
/// the levels' Poisson-disk sets, and their R-trees. Sets `params.coarse_radius` (and
/// `skipped_bounces` for an open scene).
fn place_basis(
    scene: &Scene,
    caster: &dyn RayCaster,
    params: &mut BasisParams,
    (coarse, clip_levels): (Coarse, usize),
    obs: &dyn Observer,
    warnings: &mut Vec<String>,
) -> Result<PlacedBasis, BakeError> {
    let viewpoint = scene.viewpoint;
    let mut pool = first_candidates(scene, caster, params, obs, warnings)?;
    let first_batch_s = pool.seconds;
    let settings = DartSettings {
        max_misses: params.max_misses,
        hmd_rays: params.hmd_rays,
        hmd_range: params.hmd_range,
        hmd_reject: params.hmd_reject,
        seed: params.seed,
    };
    obs.stage("poisson disk");
    let t = Instant::now();
    let r_coarse = match coarse {
        Coarse::Radius(r) => r,
        Coarse::Count(k) => {
            let (r, n) = find_coarse_radius(&mut pool, caster, k, &settings);
            obs.done(
                "coarse radius search",
                t.elapsed().as_secs_f64(),
                &format!("R_coarse = {r:.5} gives {n} level-0 points (asked {k})"),
            );
            r
        }
    };
    params.coarse_radius = r_coarse;
    let levels = params.levels as usize;
    let mut placement = place(
        &mut pool,
        caster,
        LevelPlan {
            levels,
            r_coarse,
            c_coarse: params.c_coarse,
            c_fine: params.c_fine,
        },
        &settings,
        |l, s| obs.step(l as u64 + 1, levels as u64, &level_line(l, s)),
    );
    // Candidates are also generated lazily inside the dart thrower; count that time there.
    let candidates_s = pool.seconds;
    let poisson_s = t.elapsed().as_secs_f64() - (pool.seconds - first_batch_s);
    for w in pool.notes() {
        obs.warn(&w);
        warnings.push(w);
    }
    for &l in &placement.dry_levels {
        let w = format!(
            "level {l}: the candidate pool stopped growing before the level saturated; it may be sparser than its radius allows"
        );
        obs.warn(&w);
        warnings.push(w);
    }
    if placement.basis.level_range(0).is_empty() {
        return Err(BakeError::NoCandidates {
            scene: scene.source.clone(),
            viewpoint: viewpoint.to_array(),
        });
    }
    let counts: Vec<String> = placement
        .levels
        .iter()
        .map(|s| s.points.to_string())
        .collect();
    obs.done(
        "poisson disk",
        poisson_s,
        &format!("points per level: {}", counts.join(" / ")),
    );

    obs.stage("r-trees");
    let t = Instant::now();
    let ib = cover_coarser_levels(
        IndexedBasis::build(placement.basis)?,
        &mut placement.levels,
        obs,
    )?;
    let rtrees_s = t.elapsed().as_secs_f64();
    let rtree_nodes: u64 = ib.trees.iter().map(|t| t.node_count() as u64).sum();
    obs.done("r-trees", rtrees_s, &format!("{rtree_nodes} nodes"));
    let ib = clip_sender_supports(ib, caster, clip_levels, &mut placement.levels, obs)?;

    if let Some(w) = light_warning(scene, caster) {
        obs.warn(&w);
        warnings.push(w);
    }

    let unsupported = count_points_without_coarser_support(&ib);
    let points_placed = ib.basis.len() as u64;
    if unsupported > 0 {
        let w = format!(
            "{unsupported} points of finer levels lie where no coarser level has support; their coefficients carry the full value there"
        );
        obs.warn(&w);
        warnings.push(w);
    }
    let stats = BasisStats {
        particles: pool.particles,
        candidates: pool.candidates.len() as u64,
        rays: pool.rays + placement.hmd_rays,
        points: points_placed,
        levels: placement.levels,
        rtree_nodes,
        points_without_coarser_support: unsupported,
    };
    Ok(PlacedBasis {
        ib,
        stats,
        candidates_s,
        poisson_s,
        rtrees_s,
    })
}

/// The candidate pool with its first batch of importance particles; the dart thrower grows it
/// lazily from there. An open scene whose particles all escape before the skipped bounces end
/// gets candidates from the first hit on (`params.skipped_bounces` set to 0, with a warning).
fn first_candidates<'a>(
    scene: &Scene,
    caster: &'a dyn RayCaster,
    params: &mut BasisParams,
    obs: &dyn Observer,
    warnings: &mut Vec<String>,
) -> Result<CandidatePool<'a>, BakeError> {
    let viewpoint = scene.viewpoint;
    obs.stage("candidates");
    let mut pool = CandidatePool::new(
        caster,
        viewpoint,
        params.seed,
        params.particle_bounces,
        params.skipped_bounces,
    );
    while pool.candidates.is_empty() {
        if pool.grow() == 0 && pool.particles >= 1 << 16 {
            if pool.hits == 0 || params.skipped_bounces == 0 {
                return Err(BakeError::NoCandidates {
                    scene: scene.source.clone(),
                    viewpoint: viewpoint.to_array(),
                });
            }
            // An open scene (a single quad, say): particles reach surfaces but escape before
            // the skipped bounces end. Deposit from the first hit instead, and say so.
            let w = format!(
                "no particle path survived the first {} bounces (an open scene?); candidates are deposited from the first bounce on",
                params.skipped_bounces
            );
            obs.warn(&w);
            warnings.push(w);
            params.skipped_bounces = 0;
            pool = CandidatePool::new(caster, viewpoint, params.seed, params.particle_bounces, 0);
        }
    }
    obs.done(
        "candidates",
        pool.seconds,
        &format!(
            "{} candidates from {} particles",
            pool.candidates.len(),
            pool.particles
        ),
    );
    Ok(pool)
}

fn scene_info(scene: &Scene, caster: &dyn RayCaster) -> SceneInfo {
    let (bounds_min, bounds_max) = caster.bounds();
    SceneInfo {
        source: scene.source.clone(),
        content_hash: scene.content_hash,
        triangles: scene.triangle_count(),
        degenerate_dropped: match &scene.geometry {
            mlt_scenes::Geometry::Mesh(m) => m.degenerate_dropped,
            _ => 0,
        },
        scale: scene.scale,
        viewpoint: scene.viewpoint.to_array(),
        bounds_min: bounds_min.to_array(),
        bounds_max: bounds_max.to_array(),
    }
}

/// The scene's camera as the file stores it.
fn camera_info(scene: &Scene) -> CameraInfo {
    CameraInfo {
        position: scene.camera.position,
        target: scene.camera.target,
        up: scene.camera.up,
        fovy_deg: scene.camera.fovy_deg,
        width: scene.camera.width,
        height: scene.camera.height,
    }
}

fn light_info(scene: &Scene) -> LightInfo {
    LightInfo::from(&scene.light)
}

/// Rays cast from the light to see whether it lights anything.
const LIGHT_PROBE_RAYS: u32 = 1024;

/// A warning when the scene's default light reaches no surface: a spot pointing at nothing,
/// a point light beside an open scene. `LIGHT_PROBE_RAYS` rays in the cone (or
/// over the sphere) from the light; none hitting a surface means the
/// default light gives a black image (the bake itself does not depend on the light).
pub fn light_warning(scene: &Scene, caster: &dyn RayCaster) -> Option<String> {
    let l = &scene.light;
    let origin = Vec3::from(l.position);
    let (axis, cos_max) = match (l.kind, l.direction, l.cone_deg) {
        (LightKind::Spot, Some(d), Some(c)) => (
            Vec3::from(d).normalize_or_zero(),
            (0.5 * c).to_radians().cos(),
        ),
        _ => (Vec3::Z, -1.0),
    };
    if axis == Vec3::ZERO || !origin.is_finite() {
        return None;
    }
    let mut rng = crate::rng::Rng::new(1, crate::rng::Stream::Hmd, u64::MAX);
    for _ in 0..LIGHT_PROBE_RAYS {
        let d = mlt_scenes::sampling::uniform_cone(axis, cos_max, rng.next_f32(), rng.next_f32());
        if caster.intersect(origin, d, 0.0, f32::INFINITY).is_some() {
            return None;
        }
    }
    let what = if l.kind == LightKind::Spot {
        "spot light"
    } else {
        "point light"
    };
    Some(format!(
        "{}: the default {what} at {:?} lights no surface ({LIGHT_PROBE_RAYS} rays{} hit nothing): its images will have no direct or indirect light",
        scene.source,
        l.position,
        if l.kind == LightKind::Spot {
            " in its cone"
        } else {
            ""
        }
    ))
}

/// Points of levels >= 1 at which no coarser level has support.
/// The basis with the holes of its coarser levels filled ([`crate::coverage`]), the level
/// statistics' point counts updated; reports how many points were added.
fn cover_coarser_levels(
    ib: IndexedBasis,
    levels: &mut [LevelStats],
    obs: &dyn Observer,
) -> Result<IndexedBasis, BakeError> {
    let fills = coverage_fills(&ib);
    let added: Vec<usize> = fills.iter().map(|f| f.len()).collect();
    if added.iter().all(|&n| n == 0) {
        return Ok(ib);
    }
    count_fills(levels, &added);
    let per_level: Vec<String> = added.iter().map(|n| n.to_string()).collect();
    obs.done(
        "coverage",
        0.0,
        &format!(
            "points added where a coarser level left finer points uncovered, per level: {}",
            per_level.join(" / ")
        ),
    );
    Ok(IndexedBasis::build(with_fills(&ib.basis, &fills))?)
}

/// The supports of levels `0..levels` clipped at the occluders their points see
/// ([`crate::occluders`]); the coverage of the coarser levels filled again where the clipping
/// opened holes (a floor by a wall whose coarse functions stood on the other side), and the
/// planes computed again for the basis with the fills.
fn clip_sender_supports(
    ib: IndexedBasis,
    caster: &dyn RayCaster,
    levels: usize,
    stats: &mut [LevelStats],
    obs: &dyn Observer,
) -> Result<IndexedBasis, BakeError> {
    if levels == 0 {
        return Ok(ib);
    }
    obs.stage("support clipping");
    let t = Instant::now();
    let clip = clip_supports(&ib, caster, levels);
    let ib = ib.with_clip(clip)?;
    let fills = coverage_fills(&ib);
    let added: Vec<usize> = fills.iter().map(|f| f.len()).collect();
    let ib = if added.iter().all(|&n| n == 0) {
        ib
    } else {
        count_fills(stats, &added);
        let ib = IndexedBasis::build(with_fills(&ib.basis, &fills))?;
        let clip = clip_supports(&ib, caster, levels);
        ib.with_clip(clip)?
    };
    let clipped_points = ib.basis.level_offsets[levels.min(ib.levels())] as usize;
    let per_level: Vec<String> = added.iter().take(levels).map(|n| n.to_string()).collect();
    obs.done(
        "support clipping",
        t.elapsed().as_secs_f64(),
        &format!(
            "{} of {clipped_points} supports clipped by {} planes; points added to cover, per level: {}",
            ib.clip.clipped_points(),
            ib.clip.planes.len(),
            per_level.join(" / ")
        ),
    );
    Ok(ib)
}

/// The level statistics with `added` coverage fills per level: point counts and growths.
fn count_fills(levels: &mut [LevelStats], added: &[usize]) {
    for (s, n) in levels.iter_mut().zip(added) {
        s.points += *n as u64;
    }
    for l in 1..levels.len() {
        levels[l].growth = levels[l].points as f32 / levels[l - 1].points.max(1) as f32;
    }
}

fn count_points_without_coarser_support(ib: &IndexedBasis) -> u64 {
    let b = &ib.basis;
    let mut count = 0;
    for l in 1..b.levels() {
        for j in b.level_range(l) {
            let supported =
                (0..l).any(|k| ib.weight_sum(k, b.positions[j], b.normals[j]) > MIN_WEIGHT_SUM);
            if !supported {
                count += 1;
            }
        }
    }
    count
}
