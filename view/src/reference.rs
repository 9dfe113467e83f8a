//! An independent brute-force reference: Monte Carlo path tracing of the same scene, light and
//! camera as the viewer, using nothing of the meshless basis (only the scene's [`RayCaster`]
//! and the light model of [`mlt_relight::light`]). It exists to measure the viewer's error against.
//!
//! # What it computes
//!
//! Surfaces are Lambertian: outgoing radiance `L = ρ/π · E`. A pixel's value is the mean over
//! its area (a box filter, as `view render --spp N`): each path starts with its own primary
//! ray through a uniformly random point of the pixel ([`Camera::ray_direction`]`(px + u,
//! py + v)`, `u, v` in `[0, 1)`) to the first hit `x` (shading normal `n`, albedo `ρ`); a
//! path whose primary ray hits nothing adds black.
//!
//! - Direct radiance `ρ/π · E_d(x, n)`, `E_d = I max(0, cos) / d² · V` with one hard shadow ray
//!   ([`Light::irradiance`] and [`RayCaster::occluded`]). Exact for a point light where the
//!   whole pixel sees one lit surface; the only noise is that of the pixel's coverage at
//!   edges and shadow boundaries.
//! - Indirect irradiance `E_i(x, n) = ∫_Ω L(y(ω)) cos θ dω` (bounces ≥ 1, the rendering
//!   equation of the paper's Eq. 1 for diffuse surfaces with the direct part removed), estimated
//!   by path tracing with cosine-weighted hemisphere sampling (pdf `cos θ / π`): every sample's
//!   path `x → y1 → y2 → ...` contributes `Σ_k β_k E_d(y_k)` with `β_k = ρ(y1) ⋯ ρ(y_k)`
//!   (next-event estimation toward the light at every vertex), where each vertex's one-bounce
//!   term is combined by multiple importance sampling with a sample traced from the light
//!   (`mlt_scenes::one_bounce`, which the bake's check of its light at the camera shares;
//!   without it the bright spot that a point light close to a wall makes dominates the noise).
//!   Russian roulette from bounce [`ReferenceOptions::rr_start`] on, survival probability `q = max(β)` (capped at 1) and
//!   `β /= q` on survival, keeps the estimator unbiased; a hard cap of
//!   [`ReferenceOptions::max_bounces`] bounds the work (the bias it leaves is the energy of the
//!   bounces beyond the cap, below `ρmax^max_bounces` of the total for a closed scene).
//! - Indirect radiance `ρ/π · E_i`, final radiance = direct + indirect.
//!
//! # Noise
//!
//! Each pixel is rendered twice with independent random streams, `spp / 2` paths each (halves
//! A and B); the image is their average. For a pixel with per-half standard deviation `σ`,
//! `Var(A − B) = 2σ²` and `Var((A + B)/2) = σ²/2`, so the noise of the average is
//! `RMS(A − B) / 2`. [`Noise::rms`] is that, over all pixels, on Rec. 709 luminance;
//! `reference_noise.exr` holds the signed per-pixel `(A − B) / 2` of the indirect radiance (the
//! final image's noise adds the direct part's, nonzero only at edges).
//!
//! # Determinism
//!
//! Pixel `p` of half `h` draws from its own PCG32 stream seeded from `(seed, h, p)`, pixels are
//! computed independently (rayon) and written in index order, so the images are bit-identical
//! for any thread count.

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec3;
use mlt_relight::Light;
use mlt_scenes::one_bounce::{OneBounce, PointLight};
use mlt_scenes::raycast::geometric_normal_under;
use mlt_scenes::sampling::tangent_frame;
use mlt_scenes::RayCaster;
use rayon::prelude::*;

use crate::camera::Camera;
use crate::images::{luminance, ImageError, RgbImage};
use crate::probe::Probe;

/// Errors of the reference renderer.
#[derive(Debug, thiserror::Error)]
pub enum ReferenceError {
    #[error("samples per pixel must be an even number >= 2 (two independent halves), got {0}")]
    Spp(u32),
    #[error("max_bounces must be at least 1")]
    Bounces,
    #[error("{path}: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error(transparent)]
    Format(#[from] mlt_format::FormatError),
    #[error("the reference image is not finite at pixel ({x}, {y})")]
    NotFinite { x: u32, y: u32 },
}

/// Options of the integrator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReferenceOptions {
    /// Paths per pixel (or probe), even: `spp / 2` in each independent half.
    pub spp: u32,
    /// Seed of all random streams.
    pub seed: u64,
    /// Hard cap on the path length (bounces); see the module docs for the bias it leaves.
    pub max_bounces: u32,
    /// Russian roulette starts after this many bounces.
    pub rr_start: u32,
}

