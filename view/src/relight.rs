//! Per-frame relighting on the CPU (Lehtinen et al. 2008, section 3.3), behind the
//! [`Relight`] interface so that a GPU compute version can replace it:
//! 1. direct irradiance at the sender points from the light, visibility averaged over several
//!    jittered shadow rays per point (as the tech report, against binary flicker): the rays
//!    leave the sender point and end at points spread around the light, over a disk facing the
//!    point of radius half the sender level's disk radius (at most a quarter of the distance),
//!    so that visibility is averaged over about the sender's footprint. (Jittering the start
//!    points over the tangent plane instead leaves curved surfaces and shadows them.)
//! 2. pull-push projection onto the sender levels, `e = P-dagger E`;
//! 3. `i = S e`, sender-major, skipping senders whose light is negligible;
//! 4. flattening of `i` to one level on the same points.
//!
//! When the light has not moved, nothing is recomputed.

use std::time::Instant;

use glam::Vec3;
use mlt_format::flatten::flatten;
use mlt_format::links::{ArchivedLinks, LINK_DIM};
use mlt_format::pull_push::pull_push_levels;
use mlt_format::IndexedBasis;
use mlt_scenes::RayCaster;
use rayon::prelude::*;
use serde::Serialize;

use crate::light::Light;

/// Milliseconds per stage of one relit frame.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct StageTimes {
    pub direct_ms: f64,
    pub project_ms: f64,
    pub transport_ms: f64,
    pub flatten_ms: f64,
}

/// The lighting of one frame.
#[derive(Clone, Debug, Default)]
pub struct Frame {
    /// Direct irradiance samples at the sender points, RGB.
    pub direct: Vec<f32>,
    /// Sender coefficients `e` (RGB per sender point).
    pub e: Vec<f32>,
    /// Receiver coefficients `i` of indirect vector irradiance (9 per point).
    pub i: Vec<f32>,
    /// Flat coefficients (9 per point).
    pub flat: Vec<f32>,
    pub times: StageTimes,
    /// Senders whose links were applied.
    pub senders_used: usize,
    /// True when the light had not moved and the previous frame was reused.
    pub reused: bool,
}

/// Per-frame relighting.
pub trait Relight {
    /// The lighting for `light`; recomputed only when the light changed.
    fn relight(&mut self, light: &Light) -> &Frame;
}

/// The CPU implementation.
pub struct CpuRelighter<'a> {
    ib: &'a IndexedBasis,
    links: &'a ArchivedLinks,
    caster: &'a dyn RayCaster,
    sender_levels: usize,
    shadow_rays: u32,
    /// Senders whose largest direct channel is at most this fraction of the frame's largest
    /// are skipped in `i = S e`.
    pub skip_fraction: f32,
    frame: Frame,
    last: Option<Light>,
}

impl<'a> CpuRelighter<'a> {
    pub fn new(
        ib: &'a IndexedBasis,
        links: &'a ArchivedLinks,
        caster: &'a dyn RayCaster,
        sender_levels: usize,
        shadow_rays: u32,
    ) -> CpuRelighter<'a> {
        CpuRelighter {
            ib,
            links,
            caster,
            sender_levels: sender_levels.min(ib.levels()),
            shadow_rays: shadow_rays.max(1),
            skip_fraction: 1e-4,
            frame: Frame::default(),
            last: None,
        }
    }

    /// Direct irradiance at every sender point (step 1).
    pub fn direct(&self, light: &Light) -> Vec<f32> {
        let b = &self.ib.basis;
        let senders = b.level_offsets[self.sender_levels] as usize;
        let eps = self.caster.ray_epsilon();
        let k = self.shadow_rays;
        let per_point: Vec<[f32; 3]> = (0..senders)
            .into_par_iter()
            .map(|j| {
                let x = Vec3::from(b.positions[j]);
                let n = Vec3::from(b.normals[j]);
                let e = light.irradiance(x, n);
                if e == [0.0; 3] {
                    return e;
                }
                // Shadow rays to points jittered over a disk around the light, facing the
                // point, in a fixed pattern turned per point.
                let to_light = light.position - x;
                let dist = to_light.length();
                let radius = (0.5 * b.disk_radii[b.level_of(j)]).min(0.25 * dist);
                let (t, bt) = (to_light / dist.max(f32::MIN_POSITIVE)).any_orthonormal_pair();
                let origin = x + n * eps;
                let turn = (j as u32).wrapping_mul(0x9E37_79B9) as f32 / 4_294_967_296.0;
                let mut visible = 0u32;
                for s in 0..k {
                    let offset = if k == 1 {
                        Vec3::ZERO
                    } else {
                        let r = radius * ((s as f32 + 0.5) / k as f32).sqrt();
                        let phi = std::f32::consts::TAU * (s as f32 * 0.618_034 + turn);
                        t * (r * phi.cos()) + bt * (r * phi.sin())
                    };
                    if !self.caster.occluded(origin, light.position + offset) {
                        visible += 1;
                    }
                }
                let v = visible as f32 / k as f32;
                [e[0] * v, e[1] * v, e[2] * v]
            })
            .collect();
        per_point.into_iter().flatten().collect()
    }
}

impl Relight for CpuRelighter<'_> {
    fn relight(&mut self, light: &Light) -> &Frame {
        if self.last.as_ref() == Some(light) {
            self.frame.reused = true;
            return &self.frame;
        }
        let mut times = StageTimes::default();
        let t = Instant::now();
        let direct = self.direct(light);
        times.direct_ms = t.elapsed().as_secs_f64() * 1e3;

        let t = Instant::now();
        let (e, _) = pull_push_levels(self.ib, &direct, 3, self.sender_levels);
        times.project_ms = t.elapsed().as_secs_f64() * 1e3;

        let t = Instant::now();
        let max_e = e.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let mut i = vec![0.0f32; self.ib.basis.len() * LINK_DIM];
        let used = self.links.apply(&e, self.skip_fraction * max_e, &mut i);
        times.transport_ms = t.elapsed().as_secs_f64() * 1e3;

        let t = Instant::now();
        let flat = flatten(self.ib, &i, LINK_DIM);
        times.flatten_ms = t.elapsed().as_secs_f64() * 1e3;

        self.frame = Frame {
            direct,
            e,
            i,
            flat,
            times,
            senders_used: used,
            reused: false,
        };
        self.last = Some(*light);
        &self.frame
    }
}
