//! The direct light at a sender point as its basis function sees it, for a light close to the
//! surface (section 3.3, the samples `E` of the projection `e = P-dagger E`).
//!
//! The pull-push treats the sample at a point as the value of the light over the point's
//! basis function. Far from the light the irradiance is smooth over a support and the
//! irradiance at the point is that value. A light closer than a few support radii makes a
//! hot spot narrower than the spacing of the points: a sample at one point then misses the
//! flux that lands between points (or, right under the light, counts it many times over),
//! and the energy of the projected light depends on where the light is.
//!
//! Near the light the sample is therefore the average of the unoccluded irradiance over the
//! point's normalised basis function `B_j` (Eq. 2) on its tangent plane:
//! `E_j = int B_j E dA / int B_j dA`. Since the `B_j` of a level sum to one, the `E_j`
//! weighted by the functions' areas add up to the flux the plane receives, wherever the light
//! is. The integral over the support is taken in the light's solid angle: for a point light
//! at height `h` over the plane, the flux through the ring between radii `a` and `b` around
//! the foot of the light is `I dphi (h / sqrt(h^2 + a^2) - h / sqrt(h^2 + b^2))` per angle
//! `dphi`, exactly, however narrow the hot spot. The rings are spaced geometrically in
//! `rho + h` (fine under the light, coarse far from it), over the radii and, when the foot
//! lies outside the support, the angles that the support covers; each ring sector takes the
//! value of `B_j` (and of a spot's cone) at its middle. `B_j` is tabulated once per point on a
//! grid over its support (interpolated bilinearly), and `int B_j dA` is the table's sum, so a
//! frame needs no R-tree query. The table is zero off the surface (beyond the edge of a wall:
//! farther than a little more than the finest level's spacing from its points), since a
//! function carries light only where it lies on a surface.
//!
//! Visibility is not part of this average: the caller multiplies by the shadow rays' mean.

use std::f64::consts::TAU;
use std::sync::OnceLock;

use glam::Vec3;

use crate::kernel::weight;
use crate::light_model::{Cone, Light};
use crate::shepard::{IndexedBasis, MIN_WEIGHT_SUM};

/// Within this many support radii of the light a sample is wholly the support average, as
/// far as the distance goes.
pub const NEAR_FULL: f32 = 2.0;
/// Beyond this many support radii it is wholly the point sample; in between the two blend
/// linearly, so that a moving light changes the samples continuously.
pub const NEAR_NONE: f32 = 3.0;
/// The same for the light's height over the point's tangent plane: the hot spot is narrower
/// than the support only below about one radius. (Higher, the tangent plane would also stand
/// in badly for a curved surface: the irradiance inside a sphere with the light at its
/// centre is constant, on the tangent plane it is not.)
pub const LOW_FULL: f32 = 0.5;
pub const LOW_NONE: f32 = 1.0;

/// Rings and sectors of the flux quadrature around the foot of the light.
const RINGS: usize = 16;
const SECTORS: usize = 8;
/// How many of the finest level's Poisson-disk radii from its nearest point a point still
/// counts as on the surface.
const ON_SURFACE: f32 = 1.5;
/// Cells per side of the table of a basis function over its support square.
const GRID: usize = 16;

/// The weight of the support average against the point sample for a light at distance
/// `dist` from a point of support radius `r` and at height `height` over its tangent plane:
/// 1 within [`NEAR_FULL`] radii and below [`LOW_FULL`] radii, 0 beyond [`NEAR_NONE`] or
/// above [`LOW_NONE`] radii, linear in between.
pub fn near_weight(dist: f32, height: f32, r: f32) -> f32 {
    // Also for a NaN radius.
    if r.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return 0.0;
    }
    let near = ((NEAR_NONE - dist / r) / (NEAR_NONE - NEAR_FULL)).clamp(0.0, 1.0);
    let low = ((LOW_NONE - height / r) / (LOW_NONE - LOW_FULL)).clamp(0.0, 1.0);
    near * low
}