impl ReferenceOptions {
    /// `spp` paths, the given seed, at most [`DEFAULT_MAX_BOUNCES`] bounces, roulette from
    /// bounce 3.
    pub fn new(spp: u32, seed: u64) -> ReferenceOptions {
        ReferenceOptions {
            spp,
            seed,
            max_bounces: DEFAULT_MAX_BOUNCES,
            rr_start: 3,
        }
    }

    fn check(&self) -> Result<(), ReferenceError> {
        if self.spp < 2 || self.spp & 1 == 1 {
            return Err(ReferenceError::Spp(self.spp));
        }
        if self.max_bounces == 0 {
            return Err(ReferenceError::Bounces);
        }
        Ok(())
    }
}

/// Default path-length cap: with roulette the mean path length is about `1/(1-ρ)`; the cap
/// drops less than `0.99^1024 ≈ 3e-5` of the energy even at albedo 0.99.
pub const DEFAULT_MAX_BOUNCES: u32 = 1024;

/// Noise of an image estimated from its two independent halves.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Noise {
    /// `sqrt(mean_p (L_A(p) − L_B(p))²)` over all pixels, `L` the Rec. 709 luminance.
    pub half_difference_rms: f64,
    /// The noise of the average image, `half_difference_rms / 2`.
    pub rms: f64,
    /// Mean luminance of the average image over all pixels.
    pub mean: f64,
    /// `rms / mean` (0 for a black image).
    pub relative: f64,
}

impl Noise {
    fn from_halves(a: &[[f32; 3]], b: &[[f32; 3]]) -> Noise {
        let n = a.len().max(1) as f64;
        let (mut d2, mut sum) = (0.0f64, 0.0f64);
        for (pa, pb) in a.iter().zip(b) {
            let (la, lb) = (luminance(*pa) as f64, luminance(*pb) as f64);
            d2 += (la - lb) * (la - lb);
            sum += 0.5 * (la + lb);
        }
        let half_difference_rms = (d2 / n).sqrt();
        let rms = 0.5 * half_difference_rms;
        let mean = sum / n;
        Noise {
            half_difference_rms,
            rms,
            mean,
            relative: if mean > 0.0 { rms / mean } else { 0.0 },
        }
    }
}

/// The reference images (linear radiance, rows from the top) and how they were made.
#[derive(Clone, Debug)]
pub struct ReferenceImages {
    /// `ρ/π E_d` averaged over the pixel (one shadow ray per path; noise-free where the pixel
    /// sees one lit surface).
    pub direct: RgbImage,
    /// `ρ/π E_i`, the average of the two halves.
    pub indirect: RgbImage,
    /// `direct + indirect`.
    pub final_image: RgbImage,
    /// Signed `(A − B) / 2` of the indirect radiance, per pixel: its RMS is the noise of
    /// `indirect` (and of `final_image`).
    pub noise_image: RgbImage,
    /// Noise of `direct`: zero but at edges and shadow boundaries (the pixel's coverage).
    pub direct_noise: Noise,
    /// Noise of `indirect`.
    pub indirect_noise: Noise,
    /// Noise of `final_image`: `indirect`'s and the direct part's at edges.
    pub final_noise: Noise,
    pub options: ReferenceOptions,
    /// Wall-clock seconds of the rendering.
    pub seconds: f64,
    /// Rayon threads used (the result does not depend on it).
    pub threads: usize,
    pub camera: Camera,
    pub light: Light,
}

/// A minimal PCG32 (O'Neill 2014, XSH-RR), one stream per pixel and half.
#[derive(Clone, Debug)]
struct Pcg32 {
    state: u64,
    inc: u64,
}

fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Pcg32 {
    /// The stream for `(seed, domain, index)`; distinct triples give unrelated streams.
    fn new(seed: u64, domain: u64, index: u64) -> Pcg32 {
        let a = splitmix64(seed ^ splitmix64(domain.wrapping_mul(0x2545_F491_4F6C_DD1D)));
        let b = splitmix64(a ^ splitmix64(index));
        let mut r = Pcg32 {
            state: 0,
            inc: (splitmix64(b ^ 0xDA94_2042_E4DD_58B5) << 1) | 1,
        };
        r.next_u32();
        r.state = r.state.wrapping_add(b);
        r.next_u32();
        r
    }

    fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xorshifted.rotate_right(rot)
    }

    /// Uniform in `[0, 1)`.
    fn next_f32(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0)
    }
}

