//! Per-frame relighting on the CPU (Lehtinen et al. 2008, section 3.3), behind the
//! [`Relight`] interface so that a GPU compute version can replace it, in four steps:
//! 1. direct irradiance at the sender points from the light, visibility averaged over several
//!    jittered shadow rays per point (as the tech report, against binary flicker): the rays
//!    leave the sender point and end at points spread around the light, over a disk facing the
//!    point of radius half the sender level's disk radius (at most a quarter of the distance,
//!    and at most half the light's distance to the surfaces near it, which the rays must not
//!    pass behind),
//!    so that visibility is averaged over about the sender's footprint. (Jittering the start
//!    points over the tangent plane instead leaves curved surfaces and shadows them.) Half of
//!    the rays, spread over the disk, go first; where they all agree the point is taken as
//!    wholly lit or shadowed, and the other half is cast only in the penumbra. Points whose
//!    sample the pull-push replaces by their children's average cast no rays. Within a few
//!    support radii of the light the unoccluded irradiance at the point is replaced by its
//!    average over the point's basis function ([`SupportAverage`]), so that a hot spot
//!    narrower than the spacing of the points keeps its flux.
//! 2. pull-push projection onto the sender levels, `e = P-dagger E` (section 2.1), with the
//!    weights precomputed ([`PullPushOp`]);
//! 3. `i = S e`, receiver-major in `f32` arithmetic ([`ReceiverLinks`]), skipping senders whose
//!    light is negligible; then, when [`CpuRelighter::fine_bounces`] is set, the finer
//!    receivers' bounces 2 and later, from the indirect light at every sender point through
//!    their whole rows ([`FineEmission::Senders`]; with [`CpuRelighter::lagged_feedback`]
//!    the previous frame's, added to `e` for the finer rows in the one pass of `S e`) or from the level-0
//!    coefficients through their links to level-0 senders ([`FineBounceOp`]), and,
//!    with [`CpuRelighter::bounce_feedback`], the finer receivers' bounce light re-emitted
//!    through `S`'s level-0 rows ([`BounceFeedbackOp`]: `i` as the fixed point of
//!    `i = S (e + P-dagger (n . R i) - y(i))`);
//! 4. flattening of `i` to the flat basis (section 4.1: one level on the points the solution
//!    needs, [`FlatBasis`]) by a precomputed sparse operator ([`FlattenOp`], one row per flat
//!    point) that holds only the columns of receivers with links, then a few steps of
//!    iterated Shepard correction `c_{k+1} = c_k + w_k (c_0 - W c_k)` ([`SharpenOp`]) that take
//!    back most of the flat basis' smoothing. With a view ([`Relight::set_view`]) only the
//!    rows of the flat points whose functions may meet it, and those their sharpening reads,
//!    are computed ([`FlatCulling`]); a view that needs rows the light's frame lacks has them
//!    computed from the kept `i` without relighting.
//!
//! The operators are built once, in [`CpuRelighter::new`] (timed in [`LoadStats`]). When the
//! light has not moved, nothing is recomputed.

use std::sync::{Arc, OnceLock};
use std::time::Instant;

use glam::Vec3;
use mlt_format::flat_basis::FlatBasis;
use mlt_format::links::{ArchivedLinks, LINK_DIM};
use mlt_format::meta::{BounceMethod, TransportMeta};
use mlt_format::IndexedBasis;
use mlt_scenes::RayCaster;
use rayon::prelude::*;
use serde::Serialize;

use crate::bounce_feedback::BounceFeedbackOp;
use crate::error::RelightError;
use crate::fine_bounce::FineBounceOp;
use crate::flatten_op::{FlattenOp, FlattenScratch, SharpenOp, SharpenScratch};
use crate::frustum::Frustum;
use crate::light::Light;
use crate::pull_push_op::PullPushOp;
use crate::receiver_links::ReceiverLinks;
use crate::relight::{Frame, Relight, StageTimes};
use crate::support_average::SupportAverage;
use crate::view_cull::{FlatCulling, ViewMasks};

/// Steps of the bounce-light feedback a file with the chain of bounces gets by default
/// ([`CpuRelighter::use_bounce_corrections`]).
pub const DEFAULT_FEEDBACK_STEPS: u32 = 1;

/// What building the relighter's operators cost, once per loaded file.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct LoadStats {
    /// Wall time of [`CpuRelighter::new`], milliseconds.
    pub build_ms: f64,
    /// Of which the flat basis (when built) and the flattening operator.
    pub flatten_build_ms: f64,
    /// Wall time of [`CpuRelighter::build_support_tables`] when it was called, milliseconds.
    pub support_tables_ms: f64,
    /// Points of the flat basis (of the hierarchical basis's points).
    pub flat_points: usize,
    /// Whether the flat basis was read from the file (`FLAT`) rather than built.
    pub flat_stored: bool,
    /// Columns and entries of the flattening operator, and its heap bytes.
    pub flatten_columns: usize,
    pub flatten_entries: usize,
    pub flatten_bytes: usize,
    /// Entries of the sharpening step's smoothing operator `W`, and its heap bytes.
    pub sharpen_entries: usize,
    pub sharpen_bytes: usize,
    /// Heap bytes of the precomputed pull-push.
    pub pull_push_bytes: usize,
    /// Heap bytes of the receiver-major decoded links.
    pub links_bytes: usize,
    /// Links of the receiver-major rows summed eight rows at a time (the nearly dense
    /// coarsest rows, [`ReceiverLinks::grouped_links`]), of all the links.
    pub links_grouped: usize,
    pub links_total: usize,
    /// Entries of the bounce-light feedback's reconstruction at the sender points, and their
    /// heap bytes ([`BounceFeedbackOp`]; it applies the level-0 rows of the links above).
    pub feedback_entries: usize,
    pub feedback_bytes: usize,
    /// Sender points that cast shadow rays (the others are pulled from their children).
    pub direct_points: usize,
    /// Whether the file stores each level's points in Morton order (as the bake writes them);
    /// flattening is slower otherwise.
    pub points_in_morton_order: bool,
}

