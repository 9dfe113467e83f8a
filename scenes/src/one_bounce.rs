//! The one-bounce light at a surface point under a point light, shared by the viewer's
//! reference path tracer (at every vertex of its paths) and the bake's check of its own light
//! at the scene's camera, so that both trace the same estimator.
//!
//! At a surface point `p` (shading normal `n_s`, geometric normal `n_g`, facing the side light
//! arrives from) the one-bounce term `T(p) = ∫ ρ(y)/π E_d(y) cos θ_p dω` is estimated with
//! multiple importance sampling (Veach 1997, balance heuristic) of two samples `y`: a
//! cosine-sampled direction's first hit (density `p_G = cos θ_p/π · cos θ_y/|p-y|²` in area
//! measure) and the first hit of a ray leaving the light uniformly over the sphere
//! (`p_L = cos θ_y,l / (4π |y-l|²)`), each contributing `f(y) / (p_G(y) + p_L(y))` with
//! `f(y) = ρ(y)/π E_d(y) cos θ_p cos θ_y / |p-y|² V(p, y)`. The light sample catches the bright
//! spots a point light makes on nearby surfaces (a light just below a ceiling), which cosine
//! sampling finds too rarely; the cosine sample covers `y` close to `p` (corners).
//!
//! A path chains these terms ([`OneBounce::path`]): from the cosine sample it continues with
//! throughput `β *= ρ(y)`, so `E_i(x) = Σ_k β_k T(y_k)` with `y_0 = x`, `β_0 = 1` is the
//! indirect irradiance of every bounce (next-event estimation at every vertex), with Russian
//! roulette after a number of bounces (survival probability `q = max(β)` capped at 1, `β /= q`
//! on survival, which keeps the estimate unbiased) and a hard cap on the bounces.
//!
//! `E_d(y) = I(y) max(0, cos) / d² · V` is the light's direct irradiance with one hard shadow
//! ray; the light model (intensity, cone) comes in as a function, so this crate needs none.

use glam::Vec3;

use crate::raycast::{Hit, RayCaster};
use crate::sampling::{cosine_hemisphere, uniform_sphere};

/// A point light as the estimator sees it: its position and its unoccluded irradiance
/// `E(x, n)` at a point `x` with unit normal `n` (zero behind the surface).
pub struct PointLight<'a> {
    pub position: Vec3,
    pub irradiance: Box<dyn Fn(Vec3, Vec3) -> [f32; 3] + Send + Sync + 'a>,
}

/// One path's estimate of the indirect irradiance at its first vertex: the first bounce
/// alone (the one-bounce term there) and every bounce.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PathEstimate {
    pub first: [f32; 3],
    pub all: [f32; 3],
}

/// The estimator's fixed state: the scene, the light and the scene's ray offset.
pub struct OneBounce<'a> {
    caster: &'a dyn RayCaster,
    light: PointLight<'a>,
    eps: f32,
}

fn positive(x: f32) -> bool {
    x > 0.0
}