/// Stream domains, so that pixels, halves and probes never share a stream.
const DOMAIN_PIXEL: u64 = 0x5049_5845_4C00;
const DOMAIN_PROBE: u64 = 0x5052_4F42_4500;
const DOMAIN_VECTOR: u64 = 0x5645_4354_4F52;

/// `x > 0` (false for NaN).
fn positive(x: f32) -> bool {
    x > 0.0
}

// The directions come from the bake's samplers (`mlt_scenes::sampling`); the random streams
// stay the reference's own, so the reference shares no sample with the bake.

/// A cosine-distributed direction about `n` (pdf `cos θ / π`).
#[cfg(test)]
fn cosine_sample(n: Vec3, rng: &mut Pcg32) -> Vec3 {
    let (u1, u2) = (rng.next_f32(), rng.next_f32());
    mlt_scenes::sampling::cosine_hemisphere(n, u1, u2)
}

/// The integrator's fixed state.
struct Tracer<'a> {
    caster: &'a dyn RayCaster,
    light: &'a Light,
    /// The one-bounce estimator at a path's vertices (shared with the bake's camera check);
    /// it also holds the scene's ray offset.
    one: OneBounce<'a>,
    opts: ReferenceOptions,
}

impl<'a> Tracer<'a> {
    /// A tracer of `caster` lit by `light`, once `opts` are checked.
    fn new(
        caster: &'a dyn RayCaster,
        light: &'a Light,
        opts: &ReferenceOptions,
    ) -> Result<Tracer<'a>, ReferenceError> {
        opts.check()?;
        let point = PointLight {
            position: light.position,
            irradiance: Box::new(move |x, n| light.irradiance(x, n)),
        };
        Ok(Tracer {
            caster,
            light,
            one: OneBounce::new(caster, point),
            opts: *opts,
        })
    }

    /// Direct irradiance at a surface point ([`OneBounce::direct`]).
    fn direct(&self, x: Vec3, ns: Vec3, ng: Vec3) -> [f32; 3] {
        self.one.direct(x, ns, ng)
    }

    /// One path's estimate of the indirect irradiance `E_i(x, ns)` (module docs): the
    /// one-bounce term at every vertex by multiple importance sampling of a cosine-sampled
    /// direction and a ray from the light, over at most `bounces` bounces
    /// ([`OneBounce::path`]).
    fn indirect_sample(
        &self,
        x: Vec3,
        ns: Vec3,
        ng: Vec3,
        bounces: u32,
        rng: &mut Pcg32,
    ) -> [f32; 3] {
        self.one
            .path(x, ns, ng, (bounces, self.opts.rr_start), &mut || {
                rng.next_f32()
            })
            .all
    }

    /// One estimate of the indirect *vector* irradiance `E_i(x) = ∫_Ω L_i(ω) ω dω` over the
    /// hemisphere of `n` (`L_i` the radiance of bounces >= 1 arriving at `x`), per colour
    /// channel: `[r.x, r.y, r.z, g.x, .., b.z]`, the layout of a receiver coefficient.
    ///
    /// The first segment is sampled uniformly over the hemisphere (pdf `1/2π`, so the
    /// tangential components have finite variance; a cosine-sampled direction would divide them
    /// by `cos θ`), and the one-bounce part is combined by multiple importance sampling with a
    /// sample traced from the light, as in [`Self::indirect_sample`]. The radiance leaving the
    /// first hit `y` toward `x` also carries `ρ(y)/π E_i(y)`, one path of
    /// [`Self::indirect_sample`] at `y`. No light arrives from below the surface under `x`,
    /// whose face normal `ng` ([`geometric_normal_under`], once per point) may differ from
    /// the shading normal `n`.
    fn vector_sample(&self, x: Vec3, n: Vec3, ng: Vec3, rng: &mut Pcg32) -> [f32; 9] {
        let mut out = [0.0f32; 9];
        let mut add = |v: [f32; 3], d: Vec3| {
            for c in 0..3 {
                for k in 0..3 {
                    out[c * 3 + k] += v[c] * d[k];
                }
            }
        };
        let inv_pi = std::f32::consts::FRAC_1_PI;
        let inv_2pi = 0.5 * inv_pi;
        let eps = self.one.eps();
        let po = x + n * eps;
        // Light-sampled one-bounce term.
        if let Some(y) = self.one.light_ray((rng.next_f32(), rng.next_f32())) {
            let d = y.position - po;
            let d2 = d.length_squared();
            if positive(d2) {
                let dir = d / d2.sqrt();
                let cos_y = y.geometric_normal.dot(-dir);
                if positive(n.dot(dir)) && positive(ng.dot(dir)) && positive(cos_y) {
                    let ed = self.light.irradiance(y.position, y.shading_normal);
                    let yo = y.position + y.geometric_normal * eps;
                    if ed != [0.0; 3] && !self.caster.occluded(po, yo) {
                        let p_g = inv_2pi * cos_y / d2;
                        let p_l = self.one.light_pdf(y.position, y.geometric_normal);
                        let denom = p_g + p_l;
                        if positive(denom) && denom.is_finite() {
                            let g = cos_y / d2 / denom;
                            add(
                                std::array::from_fn(|c| y.albedo[c] * inv_pi * ed[c] * g),
                                dir,
                            );
                        }
                    }
                }
            }
        }
        // Uniformly sampled first segment.
        let (u1, u2) = (rng.next_f32(), rng.next_f32());
        let zc = u1;
        let rr = (1.0 - zc * zc).max(0.0).sqrt();
        let phi = std::f32::consts::TAU * u2;
        let (t, b) = tangent_frame(n);
        let dir = (t * (rr * phi.cos()) + b * (rr * phi.sin()) + n * zc).normalize();
        if !positive(dir.dot(n)) || !positive(dir.dot(ng)) {
            return out;
        }
        let Some(hit) = self.caster.intersect(po, dir, 0.0, f32::INFINITY) else {
            return out;
        };
        let two_pi = std::f32::consts::TAU;
        let ed = self.direct(hit.position, hit.shading_normal, hit.geometric_normal);
        if ed != [0.0; 3] {
            let d2 = (hit.position - po).length_squared();
            let cos_y = hit.geometric_normal.dot(-dir).max(0.0);
            let p_g = inv_2pi * cos_y / d2;
            let p_l = self.one.light_pdf(hit.position, hit.geometric_normal);
            let wmis = if p_g + p_l > 0.0 && p_g.is_finite() {
                p_g / (p_g + p_l)
            } else {
                1.0
            };
            add(
                std::array::from_fn(|c| hit.albedo[c] * inv_pi * ed[c] * two_pi * wmis),
                dir,
            );
        }
        // Bounces 2 and later of `x` are bounces 1 and later of `y`: one fewer.
        let rest = self.opts.max_bounces - 1;
        if rest == 0 {
            return out;
        }
        let ei = self.indirect_sample(
            hit.position,
            hit.shading_normal,
            hit.geometric_normal,
            rest,
            rng,
        );
        add(
            std::array::from_fn(|c| hit.albedo[c] * inv_pi * ei[c] * two_pi),
            dir,
        );
        out
    }

    /// The direct and indirect radiance of `n` paths through uniformly random points of pixel
    /// `(px, py)` (a box filter over the pixel), each path's primary hit shaded by
    /// [`Tracer::direct`] and one [`Tracer::indirect_sample`]; a path that hits nothing adds
    /// black. Means of f64 sums.
    fn pixel_mean(
        &self,
        camera: &Camera,
        (px, py): (f32, f32),
        n: u32,
        rng: &mut Pcg32,
    ) -> ([f32; 3], [f32; 3]) {
        let (mut direct, mut indirect) = ([0.0f64; 3], [0.0f64; 3]);
        for _ in 0..n {
            let (u, v) = (rng.next_f32(), rng.next_f32());
            let dir = camera.ray_direction(px + u, py + v);
            let Some(hit) = self
                .caster
                .intersect(camera.position, dir, 0.0, f32::INFINITY)
            else {
                continue;
            };
            let (x, ns, ng) = (hit.position, hit.shading_normal, hit.geometric_normal);
            let ed = self.direct(x, ns, ng);
            let ei = self.indirect_sample(x, ns, ng, self.opts.max_bounces, rng);
            for c in 0..3 {
                let brdf = (hit.albedo[c] * std::f32::consts::FRAC_1_PI) as f64;
                direct[c] += brdf * ed[c] as f64;
                indirect[c] += brdf * ei[c] as f64;
            }
        }
        let mean = |s: [f64; 3]| s.map(|v| (v / n as f64) as f32);
        (mean(direct), mean(indirect))
    }
}