/// The CPU's part of a GPU's step 1 ([`CpuRelighter::near_light`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NearLight {
    /// The surface nearest the light, its height and normal: the shadow rays' clearance.
    pub clearance: Option<(f32, Vec3)>,
    /// The sender points near the light, with their samples blended toward the support
    /// average (before visibility).
    pub samples: Vec<(u32, [f32; 3])>,
}

/// How the finer receivers' bounces 2 and later are emitted (step 3), for a file whose `S`
/// computed them on the coarsest receivers only.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub enum FineEmission {
    /// The indirect light of `i = S e` at every sender point (Eq. 6 over every level, along
    /// the point's normal), pull-pushed onto the sender levels as the direct light is (the
    /// `P-dagger (n . R i)` of [`BounceFeedbackOp::emission`]), through the finer receivers'
    /// whole rows of `S` (T's rows: links to every sender level); the level-0 rows, which hold
    /// every bounce, are left as they are. The bounce light's detail (a lit floor against a
    /// dark arch) is then emitted by the finer senders' differences as the direct light's is.
    /// Costs about the finer rows' share of one `S e` more per frame. Not with the bounce-light
    /// feedback, whose correction is built on [`FineEmission::Level0`].
    #[default]
    Senders,
    /// The level-0 coefficients, `n_j . i_j`, through the finer receivers' links to level-0
    /// senders only ([`FineBounceOp`]): cheaper; on Sponza about 0.011 worse per pixel.
    Level0,
}

/// The CPU implementation.
pub struct CpuRelighter<'a> {
    ib: &'a IndexedBasis,
    links: &'a ArchivedLinks,
    caster: &'a dyn RayCaster,
    sender_levels: usize,
    shadow_rays: u32,
    pull_push: PullPushOp,
    /// Per sender point: whether its direct sample is used (cast rays only there).
    sample_used: Vec<bool>,
    support: SupportAverage<'a>,
    receiver_links: ReceiverLinks,
    /// Built on first use: only the level-0 emission and the bounce-light feedback need it.
    fine_bounce: OnceLock<FineBounceOp>,
    feedback: BounceFeedbackOp,
    /// The flat basis the frames' flat coefficients belong to.
    flat: FlatBasis,
    /// `None` only if the operator is too large for 32-bit offsets: then
    /// [`FlatBasis::flatten`] runs.
    flatten_op: Option<FlattenOp>,
    flatten_scratch: FlattenScratch,
    /// The sharpening step after flattening (`None` only if `W` is too large for 32-bit
    /// offsets).
    sharpen_op: Option<SharpenOp>,
    sharpen_scratch: SharpenScratch,
    load: LoadStats,
    /// Senders whose largest direct channel is at most this fraction of the frame's largest
    /// are skipped in `i = S e`.
    pub skip_fraction: f32,
    /// Cast half of the shadow rays first and the other half only where those disagree
    /// (step 1; on with 4 or more rays).
    pub adaptive_shadows: bool,
    /// Near the light, average the irradiance over each sender's basis function instead of
    /// sampling it at the point, and keep the shadow rays' ends in front of the surfaces near
    /// the light (step 1). Off, the samples are the irradiance at the points.
    pub support_average: bool,
    /// When false and the precomputed operator exists, step 4 is left to the caller (the
    /// renderer's GPU compute pass applies [`CpuRelighter::flatten_op`] to `Frame::i`), and
    /// `Frame::flat` is empty.
    pub flatten_on_cpu: bool,
    /// Sharpen the flat coefficients after flattening (step 4); off, they are the exact
    /// values of Eq. 6 at the flat points, which the flat basis then smooths.
    pub sharpen: bool,
    /// Add bounces 2 and later at the finer receivers after `i = S e` (step 3). Off by
    /// default: set it for a file whose `S` computed them on the coarsest receivers only
    /// ([`FineBounceOp::applies_to`] on its transport metadata).
    pub fine_bounces: bool,
    /// How step 3 emits the bounce light the finer receivers' later bounces come from
    /// ([`FineEmission`]).
    pub fine_emission: FineEmission,
    /// Steps of the bounce-light feedback after step 3 ([`BounceFeedbackOp`]): the finer
    /// receivers' bounce light re-emitted through `S`'s level-0 rows. 0 (the default) leaves
    /// it out; set it (1 is enough) for a file whose `S` chained its bounces through the
    /// coarsest receivers ([`FineBounceOp::applies_to`]).
    pub bounce_feedback: u32,
    /// Lagged bounce light, for interactive use: the emission that step 3 computes from the
    /// frame's own `S e` is taken from the previous frame instead, in the same pass over the
    /// links as `S e`, and the frame's is kept for the next. With `bounce_feedback` above 0
    /// that is the feedback's correction, which the level-0 rows of `S` take (the fine
    /// bounces then come with the frame's own); without it, when the fine bounces re-emit
    /// the bounce light from every sender point ([`FineEmission::Senders`], files whose
    /// level-0 rows were traced as paths), that emission `y`, which the finer rows (`T`'s)
    /// take added to `e`: one product `T_fine (e + y)` where the exact frame has two, `S e`
    /// and then `T_fine y` of its `S e`. The lagged `y` is the emission of the previous
    /// frame's whole `i`, the finer receivers' later bounces included, which the exact frame's
    /// `y` (of `S e`) leaves out: frame after frame the finer rows iterate toward the fixed
    /// point `i_fine = T_fine (e + y(i))`, the fuller solution (a step shrinks the distance to
    /// it about fivefold; on the small Cornell box of the tests the fixed point lies 3.5 %
    /// relative RMS from the exact frame, its mean 0.5 % above). A moving light's lagged part
    /// is one frame late; when the light stops, the next call for it relights once more with
    /// its own (a further step of either fixed point, nearer to it than the exact frame) and
    /// later calls reuse that frame. The first frame, and the first after
    /// [`CpuRelighter::reset_lag`], is computed exactly. Off by default.
    pub lagged_feedback: bool,
    /// The previous frame's feedback correction (lagged feedback).
    feedback_prev: Option<Vec<f32>>,
    /// The previous frame's fine-bounce emission `y` (lagged fine bounces).
    fine_prev: Option<Vec<f32>>,
    /// False after a frame that took a correction computed under another light: the same
    /// light again is then relit once more (with its own correction) instead of reused.
    lag_settled: bool,
    /// The light of the frame that computed the lagged parts held for the next frame
    /// (`feedback_prev`, `fine_prev`): they are a frame's own when its light is this one.
    /// Kept apart from `last`, which [`Relight::set_flatten_on_cpu`] forgets to force a
    /// recomputation without making the lagged parts stale.
    lag_light: Option<Light>,
    /// The view the flat coefficients are for ([`Relight::set_view`]): with one, step 4
    /// computes only the rows it needs; without, every row.
    view: Option<Frustum>,
    /// Built on the first frame with a view; `None` inside where the operators' layout allows
    /// no culling ([`FlatCulling::build`]).
    culling: OnceLock<Option<FlatCulling>>,
    /// The view and rows of `frame.flat` that hold the coefficients of `frame`'s light;
    /// `None`: all.
    flat_done: Option<(Frustum, Arc<ViewMasks>)>,
    /// The rows step 4 computed for the last view (the dilation through `W` is redone only
    /// when the view or the number of sharpening steps changes).
    masks_cache: Option<(Frustum, usize, Arc<ViewMasks>)>,
    /// Compute step 4 only for the view set with [`Relight::set_view`] (on by default; off,
    /// every flat point's coefficients are computed whatever the view).
    pub view_culling: bool,
    frame: Frame,
    last: Option<Light>,
}