impl<'a> OneBounce<'a> {
    /// The estimator for `caster` lit by `light`.
    pub fn new(caster: &'a dyn RayCaster, light: PointLight<'a>) -> OneBounce<'a> {
        OneBounce {
            caster,
            light,
            eps: caster.ray_epsilon(),
        }
    }

    /// The offset of secondary rays from the surface they leave ([`RayCaster::ray_epsilon`]).
    pub fn eps(&self) -> f32 {
        self.eps
    }

    /// Direct irradiance `E_d` at a surface point with shading normal `ns`, leaving on the side
    /// of the (ray-facing) geometric normal `ng`: the light model times one shadow ray.
    pub fn direct(&self, x: Vec3, ns: Vec3, ng: Vec3) -> [f32; 3] {
        if (self.light.position - x).dot(ng) <= 0.0 {
            return [0.0; 3];
        }
        let e = (self.light.irradiance)(x, ns);
        if e == [0.0; 3] || self.caster.occluded(x + ng * self.eps, self.light.position) {
            return [0.0; 3];
        }
        e
    }

    /// Area-measure density with which a ray from the light, uniform over the sphere of
    /// directions, first hits the surface point `y` (geometric normal `ng`, lit side): `p_L`.
    pub fn light_pdf(&self, y: Vec3, ng: Vec3) -> f32 {
        let d = self.light.position - y;
        let d2 = d.length_squared();
        if !positive(d2) {
            return 0.0;
        }
        let cos = (ng.dot(d) / d2.sqrt()).max(0.0);
        cos / (4.0 * std::f32::consts::PI * d2)
    }

    /// The first hit of the ray leaving the light in the direction of `uniform_sphere(u)`.
    pub fn light_ray(&self, u: (f32, f32)) -> Option<Hit> {
        let w = uniform_sphere(u.0, u.1);
        self.caster
            .intersect(self.light.position, w, 0.0, f32::INFINITY)
    }

    /// The light-sampled half of `T(p)`: `f(y) / (p_G(y) + p_L(y))` for `y` the first hit of
    /// the light's ray `uniform_sphere(u)` (module docs).
    pub fn light_sample(&self, p: Vec3, ns: Vec3, ng: Vec3, u: (f32, f32)) -> [f32; 3] {
        let Some(y) = self.light_ray(u) else {
            return [0.0; 3];
        };
        let po = p + ng * self.eps;
        let yo = y.position + y.geometric_normal * self.eps;
        let d = y.position - po;
        let d2 = d.length_squared();
        if !positive(d2) {
            return [0.0; 3];
        }
        let dir = d / d2.sqrt();
        let cos_p = ns.dot(dir);
        let cos_y = y.geometric_normal.dot(-dir);
        if !(positive(cos_p) && positive(cos_y) && positive(ng.dot(dir))) {
            return [0.0; 3];
        }
        let ed = (self.light.irradiance)(y.position, y.shading_normal);
        if ed == [0.0; 3] || self.caster.occluded(po, yo) {
            return [0.0; 3];
        }
        let inv_pi = std::f32::consts::FRAC_1_PI;
        let g = cos_p * cos_y / d2;
        let p_g = cos_p * inv_pi * cos_y / d2;
        let p_l = self.light_pdf(y.position, y.geometric_normal);
        let denom = p_g + p_l;
        if !positive(denom) || !denom.is_finite() {
            return [0.0; 3];
        }
        std::array::from_fn(|c| y.albedo[c] * inv_pi * ed[c] * g / denom)
    }

    /// The cosine-sampled half of `T(p)`, in parts: `E_d(y)` and the balance weight
    /// `p_G / (p_G + p_L)` for `hit` the first hit `y` of the cosine-sampled direction `dir`
    /// (cosine `cos_p` to `p`'s shading normal) from `origin`, the point `p` moved off its
    /// surface by [`Self::eps`]; `None` where `y` is unlit. The half is `ρ(y) E_d(y)` times the
    /// weight.
    pub fn cosine_half(
        &self,
        origin: Vec3,
        dir: Vec3,
        cos_p: f32,
        hit: &Hit,
    ) -> Option<([f32; 3], f32)> {
        let ed = self.direct(hit.position, hit.shading_normal, hit.geometric_normal);
        if ed == [0.0; 3] {
            return None;
        }
        let inv_pi = std::f32::consts::FRAC_1_PI;
        let d2 = (hit.position - origin).length_squared();
        let cos_y = hit.geometric_normal.dot(-dir).max(0.0);
        let p_g = cos_p * inv_pi * cos_y / d2;
        let p_l = self.light_pdf(hit.position, hit.geometric_normal);
        let w = if p_g + p_l > 0.0 && p_g.is_finite() {
            p_g / (p_g + p_l)
        } else {
            1.0
        };
        Some((ed, w))
    }

    /// One path's estimate of the indirect irradiance `E_i(x, ns)` at the surface point `x`
    /// (shading normal `ns`, geometric normal `ng`, facing the side light arrives from), over at
    /// most `bounces` bounces with roulette from bounce `rr_start` on (module docs); `next`
    /// gives uniform numbers in `[0, 1)`, drawn in a fixed order (two for the light sample and
    /// two for the cosine direction per vertex, one for the roulette).
    pub fn path(
        &self,
        x: Vec3,
        ns: Vec3,
        ng: Vec3,
        (bounces, rr_start): (u32, u32),
        next: &mut dyn FnMut() -> f32,
    ) -> PathEstimate {
        let mut acc = [0.0f32; 3];
        let mut first = [0.0f32; 3];
        let mut beta = [1.0f32; 3];
        let (mut p, mut ns, mut ng) = (x, ns, ng);
        for bounce in 1..=bounces {
            // Light-sampled one-bounce term.
            let t = self.light_sample(p, ns, ng, (next(), next()));
            for c in 0..3 {
                acc[c] += beta[c] * t[c];
            }
            if bounce == 1 {
                first = acc;
            }
            // Cosine-sampled next vertex: its share of the one-bounce term, then continue.
            let (u1, u2) = (next(), next());
            let dir = cosine_hemisphere(ns, u1, u2);
            let cos_p = dir.dot(ns);
            if dir.dot(ng) <= 0.0 || !positive(cos_p) {
                // Below the geometric surface (shading normal leaning away): no light.
                break;
            }
            let Some(hit) = self
                .caster
                .intersect(p + ng * self.eps, dir, 0.0, f32::INFINITY)
            else {
                break;
            };
            for (b, r) in beta.iter_mut().zip(hit.albedo) {
                *b *= r;
            }
            if let Some((ed, w)) = self.cosine_half(p + ng * self.eps, dir, cos_p, &hit) {
                for c in 0..3 {
                    acc[c] += beta[c] * ed[c] * w;
                }
            }
            if bounce == 1 {
                first = acc;
            }
            if bounce >= rr_start {
                let q = beta[0].max(beta[1]).max(beta[2]).min(1.0);
                if q.is_nan() || q <= 0.0 || next() >= q {
                    break;
                }
                for b in &mut beta {
                    *b /= q;
                }
            }
            p = hit.position;
            ns = hit.shading_normal;
            ng = hit.geometric_normal;
        }
        PathEstimate { first, all: acc }
    }
}