/// Renders the reference with `spp` paths per pixel and the default options; see
/// [`render_reference_with`].
pub fn render_reference(
    caster: &dyn RayCaster,
    camera: &Camera,
    light: &Light,
    spp: u32,
    seed: u64,
) -> Result<ReferenceImages, ReferenceError> {
    render_reference_with(caster, camera, light, &ReferenceOptions::new(spp, seed))
}

/// Renders the reference images (module docs) for the camera and light.
pub fn render_reference_with(
    caster: &dyn RayCaster,
    camera: &Camera,
    light: &Light,
    opts: &ReferenceOptions,
) -> Result<ReferenceImages, ReferenceError> {
    let start = Instant::now();
    let tracer = Tracer::new(caster, light, opts)?;
    let (w, h) = (camera.width, camera.height);
    let half = opts.spp / 2;
    // Per pixel: direct and indirect radiance of halves A and B.
    let pixels: Vec<[[f32; 3]; 4]> = (0..w as u64 * h as u64)
        .into_par_iter()
        .map(|idx| {
            let (px, py) = ((idx % w as u64) as f32, (idx / w as u64) as f32);
            let mut ra = Pcg32::new(opts.seed, DOMAIN_PIXEL, 2 * idx);
            let mut rb = Pcg32::new(opts.seed, DOMAIN_PIXEL, 2 * idx + 1);
            let (da, ia) = tracer.pixel_mean(camera, (px, py), half, &mut ra);
            let (db, ib) = tracer.pixel_mean(camera, (px, py), half, &mut rb);
            [da, db, ia, ib]
        })
        .collect();
    let mut direct = RgbImage::new(w, h);
    let mut indirect = RgbImage::new(w, h);
    let mut final_image = RgbImage::new(w, h);
    let mut noise_image = RgbImage::new(w, h);
    let mut half_a = Vec::with_capacity(pixels.len());
    let mut half_b = Vec::with_capacity(pixels.len());
    let mut final_a = Vec::with_capacity(pixels.len());
    let mut final_b = Vec::with_capacity(pixels.len());
    let mut direct_a = Vec::with_capacity(pixels.len());
    let mut direct_b = Vec::with_capacity(pixels.len());
    for (k, [da, db, a, b]) in pixels.into_iter().enumerate() {
        let d: [f32; 3] = std::array::from_fn(|c| 0.5 * (da[c] + db[c]));
        let avg: [f32; 3] = std::array::from_fn(|c| 0.5 * (a[c] + b[c]));
        let fin: [f32; 3] = std::array::from_fn(|c| d[c] + avg[c]);
        if !(d.iter().chain(&avg).all(|v| v.is_finite())) {
            return Err(ReferenceError::NotFinite {
                x: (k as u64 % w as u64) as u32,
                y: (k as u64 / w as u64) as u32,
            });
        }
        direct.pixels[k] = d;
        indirect.pixels[k] = avg;
        final_image.pixels[k] = fin;
        noise_image.pixels[k] = std::array::from_fn(|c| 0.5 * (a[c] - b[c]));
        half_a.push(a);
        half_b.push(b);
        final_a.push(std::array::from_fn(|c| da[c] + a[c]));
        final_b.push(std::array::from_fn(|c| db[c] + b[c]));
        direct_a.push(da);
        direct_b.push(db);
    }
    Ok(ReferenceImages {
        direct,
        indirect,
        final_image,
        noise_image,
        direct_noise: Noise::from_halves(&direct_a, &direct_b),
        indirect_noise: Noise::from_halves(&half_a, &half_b),
        final_noise: Noise::from_halves(&final_a, &final_b),
        options: *opts,
        seconds: start.elapsed().as_secs_f64(),
        threads: rayon::current_num_threads(),
        camera: *camera,
        light: *light,
    })
}