/// Support averages of the direct light over the basis functions of an [`IndexedBasis`].
/// Each function is tabulated over its support on first use (the same values for any thread
/// order), so that a frame needs no R-tree query.
pub struct SupportAverage<'a> {
    ib: &'a IndexedBasis,
    tables: Vec<OnceLock<Table>>,
}

/// A basis function `B_j` on its tangent plane: values at the centres of a `GRID x GRID`
/// grid over the square `[-r_j, r_j]^2` (in the point's tangent frame), and its integral.
struct Table {
    values: Box<[f32]>,
    area: f32,
}

impl<'a> SupportAverage<'a> {
    /// Averages over the functions of the first `points` points of `ib`.
    pub fn new(ib: &'a IndexedBasis, points: usize) -> SupportAverage<'a> {
        let points = points.min(ib.basis.len());
        SupportAverage {
            ib,
            tables: (0..points).map(|_| OnceLock::new()).collect(),
        }
    }

    /// Builds now, in parallel, the tables of the points `j` with `wanted[j]` (as a frame near
    /// them would on first use), so that no frame pays for them.
    pub fn build_tables(&self, wanted: &[bool]) {
        use rayon::prelude::*;
        (0..self.tables.len().min(wanted.len()))
            .into_par_iter()
            .filter(|&j| wanted[j])
            .for_each(|j| {
                self.table(j);
            });
    }

    /// Heap bytes of the tables built so far.
    pub fn bytes(&self) -> usize {
        let built = self.tables.iter().filter(|t| t.get().is_some()).count();
        self.tables.len() * std::mem::size_of::<OnceLock<Table>>() + built * GRID * GRID * 4
    }

    /// The value at `x` of point `j`'s normalised basis function on its tangent plane (whose
    /// normal `n` is the point's): `w_j / sum_k w_k` over `j`'s level (Eq. 2); 0 off the
    /// surface.
    fn basis_value(&self, j: usize, level: usize, x: Vec3, n: Vec3) -> f32 {
        let b = &self.ib.basis;
        let (xa, na) = (x.to_array(), n.to_array());
        let w = weight(xa, na, b.positions[j], b.normals[j], b.radii[j]);
        if w <= 0.0 || self.ib.clip.cuts(j, xa) {
            return 0.0;
        }
        let sum = self.ib.weight_sum(level, xa, na);
        if sum > MIN_WEIGHT_SUM && self.on_surface(x, n) {
            w / sum
        } else {
            0.0
        }
    }

    /// Whether the tangent-plane point `x` (normal `n`) lies on the surface: within
    /// [`ON_SURFACE`] Poisson-disk radii of a point of the finest level that faces the same
    /// way, as the finest points cover the surface at that spacing. Beyond the edge of a wall,
    /// say, a function carries no light.
    pub fn on_surface(&self, x: Vec3, n: Vec3) -> bool {
        let b = &self.ib.basis;
        let finest = self.ib.levels() - 1;
        let reach = ON_SURFACE * b.disk_radii[finest];
        let mut found = false;
        self.ib
            .for_each_weight(finest, x.to_array(), n.to_array(), |k, _| {
                found |= Vec3::from(b.positions[k]).distance_squared(x) <= reach * reach;
            });
        found
    }

    /// Point `j`'s table, built on first use.
    fn table(&self, j: usize) -> &Table {
        self.tables[j].get_or_init(|| {
            let b = &self.ib.basis;
            let (p, n) = (Vec3::from(b.positions[j]), Vec3::from(b.normals[j]));
            let (r, level) = (b.radii[j], b.level_of(j));
            let (t, bt) = n.any_orthonormal_pair();
            let cell = 2.0 * r / GRID as f32;
            let centre = |i: usize| -r + (i as f32 + 0.5) * cell;
            let mut values = vec![0.0f32; GRID * GRID];
            let mut sum = 0.0f64;
            for iv in 0..GRID {
                for iu in 0..GRID {
                    let x = p + t * centre(iu) + bt * centre(iv);
                    let v = self.basis_value(j, level, x, n);
                    values[iv * GRID + iu] = v;
                    sum += f64::from(v);
                }
            }
            Table {
                values: values.into_boxed_slice(),
                area: (sum * f64::from(cell) * f64::from(cell)) as f32,
            }
        })
    }

    /// `int B_j dA` over point `j`'s tangent plane (on the surface).
    pub fn area(&self, j: usize) -> f32 {
        self.table(j).area
    }

    /// `int B_j E dA` over point `j`'s tangent plane: the unoccluded flux of `light` that the
    /// function receives, RGB.
    pub fn flux(&self, j: usize, light: &Light) -> [f32; 3] {
        let b = &self.ib.basis;
        let (p, n) = (Vec3::from(b.positions[j]), Vec3::from(b.normals[j]));
        let r = b.radii[j];
        let height = (light.position - p).dot(n);
        if !(height > 0.0 && r > 0.0) {
            return [0.0; 3];
        }
        // A light on the plane itself sends its flux into a point: keep a tiny height.
        let h = f64::from(height.max(1e-4 * r));
        let foot = light.position - n * height;
        let (t, bt) = n.any_orthonormal_pair();
        let to_p = p - foot;
        let s = f64::from(to_p.length());
        let r64 = f64::from(r);
        // The radii and angles (around the foot) that the support covers.
        let (rho0, rho1) = ((s - r64).max(0.0), s + r64);
        let (phi0, span) = if s > r64 {
            let centre = f64::from(to_p.dot(bt)).atan2(f64::from(to_p.dot(t)));
            let half = (r64 / s).asin();
            (centre - half, 2.0 * half)
        } else {
            (0.0, TAU)
        };
        // Ring `a` spans the radii `(rho0 + h) q^a - h` to `(rho0 + h) q^(a+1) - h`.
        let q = ((rho1 + h) / (rho0 + h)).powf(1.0 / RINGS as f64);
        let cosine = |rho: f64| h / (h * h + rho * rho).sqrt();
        // The radius at which the cosine of the angle from the normal is `c`.
        let radius_of = |c: f64| (h * (1.0 / (c * c) - 1.0).max(0.0).sqrt()) as f32;
        let sector = span / SECTORS as f64;
        let table = self.table(j);
        let cell = 2.0 * r / GRID as f32;
        let foot_uv = (-to_p.dot(t), -to_p.dot(bt));
        // The sectors' middle directions, by rotation from the first: on a full circle every
        // other ring is turned by half a sector.
        let step = (sector.cos(), sector.sin());
        let directions = |turn: f64| {
            let a = phi0 + sector * turn;
            let mut d = (a.cos(), a.sin());
            std::array::from_fn::<(f64, f64, f64), SECTORS, _>(|k| {
                let here = d;
                d = (d.0 * step.0 - d.1 * step.1, d.0 * step.1 + d.1 * step.0);
                (here.0, here.1, a + sector * k as f64)
            })
        };
        let (even, odd) = if span < TAU {
            let d = directions(0.5);
            (d, d)
        } else {
            (directions(0.0), directions(0.5))
        };
        let mut acc = 0.0f64;
        let mut outer = rho0 + h;
        let mut cb = cosine(rho0);
        for a in 0..RINGS {
            let ca = cb;
            outer *= q;
            cb = cosine(outer - h);
            let solid_angle = (ca - cb) * sector;
            // The middle of the ring in solid angle.
            let rho = radius_of(0.5 * (ca + cb));
            let dirs = if a % 2 == 0 { &even } else { &odd };
            for &(cos, sin, phi) in dirs {
                let (u, v) = (foot_uv.0 + rho * cos as f32, foot_uv.1 + rho * sin as f32);
                let value = bilinear(&table.values, (u + r) / cell - 0.5, (v + r) / cell - 0.5);
                if value > 0.0 {
                    let cone = cone_average(light, foot, (t, bt), phi, sector, (ca, cb), radius_of);
                    acc += f64::from(value * cone) * solid_angle;
                }
            }
        }
        let acc = acc as f32;
        light.intensity.map(|i| i * acc)
    }

    /// The direct-light sample at point `j` before visibility, as the viewer's relighting and
    /// the bake's estimates take it: the light's irradiance at the point, blended toward the
    /// support average ([`SupportAverage::irradiance`]) by [`near_weight`]; and whether the
    /// average took part.
    pub fn sample(&self, j: usize, light: &Light) -> ([f32; 3], bool) {
        let b = &self.ib.basis;
        let (x, n) = (Vec3::from(b.positions[j]), Vec3::from(b.normals[j]));
        let e = light.irradiance(x, n);
        let near = near_weight(
            light.position.distance(x),
            (light.position - x).dot(n),
            b.radii[j],
        );
        if near > 0.0 {
            let avg = self.irradiance(j, light);
            (
                std::array::from_fn(|c| near * avg[c] + (1.0 - near) * e[c]),
                true,
            )
        } else {
            (e, false)
        }
    }

    /// The support average `int B_j E dA / int B_j dA` of the unoccluded irradiance, RGB.
    pub fn irradiance(&self, j: usize, light: &Light) -> [f32; 3] {
        let area = self.area(j);
        if area.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return [0.0; 3];
        }
        self.flux(j, light).map(|f| f / area)
    }
}