impl<'a> CpuRelighter<'a> {
    /// Builds the per-file operators (in parallel; the same for any thread count). `links`
    /// must be validated. Fails when the flat basis cannot be built on `ib`.
    pub fn new(
        ib: &'a IndexedBasis,
        links: &'a ArchivedLinks,
        caster: &'a dyn RayCaster,
        sender_levels: usize,
        shadow_rays: u32,
    ) -> Result<CpuRelighter<'a>, RelightError> {
        Self::with_flat_basis(ib, links, caster, sender_levels, shadow_rays, None)
    }

    /// [`CpuRelighter::new`] with the flat basis given (as a file's `FLAT` section stores it,
    /// [`mlt_format::BakedFile::flat_basis`]) instead of built; `None` builds it. A given flat
    /// basis must be the one of `ib` and the receivers of `links`.
    pub fn with_flat_basis(
        ib: &'a IndexedBasis,
        links: &'a ArchivedLinks,
        caster: &'a dyn RayCaster,
        sender_levels: usize,
        shadow_rays: u32,
        stored: Option<FlatBasis>,
    ) -> Result<CpuRelighter<'a>, RelightError> {
        let t0 = Instant::now();
        let sender_levels = sender_levels.min(ib.levels());
        let flat_stored = stored.is_some();
        let (
            ((pull_push, feedback), receiver_links),
            (flat, (flatten_op, sharpen_op), flatten_build_ms),
        ) = rayon::join(
            || {
                rayon::join(
                    || {
                        rayon::join(
                            || PullPushOp::build(ib, sender_levels),
                            || BounceFeedbackOp::build(ib, links, sender_levels),
                        )
                    },
                    || ReceiverLinks::build(links),
                )
            },
            || {
                let t = Instant::now();
                // Only receivers with links can have a non-zero coefficient.
                let keep = links.linked_flags(ib.basis.len());
                let flat = match stored {
                    Some(flat) => Ok(flat),
                    None => FlatBasis::build(ib, Some(&keep)),
                };
                let ops = match flat.as_ref() {
                    Ok(flat) => rayon::join(
                        || FlattenOp::build(ib, flat, Some(&keep)).ok(),
                        || SharpenOp::build(flat).ok(),
                    ),
                    Err(_) => (None, None),
                };
                (flat, ops, t.elapsed().as_secs_f64() * 1e3)
            },
        );
        let flat = flat?;
        let sample_used = pull_push.sample_used();
        let load = LoadStats {
            build_ms: t0.elapsed().as_secs_f64() * 1e3,
            flatten_build_ms,
            support_tables_ms: 0.0,
            flat_points: flat.len(),
            flat_stored,
            flatten_columns: flatten_op.as_ref().map_or(0, FlattenOp::columns),
            flatten_entries: flatten_op.as_ref().map_or(0, FlattenOp::entries),
            flatten_bytes: flatten_op.as_ref().map_or(0, FlattenOp::bytes),
            sharpen_entries: sharpen_op.as_ref().map_or(0, SharpenOp::entries),
            sharpen_bytes: sharpen_op.as_ref().map_or(0, SharpenOp::bytes),
            pull_push_bytes: pull_push.bytes(),
            links_bytes: receiver_links.bytes(),
            links_grouped: receiver_links.grouped_links(),
            links_total: receiver_links.link_count(),
            feedback_entries: feedback.entries(),
            feedback_bytes: feedback.bytes(),
            direct_points: sample_used.iter().filter(|u| **u).count(),
            points_in_morton_order: flatten_op.as_ref().is_some_and(FlattenOp::in_point_order),
        };
        Ok(CpuRelighter {
            ib,
            links,
            caster,
            sender_levels,
            shadow_rays: shadow_rays.max(1),
            pull_push,
            sample_used,
            support: SupportAverage::new(ib, pull_push_points(ib, sender_levels)),
            receiver_links,
            fine_bounce: OnceLock::new(),
            feedback,
            flat,
            flatten_op,
            flatten_scratch: FlattenScratch::default(),
            sharpen_op,
            sharpen_scratch: SharpenScratch::default(),
            load,
            skip_fraction: 1e-4,
            adaptive_shadows: true,
            support_average: true,
            flatten_on_cpu: true,
            sharpen: true,
            fine_bounces: false,
            fine_emission: FineEmission::default(),
            bounce_feedback: 0,
            lagged_feedback: false,
            feedback_prev: None,
            fine_prev: None,
            lag_settled: true,
            lag_light: None,
            view: None,
            culling: OnceLock::new(),
            flat_done: None,
            masks_cache: None,
            view_culling: true,
            frame: Frame::default(),
            last: None,
        })
    }

    /// Turns on the per-frame corrections of a bake's chain of bounces through the coarsest
    /// receivers, as the viewer relights a file with transport metadata `tm` and `TBNC`
    /// section `traced`: the fine bounces where [`FineBounceOp::applies_to`] it, and with them
    /// `feedback_steps` steps of the bounce-light feedback (which re-emits the light the fine
    /// bounces add), by default [`DEFAULT_FEEDBACK_STEPS`], or none where the level-0 rows were
    /// traced as paths: those rows hold every bounce already, and re-emitting through them
    /// would count the later bounces twice. Both stay off for other files.
    pub fn use_bounce_corrections(
        &mut self,
        tm: &TransportMeta,
        traced: Option<&BounceMethod>,
        feedback_steps: Option<u32>,
    ) {
        self.fine_bounces = FineBounceOp::applies_to(tm);
        let traced = traced.is_some_and(|b| b.level0_paths > 0);
        let steps = feedback_steps.unwrap_or(if traced { 0 } else { DEFAULT_FEEDBACK_STEPS });
        self.bounce_feedback = if self.fine_bounces { steps } else { 0 };
    }

    /// The finer receivers' links to level-0 senders, built the first time they are needed.
    fn fine_bounce_op(&self) -> &FineBounceOp {
        self.fine_bounce
            .get_or_init(|| FineBounceOp::build(self.ib, self.links))
    }

    /// The level at or below which a sender's emission in `em` (RGB per sender point) is
    /// skipped in a product: `skip_fraction` of its largest channel.
    fn skip_threshold(&self, em: &[f32]) -> f32 {
        self.skip_fraction * em.iter().fold(0.0f32, |m, v| m.max(v.abs()))
    }

    /// Whether [`CpuRelighter::lagged_feedback`] saves work per frame with the current
    /// settings: with the bounce-light feedback it saves the feedback's own product, with the
    /// fine bounces from every sender point the finer rows' second product (`T_fine y` apart
    /// from `S e`); both whenever the links are receiver-major (files written by the bake).
    /// False where nothing is lagged.
    pub fn lag_pays(&self) -> bool {
        // The conditions under which `relight` lags either part.
        let n = self.ib.basis.len();
        let receiver_major = self.links.receivers.to_native() as usize == n;
        receiver_major
            && (self.bounce_feedback > 0
                || (self.fine_bounces && self.fine_emission == FineEmission::Senders))
    }

    /// Forgets the lagged bounce light: the next frame is computed exactly.
    pub fn reset_lag(&mut self) {
        self.feedback_prev = None;
        self.fine_prev = None;
    }

    /// The precomputed pull-push of step 2 (also the fine bounces' emission's).
    pub fn pull_push_op(&self) -> &PullPushOp {
        &self.pull_push
    }

    /// The reconstruction at the sender points that the fine bounces' emission and the
    /// bounce-light feedback use.
    pub fn feedback_op(&self) -> &BounceFeedbackOp {
        &self.feedback
    }

    /// What a GPU's step 1 needs from the CPU per frame for `light`, as
    /// [`CpuRelighter::direct_stats`] uses it: the surface nearest the light (the shadow rays'
    /// clearance: its height and normal), and the sender points within a few support radii of
    /// the light with their samples blended toward the support average (before visibility).
    /// Both empty when [`CpuRelighter::support_average`] is off.
    pub fn near_light(&self, light: &Light) -> NearLight {
        if !self.support_average {
            return NearLight::default();
        }
        let b = &self.ib.basis;
        let senders = b.level_offsets[self.sender_levels] as usize;
        let near = (0..senders)
            .filter(|&j| self.sample_used[j])
            .filter(|&j| {
                let x = Vec3::from(b.positions[j]);
                let d = light.position - x;
                mlt_format::support_average::near_weight(
                    d.length(),
                    d.dot(Vec3::from(b.normals[j])),
                    b.radii[j],
                ) > 0.0
            })
            .map(|j| (j as u32, self.support.sample(j, light).0))
            .collect();
        NearLight {
            clearance: self.clearance(light),
            samples: near,
        }
    }

    /// Per sender point, whether step 1 samples it (the pull replaces the others).
    pub fn sample_used(&self) -> &[bool] {
        &self.sample_used
    }

    /// Shadow rays per sender point (step 1).
    pub fn shadow_rays(&self) -> u32 {
        self.shadow_rays
    }

    /// The scene's ray caster (the shadow rays').
    pub fn caster(&self) -> &'a dyn RayCaster {
        self.caster
    }

    /// The basis and the links this relighter was built on.
    pub fn basis_and_links(&self) -> (&IndexedBasis, &ArchivedLinks) {
        (self.ib, self.links)
    }

    /// The precomputed flattening operator (absent only when too large for 32-bit offsets).
    pub fn flatten_op(&self) -> Option<&FlattenOp> {
        self.flatten_op.as_ref()
    }

    /// Gives the flat basis' weights the normal power `power` ([`FlatBasis::with_normal_power`];
    /// 2: Eq. 8's weights) and builds the sharpening step for them again; the flattening
    /// operator, which evaluates the hierarchical basis at the flat points, is unchanged. For
    /// experiments; a power below 2 is an error and changes nothing.
    pub fn set_flat_normal_power(&mut self, power: f32) -> Result<(), RelightError> {
        if power == self.flat.normal_power {
            return Ok(());
        }
        let flat = self.flat.clone().with_normal_power(power)?;
        let mut sharpen_op = SharpenOp::build(&flat)?;
        if let Some(old) = &self.sharpen_op {
            sharpen_op.set_steps(old.steps())?;
        }
        self.load.sharpen_entries = sharpen_op.entries();
        self.load.sharpen_bytes = sharpen_op.bytes();
        self.flat = flat;
        self.sharpen_op = Some(sharpen_op);
        self.culling = OnceLock::new();
        Ok(())
    }

    /// Sets the sharpening steps after flattening ([`SharpenOp::set_steps`]; 1 to
    /// [`crate::flatten_op::MAX_SHARPEN_STEPS`], else an error that changes nothing). For
    /// experiments; [`CpuRelighter::sharpen`] turns the steps off.
    pub fn set_sharpen_steps(&mut self, steps: usize) -> Result<(), RelightError> {
        match self.sharpen_op.as_mut() {
            Some(op) => op.set_steps(steps),
            None => Ok(()),
        }
    }

    /// Tabulates now the basis functions of every sender point whose direct sample is used,
    /// for the support averages near the light (step 1), which frames otherwise tabulate on
    /// first use: the first frames near a surface then cost no more than the others.
    pub fn build_support_tables(&mut self) {
        let t = Instant::now();
        self.support.build_tables(&self.sample_used);
        self.load.support_tables_ms = t.elapsed().as_secs_f64() * 1e3;
    }

    /// What building the operators cost.
    pub fn load_stats(&self) -> &LoadStats {
        &self.load
    }

    /// Direct irradiance at every sender point (step 1); zero, without rays, at the points
    /// whose sample the pull-push does not use.
    pub fn direct(&self, light: &Light) -> Vec<f32> {
        self.direct_stats(light).0
    }

    /// [`CpuRelighter::direct`] and the number of shadow rays it cast.
    pub fn direct_counted(&self, light: &Light) -> (Vec<f32>, u64) {
        let (e, rays, _) = self.direct_stats(light);
        (e, rays)
    }

    /// [`CpuRelighter::direct`], the number of shadow rays it cast and the number of points
    /// whose sample is (partly) a support average.
    pub fn direct_stats(&self, light: &Light) -> (Vec<f32>, u64, u64) {
        let b = &self.ib.basis;
        let senders = b.level_offsets[self.sender_levels] as usize;
        let clearance = if self.support_average {
            self.clearance(light)
        } else {
            None
        };
        let per_point: Vec<([f32; 3], u32, bool)> = (0..senders)
            .into_par_iter()
            .map(|j| {
                if !self.sample_used[j] {
                    return ([0.0; 3], 0, false);
                }
                let (e, averaged) = if self.support_average {
                    self.support.sample(j, light)
                } else {
                    let (x, n) = (Vec3::from(b.positions[j]), Vec3::from(b.normals[j]));
                    (light.irradiance(x, n), false)
                };
                if e == [0.0; 3] {
                    return (e, 0, averaged);
                }
                let (v, rays) = self.visibility(j, light, clearance);
                ([e[0] * v, e[1] * v, e[2] * v], rays, averaged)
            })
            .collect();
        let rays = per_point.iter().map(|p| u64::from(p.1)).sum();
        let averaged = per_point.iter().filter(|p| p.2).count() as u64;
        (
            per_point.into_iter().flat_map(|p| p.0).collect(),
            rays,
            averaged,
        )
    }

    /// The surface nearest the light: the least height of the light over the tangent plane
    /// of a sender point whose support disk, and the surface, lie under it, with that point's
    /// normal (`None` when there is none). Ties go to the lower index, so the result does not
    /// depend on the order of the reduction. The surface test, a query of the finest level,
    /// is made only for the points under the light in order of height, until one passes.
    fn clearance(&self, light: &Light) -> Option<(f32, Vec3)> {
        let b = &self.ib.basis;
        let senders = b.level_offsets[self.sender_levels] as usize;
        // The light must lie over the point's support disk (cheap to test at every point)...
        let mut under: Vec<(f32, usize)> = (0..senders)
            .into_par_iter()
            .filter_map(|j| {
                let d = light.position - Vec3::from(b.positions[j]);
                let h = d.dot(Vec3::from(b.normals[j]));
                (h > 0.0 && d.length_squared() - h * h < b.radii[j] * b.radii[j]).then_some((h, j))
            })
            .collect();
        // ...and over the surface (a query): the first such point in order of height.
        under.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        under.into_iter().find_map(|(h, j)| {
            let n = Vec3::from(b.normals[j]);
            self.support
                .on_surface(light.position - n * h, n)
                .then_some((h, n))
        })
    }

    /// The fraction of shadow rays from sender point `j` that reach the light, and the number
    /// of rays cast. The rays end on a disk around the light, and the disk reaches at most
    /// half-way to the surface nearest the light (`clearance`: its height and normal), so that
    /// no ray ends behind it.
    fn visibility(&self, j: usize, light: &Light, clearance: Option<(f32, Vec3)>) -> (f32, u32) {
        let b = &self.ib.basis;
        let eps = self.caster.ray_epsilon();
        let k = self.shadow_rays;
        let x = Vec3::from(b.positions[j]);
        let n = Vec3::from(b.normals[j]);
        // Shadow rays to points jittered over a disk around the light, facing the point, in a
        // fixed pattern turned per point.
        let to_light = light.position - x;
        let dist = to_light.length();
        let l = to_light / dist.max(f32::MIN_POSITIVE);
        let mut radius = (0.5 * b.disk_radii[b.level_of(j)]).min(0.25 * dist);
        if let Some((h, nc)) = clearance {
            // The disk, perpendicular to `l`, reaches `radius * sin(l, nc)` towards the surface.
            let sin = (1.0 - l.dot(nc).powi(2)).max(0.0).sqrt();
            if radius * sin > 0.5 * h {
                radius = 0.5 * h / sin;
            }
        }
        let (t, bt) = l.any_orthonormal_pair();
        let origin = x + n * eps;
        let turn = (j as u32).wrapping_mul(0x9E37_79B9) as f32 / 4_294_967_296.0;
        let ray = |s: u32| {
            let offset = if k == 1 {
                Vec3::ZERO
            } else {
                let r = radius * ((s as f32 + 0.5) / k as f32).sqrt();
                let phi = std::f32::consts::TAU * (s as f32 * 0.618_034 + turn);
                t * (r * phi.cos()) + bt * (r * phi.sin())
            };
            u32::from(!self.caster.occluded(origin, light.position + offset))
        };
        // The even rays first (spread over the whole disk); where they agree the point is
        // taken as wholly lit or wholly shadowed, and only where they disagree (in the
        // penumbra) are the odd rays cast too.
        let even: u32 = (0..k).step_by(2).map(ray).sum();
        let half = k.div_ceil(2);
        if self.adaptive_shadows && k >= 4 && (even == 0 || even == half) {
            (if even == 0 { 0.0 } else { 1.0 }, half)
        } else {
            let odd: u32 = (1..k).step_by(2).map(ray).sum();
            ((even + odd) as f32 / k as f32, k)
        }
    }
}