/// File names written by [`write_reference`] in its directory.
pub const REFERENCE_FILES: [&str; 6] = [
    "reference_direct.exr",
    "reference_indirect.exr",
    "reference_final.exr",
    "reference_noise.exr",
    "reference.png",
    "reference.json",
];

/// The JSON summary written next to the images.
pub fn reference_json(r: &ReferenceImages) -> serde_json::Value {
    serde_json::json!({
        "tool": concat!("mlt-view ", env!("CARGO_PKG_VERSION"), " reference"),
        "spp": r.options.spp,
        "spp_per_half": r.options.spp / 2,
        "seed": r.options.seed,
        "max_bounces": r.options.max_bounces,
        "russian_roulette_from_bounce": r.options.rr_start,
        "width": r.camera.width,
        "height": r.camera.height,
        "camera": {
            "position": r.camera.position.to_array(),
            "target": r.camera.target.to_array(),
            "up": r.camera.up.to_array(),
            "fovy_deg": r.camera.fovy_deg,
        },
        "light": {
            "position": r.light.position.to_array(),
            "intensity": r.light.intensity,
            "cone": format!("{:?}", r.light.cone),
        },
        "noise_definition": "luminance; rms = RMS over pixels of (half A - half B) / 2, the noise of the average; relative = rms / mean",
        "noise": {
            "indirect": r.indirect_noise,
            "final": r.final_noise,
            "direct": r.direct_noise,
        },
        "seconds": r.seconds,
        "threads": r.threads,
    })
}