/// Bilinear interpolation of a `GRID x GRID` table at the fractional cell-centre indices
/// `(fu, fv)`; 0 outside the table.
fn bilinear(values: &[f32], fu: f32, fv: f32) -> f32 {
    let (u0, v0) = (fu.floor(), fv.floor());
    let (du, dv) = (fu - u0, fv - v0);
    let at = |iu: f32, iv: f32| {
        if iu < 0.0 || iv < 0.0 || iu >= GRID as f32 || iv >= GRID as f32 {
            0.0
        } else {
            values[iv as usize * GRID + iu as usize]
        }
    };
    (1.0 - dv) * ((1.0 - du) * at(u0, v0) + du * at(u0 + 1.0, v0))
        + dv * ((1.0 - du) * at(u0, v0 + 1.0) + du * at(u0 + 1.0, v0 + 1.0))
}

/// The unit vector at angle `phi` in the plane spanned by `t` and `bt`.
fn in_plane(t: Vec3, bt: Vec3, phi: f64) -> Vec3 {
    let phi = phi as f32;
    t * phi.cos() + bt * phi.sin()
}

/// The mean of a spot's cone factor over the ring sector centred on the angle `phi` (width
/// `sector`) between the cosines `ca` and `cb` from the normal: 8 x 2 points uniform in solid
/// angle, since a cone's edge may cross the sector. 1 for a point light.
fn cone_average(
    light: &Light,
    foot: Vec3,
    (t, bt): (Vec3, Vec3),
    phi: f64,
    sector: f64,
    (ca, cb): (f64, f64),
    radius_of: impl Fn(f64) -> f32,
) -> f32 {
    if light.cone == Cone::None {
        return 1.0;
    }
    let mut sum = 0.0f32;
    for q in 0..8 {
        let rho = radius_of(ca + (cb - ca) * (q as f64 + 0.5) / 8.0);
        for side in [-0.25, 0.25] {
            let x = foot + in_plane(t, bt, phi + side * sector) * rho;
            sum += light.cone_factor((x - light.position).normalize_or_zero());
        }
    }
    sum / 16.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_support::plane_basis;

    fn light_at(x: f32, y: f32, h: f32) -> Light {
        Light::point(Vec3::new(x, y, h), [1.0, 2.0, 0.5]).unwrap()
    }

    #[test]
    fn near_weight_blends_between_the_two_distances() {
        assert_eq!(near_weight(1.0, 0.1, 1.0), 1.0);
        assert_eq!(near_weight(2.0, 0.5, 1.0), 1.0);
        assert_eq!(near_weight(2.5, 0.1, 1.0), 0.5);
        assert_eq!(near_weight(2.0, 0.75, 1.0), 0.5);
        assert_eq!(near_weight(3.0, 0.1, 1.0), 0.0);
        assert_eq!(near_weight(1.0, 1.0, 1.0), 0.0);
        assert_eq!(near_weight(1.0, 0.1, 0.0), 0.0);
    }

    /// The flux that the functions of one level receive adds up to the flux through the
    /// plane, wherever the light is and however close.
    #[test]
    fn a_level_receives_the_flux_of_the_plane_at_any_height() {
        let ib = plane_basis(4, 3);
        let b = &ib.basis;
        let avg = SupportAverage::new(&ib, b.len());
        let level_flux = |level: usize, light: &Light| -> f32 {
            b.level_range(level).map(|j| avg.flux(j, light)[0]).sum()
        };
        for level in 1..3 {
            let overhang = b.radii[b.level_range(level).start];
            // A point light: between the flux through the unit square and through the square
            // grown by the support radius (the functions cover the one and not the other).
            for h in [0.01f32, 0.005, 0.002, 0.0005] {
                for (x, y) in [(0.5f32, 0.5f32), (0.43, 0.58)] {
                    let light = light_at(x, y, h);
                    let total = level_flux(level, &light);
                    let low = rectangle_solid_angle(x, y, h, 0.0);
                    let high = rectangle_solid_angle(x, y, h, overhang);
                    assert!(
                        total > 0.99 * low && total < 1.01 * high,
                        "level {level} h {h}: {total} not in [{low}, {high}]"
                    );
                }
            }
            // A smooth spot whose cone lands well inside the square: its whole flux,
            // `2 pi I ((1 - cos_inner) + (cos_inner - cos_outer) / 3)`.
            for h in [0.2f32, 0.05, 0.01, 0.002] {
                let light =
                    Light::spot(Vec3::new(0.47, 0.52, h), [1.0; 3], -Vec3::Z, 40.0, true).unwrap();
                let (ci, co) = (10f32.to_radians().cos(), 20f32.to_radians().cos());
                let want = std::f32::consts::TAU * ((1.0 - ci) + (ci - co) / 3.0);
                let total = level_flux(level, &light);
                assert!(
                    (total / want - 1.0).abs() < 0.01,
                    "spot, level {level} h {h}: {total} vs {want}"
                );
            }
        }
    }

    /// Far from the light the support average is the point sample (a smooth irradiance).
    #[test]
    fn far_from_the_light_the_average_is_the_point_sample() {
        let ib = plane_basis(4, 3);
        let b = &ib.basis;
        let avg = SupportAverage::new(&ib, b.len());
        let light = light_at(0.5, 0.5, 1.5);
        for j in b.level_range(2).step_by(7) {
            let p = Vec3::from(b.positions[j]);
            if (p.x - 0.5).abs() > 0.3 || (p.y - 0.5).abs() > 0.3 {
                continue;
            }
            let point = light.irradiance(p, Vec3::from(b.normals[j]))[1];
            let average = avg.irradiance(j, &light)[1];
            assert!((average / point - 1.0).abs() < 0.02, "{average} vs {point}");
        }
    }

    /// Solid angle of the square `[-g, 1 + g]^2` (z = 0) seen from `(x, y, h)`.
    fn rectangle_solid_angle(x: f32, y: f32, h: f32, g: f32) -> f32 {
        let (x, y, h, g) = (f64::from(x), f64::from(y), f64::from(h), f64::from(g));
        // Solid angle of the rectangle [0,a]x[0,b] from a point at height h above its corner.
        let corner = |a: f64, b: f64| (a * b / (h * (h * h + a * a + b * b).sqrt())).atan();
        let (x0, x1, y0, y1) = (x + g, 1.0 + g - x, y + g, 1.0 + g - y);
        let q = [(x1, y1), (x0, y1), (x1, y0), (x0, y0)];
        q.iter().map(|&(a, b)| corner(a, b)).sum::<f64>() as f32
    }
}