/// The points of the coarsest `levels` levels of `ib`.
fn pull_push_points(ib: &IndexedBasis, levels: usize) -> usize {
    ib.basis.level_offsets[levels.min(ib.levels())] as usize
}

/// `a + b` per element: the emission with a lagged part added, for one side of a split
/// product.
fn added(a: &[f32], b: &[f32]) -> Vec<f32> {
    a.iter().zip(b).map(|(x, y)| x + y).collect()
}

/// What the flat coefficients computed for a light hold of the rows a view needs.
enum Coverage {
    /// Every row.
    Covered,
    /// All but the rows of the flat points flagged, which no earlier view of the light saw.
    Adds(Vec<bool>),
    /// They were culled to another view and cannot be extended: every row must be redone.
    All,
}

impl CpuRelighter<'_> {
    /// The sharpening steps step 4 runs (0: none).
    fn sharpen_steps(&self) -> usize {
        self.sharpen_op
            .as_ref()
            .filter(|_| self.sharpen)
            .map_or(0, SharpenOp::steps)
    }

    /// The rows step 4 computes for the current view, and the view, or `None` for every row
    /// (no view, culling off, or operators whose layout allows none).
    fn view_masks(&mut self) -> Option<(Frustum, Arc<ViewMasks>)> {
        let steps = self.sharpen_steps();
        let (culling, view) = self.culling_for_view()?;
        let view = *view;
        if let Some((v, s, m)) = &self.masks_cache {
            if *v == view && *s == steps {
                return Some((view, m.clone()));
            }
        }
        let masks = Arc::new(culling.masks(&view, steps));
        self.masks_cache = Some((view, steps, masks.clone()));
        Some((view, masks))
    }

    /// The culling structure and the view to cull to, when step 4 is culled.
    fn culling_for_view(&self) -> Option<(&FlatCulling, &Frustum)> {
        let view = self.view.as_ref().filter(|_| self.view_culling)?;
        let op = self.flatten_op.as_ref()?;
        let culling = self
            .culling
            .get_or_init(|| FlatCulling::build(&self.flat, op, self.sharpen_op.as_ref()))
            .as_ref()?;
        Some((culling, view))
    }

    /// What `frame.flat` holds, for the frame's light, of the rows the current view needs.
    fn view_coverage(&self) -> Coverage {
        let Some((done_view, done)) = &self.flat_done else {
            return Coverage::Covered;
        };
        if self.frame.flat.is_empty() {
            return Coverage::Covered;
        }
        match self.culling_for_view() {
            Some((_, view)) if view == done_view => Coverage::Covered,
            Some((culling, view)) => {
                let mut seen = culling.visible(view);
                let mut adds = false;
                for (s, &d) in seen.iter_mut().zip(&done.visible) {
                    *s &= !d;
                    adds |= *s;
                }
                if adds {
                    Coverage::Adds(seen)
                } else {
                    Coverage::Covered
                }
            }
            None => Coverage::All,
        }
    }

    /// Step 4 for a new view under the light `flat` was computed for, which sees the flat
    /// points `seen` flags besides those earlier views of this light saw: only the rows those
    /// points need that were not computed, into the buffers the earlier products left (`flat`
    /// and the sharpening's step inputs); returns the rows the flattening product computed.
    /// Falls back to [`CpuRelighter::flatten_stage`] when there is nothing to add to.
    fn extend_flatten_stage(&mut self, i: &[f32], flat: &mut Vec<f32>, seen: Vec<bool>) -> usize {
        let steps = self.sharpen_steps();
        let done = match &self.flat_done {
            Some((_, done)) if self.flatten_on_cpu && done.sharpen.len() == steps => done.clone(),
            _ => return self.flatten_stage(i, flat),
        };
        let Some((culling, view)) = self.culling_for_view() else {
            return self.flatten_stage(i, flat);
        };
        let (view, new) = (*view, culling.masks_for(seen, steps));
        let Some(op) = self.flatten_op.as_ref() else {
            return self.flatten_stage(i, flat);
        };
        let added = new.minus(&done);
        match self.sharpen_op.as_ref().filter(|_| self.sharpen) {
            Some(sharpen) => {
                op.apply_masked(
                    i,
                    LINK_DIM,
                    self.sharpen_scratch.original_mut(),
                    &mut self.flatten_scratch,
                    &added.flatten,
                );
                sharpen.extend_masked(flat, LINK_DIM, &mut self.sharpen_scratch, &added.sharpen);
            }
            None => op.apply_masked(i, LINK_DIM, flat, &mut self.flatten_scratch, &added.flatten),
        }
        self.flat_done = Some((view, Arc::new(done.union(&new))));
        added.flatten_rows()
    }

    /// Step 4: `flat` from `i`, on the rows the view needs; returns the rows the flattening
    /// product computed (0 when the renderer flattens).
    fn flatten_stage(&mut self, i: &[f32], flat: &mut Vec<f32>) -> usize {
        let masks = self.view_masks();
        self.flat_done = None;
        let mut rows = self.flat.len();
        match &self.flatten_op {
            Some(_) if !self.flatten_on_cpu => {
                flat.clear();
                return 0;
            }
            Some(op) => match &masks {
                Some((_, m)) => {
                    op.apply_masked(i, LINK_DIM, flat, &mut self.flatten_scratch, &m.flatten);
                    rows = m.flatten_rows();
                }
                None => op.apply(i, LINK_DIM, flat, &mut self.flatten_scratch),
            },
            None => *flat = self.flat.flatten(self.ib, i, LINK_DIM),
        }
        if let Some(sharpen) = self.sharpen_op.as_ref().filter(|_| self.sharpen) {
            if !flat.is_empty() {
                match &masks {
                    Some((_, m)) => {
                        sharpen.apply_masked(flat, LINK_DIM, &mut self.sharpen_scratch, &m.sharpen)
                    }
                    None => sharpen.apply(flat, LINK_DIM, &mut self.sharpen_scratch),
                }
            }
        }
        self.flat_done = masks;
        rows
    }
}