/// Writes `reference_{direct,indirect,final,noise}.exr`, `reference.png` (the final image,
/// tone-mapped) and `reference.json` into `dir` (created if missing).
pub fn write_reference(dir: &Path, r: &ReferenceImages) -> Result<(), ReferenceError> {
    std::fs::create_dir_all(dir).map_err(|error| ReferenceError::Io {
        path: dir.to_path_buf(),
        error,
    })?;
    r.direct.write_exr(&dir.join(REFERENCE_FILES[0]))?;
    r.indirect.write_exr(&dir.join(REFERENCE_FILES[1]))?;
    r.final_image.write_exr(&dir.join(REFERENCE_FILES[2]))?;
    r.noise_image.write_exr(&dir.join(REFERENCE_FILES[3]))?;
    r.final_image.write_png(&dir.join(REFERENCE_FILES[4]))?;
    let json = serde_json::to_string_pretty(&reference_json(r)).unwrap_or_default();
    mlt_format::file::write_atomic(&dir.join(REFERENCE_FILES[5]), json.as_bytes())?;
    Ok(())
}

/// The reference at one probe point (irradiance, not radiance: comparable with `view
/// --probe`'s `direct` and `indirect` columns).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProbeReference {
    /// Direct irradiance, light model with one shadow ray (exact).
    pub direct: [f32; 3],
    /// Indirect irradiance `E_i(x, n)`, the mean of all `spp` paths (both halves).
    pub indirect: [f32; 3],
    /// Half A's and half B's means (`spp / 2` paths each).
    pub halves: [[f32; 3]; 2],
    /// Standard error of `indirect` per channel: `sqrt(s² / spp)`, `s²` the sample variance
    /// of the `spp` path estimates.
    pub std_error: [f32; 3],
    /// The same for the luminance of `indirect`.
    pub std_error_luminance: f32,
}

/// Indirect (and direct) irradiance at probe points `(x, n)` by the same path tracer; the
/// point is offset along `n` for its rays, as `view --probe` does. Probe `k` draws from its own
/// streams, so results do not depend on the thread count or on the other probes.
pub fn reference_probes(
    caster: &dyn RayCaster,
    light: &Light,
    probes: &[Probe],
    opts: &ReferenceOptions,
) -> Result<Vec<ProbeReference>, ReferenceError> {
    let tracer = Tracer::new(caster, light, opts)?;
    let half = opts.spp / 2;
    Ok(probes
        .par_iter()
        .enumerate()
        .map(|(k, p)| {
            let (x, n) = (p.position, p.normal);
            let direct = tracer.direct(x, n, n);
            let mut sum = [[0.0f64; 3]; 2];
            let mut sq = [0.0f64; 3];
            let (mut lsum, mut lsq) = (0.0f64, 0.0f64);
            for (hh, s) in sum.iter_mut().enumerate() {
                let mut rng = Pcg32::new(opts.seed, DOMAIN_PROBE, 2 * k as u64 + hh as u64);
                for _ in 0..half {
                    let v = tracer.indirect_sample(x, n, n, opts.max_bounces, &mut rng);
                    for c in 0..3 {
                        s[c] += v[c] as f64;
                        sq[c] += (v[c] as f64) * (v[c] as f64);
                    }
                    let l = luminance(v) as f64;
                    lsum += l;
                    lsq += l * l;
                }
            }
            let n_all = opts.spp as f64;
            let se = |s: f64, q: f64| {
                let mean = s / n_all;
                let var = ((q / n_all - mean * mean) * n_all / (n_all - 1.0)).max(0.0);
                (var / n_all).sqrt() as f32
            };
            ProbeReference {
                direct,
                indirect: std::array::from_fn(|c| ((sum[0][c] + sum[1][c]) / n_all) as f32),
                halves: sum.map(|s| s.map(|v| (v / half as f64) as f32)),
                std_error: std::array::from_fn(|c| se(sum[0][c] + sum[1][c], sq[c])),
                std_error_luminance: se(lsum, lsq),
            }
        })
        .collect())
}

/// The indirect vector irradiance at surface points (module docs; the estimator is
/// `Tracer::vector_sample`): per point 9 floats, `[r.x, r.y, r.z, g.x, .., b.z]`, the mean of
/// `opts.spp` paths, and per point the standard error of the irradiance along its normal
/// (luminance), for the noise of what is built from them. Point `k` draws from its own stream,
/// so the result does not depend on the thread count.
pub fn reference_vector_irradiance(
    caster: &dyn RayCaster,
    light: &Light,
    points: &[Probe],
    opts: &ReferenceOptions,
) -> Result<(Vec<f32>, Vec<f32>), ReferenceError> {
    let tracer = Tracer::new(caster, light, opts)?;
    let n_all = opts.spp as f64;
    let per_point: Vec<([f32; 9], f32)> = points
        .par_iter()
        .enumerate()
        .map(|(k, p)| {
            let mut rng = Pcg32::new(opts.seed, DOMAIN_VECTOR, k as u64);
            let mut sum = [0.0f64; 9];
            let (mut lsum, mut lsq) = (0.0f64, 0.0f64);
            // No light from below the surface (a leaning shading normal), as in the bake's
            // gathers and the reference's paths.
            let ng = geometric_normal_under(caster, p.position, p.normal, tracer.one.eps());
            for _ in 0..opts.spp {
                let v = tracer.vector_sample(p.position, p.normal, ng, &mut rng);
                for (s, x) in sum.iter_mut().zip(v) {
                    *s += x as f64;
                }
                let nv: [f32; 3] = std::array::from_fn(|c| {
                    p.normal
                        .dot(Vec3::new(v[c * 3], v[c * 3 + 1], v[c * 3 + 2]))
                });
                let l = luminance(nv) as f64;
                lsum += l;
                lsq += l * l;
            }
            let mean = lsum / n_all;
            let var = ((lsq / n_all - mean * mean) * n_all / (n_all - 1.0)).max(0.0);
            (sum.map(|s| (s / n_all) as f32), (var / n_all).sqrt() as f32)
        })
        .collect();
    let se = per_point.iter().map(|p| p.1).collect();
    Ok((per_point.into_iter().flat_map(|p| p.0).collect(), se))
}

/// Header of [`probes_to_csv`]: the columns of `view --probe-out` that the reference has
/// (`direct_*`, `indirect_*`), then the standard errors.
pub const PROBE_CSV_HEADER: &str = "x,y,z,nx,ny,nz,direct_r,direct_g,direct_b,indirect_r,indirect_g,indirect_b,indirect_se_r,indirect_se_g,indirect_se_b,indirect_se_lum";

/// The probe references as CSV (header [`PROBE_CSV_HEADER`]).
pub fn probes_to_csv(probes: &[Probe], values: &[ProbeReference]) -> String {
    let mut o = String::from(PROBE_CSV_HEADER);
    o.push('\n');
    for (p, v) in probes.iter().zip(values) {
        let mut f: Vec<String> = Vec::with_capacity(16);
        f.extend(p.position.to_array().iter().map(|c| c.to_string()));
        f.extend(p.normal.to_array().iter().map(|c| c.to_string()));
        f.extend(v.direct.iter().map(|c| c.to_string()));
        f.extend(v.indirect.iter().map(|c| c.to_string()));
        f.extend(v.std_error.iter().map(|c| c.to_string()));
        f.push(v.std_error_luminance.to_string());
        o.push_str(&f.join(","));
        o.push('\n');
    }
    o
}