impl Relight for CpuRelighter<'_> {
    fn flat_basis(&self) -> &FlatBasis {
        &self.flat
    }

    fn flatten_operator(&self) -> Option<&FlattenOp> {
        self.flatten_op.as_ref()
    }

    fn sharpen_operator(&self) -> Option<&SharpenOp> {
        self.sharpen_op.as_ref().filter(|_| self.sharpen)
    }

    fn set_flatten_on_cpu(&mut self, on: bool) {
        self.flatten_on_cpu = on;
        // The next frame recomputes (its flat coefficients are wanted, or no longer).
        self.last = None;
    }

    fn set_view(&mut self, view: Option<&Frustum>) {
        self.view = view.copied();
    }

    fn relight(&mut self, light: &Light) -> &Frame {
        let same_light = self.last.as_ref() == Some(light);
        if same_light && self.lag_settled {
            let t = Instant::now();
            let coverage = self.view_coverage();
            if let Coverage::Covered = coverage {
                self.frame.reused = true;
            } else {
                // Only step 4, for the rows the new view adds, from the kept `i`.
                let i = std::mem::take(&mut self.frame.i);
                let mut flat = std::mem::take(&mut self.frame.flat);
                self.frame.flat_rows = match coverage {
                    Coverage::Adds(seen) => self.extend_flatten_stage(&i, &mut flat, seen),
                    _ => self.flatten_stage(&i, &mut flat),
                };
                self.frame.i = i;
                self.frame.flat = flat;
                self.frame.times = StageTimes {
                    flatten_ms: t.elapsed().as_secs_f64() * 1e3,
                    ..StageTimes::default()
                };
                self.frame.reused = false;
            }
            return &self.frame;
        }
        let mut times = StageTimes::default();
        let t = Instant::now();
        let (mut e, shadow_rays, averaged_points) = self.direct_stats(light);
        times.direct_ms = t.elapsed().as_secs_f64() * 1e3;

        let t = Instant::now();
        self.pull_push.pull(&mut e, 3);
        let direct = e.clone();
        self.pull_push.push(&mut e, 3);
        times.project_ms = t.elapsed().as_secs_f64() * 1e3;

        // The previous frame's buffers are reused (every value is overwritten).
        let n = self.ib.basis.len() * LINK_DIM;
        let mut i = std::mem::take(&mut self.frame.i);
        i.resize(n, 0.0);
        let mut flat = std::mem::take(&mut self.frame.flat);
        flat.resize(self.flat.len() * LINK_DIM, 0.0);

        let t = Instant::now();
        let threshold = self.skip_threshold(&e);
        // The bake writes one receiver per point; other files use the stored links.
        let receiver_major = self.links.receivers.to_native() as usize * LINK_DIM == n;
        let feedback = self.bounce_feedback > 0 && receiver_major;
        let lag = feedback && self.lagged_feedback;
        let prev = if lag { self.feedback_prev.take() } else { None };
        // The fine bounces from every sender point, through the finer rows (T's: links to
        // every sender level), from the bounce light `y` at every sender point pull-pushed
        // onto the sender levels: the frame's own (from `S e`), or with the lag the last
        // frame's (from its whole `i`), which the finer rows take with `e`.
        let fine_senders = self.fine_bounces
            && self.fine_emission == FineEmission::Senders
            && self.bounce_feedback == 0
            && receiver_major;
        let fine_lag = fine_senders && self.lagged_feedback;
        let fine_prev = if fine_lag {
            self.fine_prev.take()
        } else {
            None
        };
        // A lagged part computed under this same light is the frame's own.
        self.lag_settled =
            (prev.is_none() && fine_prev.is_none()) || self.lag_light.as_ref() == Some(light);
        let m = self.ib.basis.level_range(0).len();
        let used = if let Some(d) = &prev {
            // The level-0 rows take last frame's correction with the emission.
            self.receiver_links
                .apply_split(&e, &added(&e, d), m, threshold, &mut i)
        } else if let Some(y) = &fine_prev {
            // `T_fine (e + y)` on the finer rows, `S_0 e` on the level-0 rows, in one pass.
            self.receiver_links
                .apply_split(&added(&e, y), &e, m, threshold, &mut i)
        } else if receiver_major {
            self.receiver_links.apply(&e, threshold, &mut i)
        } else {
            // Fewer receivers than points (not written by the bake): the stored links.
            i.fill(0.0);
            self.links.apply(&e, threshold, &mut i)
        };
        if fine_prev.is_some() {
            // The next frame's `y`: this frame's bounce light, its finer receivers' later
            // bounces included.
            self.fine_prev = Some(self.feedback.emission(&self.pull_push, &i));
        } else if fine_senders {
            let y = self.feedback.emission(&self.pull_push, &i);
            self.receiver_links
                .apply_add_from(&y, self.skip_threshold(&y), m, &mut i);
            if fine_lag {
                // The next frame's `y`, as a lagged frame's: from the whole `i`.
                self.fine_prev = Some(self.feedback.emission(&self.pull_push, &i));
            }
        } else if self.fine_bounces {
            self.fine_bounce_op().apply(&mut i);
        }
        times.transport_ms = t.elapsed().as_secs_f64() * 1e3;

        let t = Instant::now();
        if feedback && prev.is_none() {
            let fine = self.fine_bounces.then(|| self.fine_bounce_op());
            self.feedback.apply(
                &self.receiver_links,
                &self.pull_push,
                fine,
                self.bounce_feedback,
                threshold,
                &mut i,
            );
        }
        if lag {
            self.feedback_prev = Some(self.feedback.correction(&self.pull_push, &i));
        }
        times.feedback_ms = t.elapsed().as_secs_f64() * 1e3;

        let t = Instant::now();
        let flat_rows = self.flatten_stage(&i, &mut flat);
        times.flatten_ms = t.elapsed().as_secs_f64() * 1e3;

        self.frame = Frame {
            direct,
            e,
            i,
            flat,
            times,
            senders_used: used,
            shadow_rays,
            averaged_points,
            flat_rows,
            reused: false,
        };
        self.last = Some(*light);
        self.lag_light = Some(*light);
        &self.frame
    }
}