/// Probe points where the camera sees the scene: the primary hits of a `cols x rows` grid of
/// pixel centres spread over the image (a subsample of what the viewer's pixels show), with
/// the shading normal. Pixels whose ray misses give no probe.
pub fn camera_probes(caster: &dyn RayCaster, camera: &Camera, cols: u32, rows: u32) -> Vec<Probe> {
    let mut out = Vec::new();
    for j in 0..rows {
        for i in 0..cols {
            let px = ((i as f32 + 0.5) / cols as f32 * camera.width as f32).floor();
            let py = ((j as f32 + 0.5) / rows as f32 * camera.height as f32).floor();
            let dir = camera.ray_direction(px + 0.5, py + 0.5);
            if let Some(hit) = caster.intersect(camera.position, dir, 0.0, f32::INFINITY) {
                out.push(Probe {
                    position: hit.position,
                    normal: hit.shading_normal,
                });
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streams_differ_and_are_uniform_enough() {
        let mut a = Pcg32::new(1, DOMAIN_PIXEL, 0);
        let mut b = Pcg32::new(1, DOMAIN_PIXEL, 1);
        let va: Vec<u32> = (0..8).map(|_| a.next_u32()).collect();
        let vb: Vec<u32> = (0..8).map(|_| b.next_u32()).collect();
        assert_ne!(va, vb);
        let mut r = Pcg32::new(7, DOMAIN_PROBE, 3);
        let n = 100_000;
        let mean: f64 = (0..n).map(|_| r.next_f32() as f64).sum::<f64>() / n as f64;
        assert!((mean - 0.5).abs() < 0.005, "{mean}");
    }

    #[test]
    fn cosine_samples_have_the_cosine_mean() {
        // E[cos θ] under pdf cos θ / π is 2/3.
        let n = Vec3::new(0.3, -0.8, 0.52).normalize();
        let mut r = Pcg32::new(3, 0, 0);
        let m = 50_000;
        let mut s = 0.0f64;
        for _ in 0..m {
            let d = cosine_sample(n, &mut r);
            assert!(d.dot(n) >= -1e-6);
            assert!((d.length() - 1.0).abs() < 1e-5);
            s += d.dot(n) as f64;
        }
        assert!((s / m as f64 - 2.0 / 3.0).abs() < 0.005, "{}", s / m as f64);
    }

    /// In a closed sphere of albedo `rho` lit by a point light at its centre, every wall
    /// point sees uniform radiance, so the indirect vector irradiance is
    /// `rho/(1-rho) E0` along the inward normal (`E0 = I/R^2`) and zero across it.
    #[test]
    fn vector_irradiance_in_a_closed_sphere_points_along_the_normal() {
        let scene = mlt_scenes::load_scene("builtin:sphere?albedo=0.5&radius=1").unwrap();
        let caster = scene.build_caster();
        let light = Light::point(Vec3::ZERO, [1.0; 3]).unwrap();
        let points: Vec<Probe> = [
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, -1.0, 0.0),
            Vec3::new(0.6, 0.0, 0.8),
        ]
        .iter()
        .map(|&x| Probe {
            position: x,
            normal: -x,
        })
        .collect();
        let opts = ReferenceOptions::new(2000, 5);
        let (v, se) = reference_vector_irradiance(caster.as_ref(), &light, &points, &opts).unwrap();
        for (k, p) in points.iter().enumerate() {
            for c in 0..3 {
                let e = Vec3::new(v[9 * k + 3 * c], v[9 * k + 3 * c + 1], v[9 * k + 3 * c + 2]);
                let along = e.dot(p.normal);
                let across = (e - p.normal * along).length();
                let tol = 4.0 * se[k] + 0.01;
                assert!(
                    (along - 1.0).abs() < tol,
                    "point {k}: {along} (se {})",
                    se[k]
                );
                assert!(across < 2.0 * tol, "point {k}: tangential {across}");
            }
        }
    }

    /// With a bounce cap `B` the closed sphere's vector irradiance is the series' first `B`
    /// terms, `E0 (rho + .. + rho^B)` along the normal: the cap counts bounces as the camera
    /// reference's `--max-bounces` does (the first bounce is bounce 1).
    #[test]
    fn vector_irradiance_bounce_cap_counts_like_the_reference() {
        let scene = mlt_scenes::load_scene("builtin:sphere?albedo=0.5&radius=1").unwrap();
        let caster = scene.build_caster();
        let light = Light::point(Vec3::ZERO, [1.0; 3]).unwrap();
        let points = [Probe {
            position: Vec3::new(0.0, 0.0, 1.0),
            normal: Vec3::new(0.0, 0.0, -1.0),
        }];
        for (cap, want) in [(1u32, 0.5f32), (2, 0.75), (3, 0.875)] {
            let mut opts = ReferenceOptions::new(2000, 9);
            opts.max_bounces = cap;
            let (v, se) =
                reference_vector_irradiance(caster.as_ref(), &light, &points, &opts).unwrap();
            let along = Vec3::new(v[0], v[1], v[2]).dot(points[0].normal);
            assert!(
                (along - want).abs() < 4.0 * se[0] + 0.01,
                "cap {cap}: {along}, expected {want} (se {})",
                se[0]
            );
        }
    }

    #[test]
    fn odd_or_zero_spp_is_refused() {
        assert!(ReferenceOptions::new(3, 0).check().is_err());
        assert!(ReferenceOptions::new(0, 0).check().is_err());
        assert!(ReferenceOptions::new(2, 0).check().is_ok());
    }
}
