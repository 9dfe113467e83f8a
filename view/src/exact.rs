//! Exact per-pixel evaluation of the indirect image, the yardstick of the flat basis the
//! renderer splats: at each pixel's surface point `(x, n)` (ray cast through the pixel centre,
//! as the G-buffer rasterises it) the hierarchical expansion of the receivers' coefficients is
//! evaluated directly, `E(x) = sum_l sum_{k in X_l} i_k B^l_k(x, n)` (Eq. 6), and the pixel is
//! `rho / pi * max(0, n . E_c)` per colour channel `c`, as the resolve pass shades the
//! vector irradiance. The same pixels can be evaluated through the flat basis
//! ([`FlatBasis::reconstruct`]) to see what flattening alone changes.

use mlt_format::flat_basis::FlatBasis;
use mlt_format::links::LINK_DIM;
use mlt_format::IndexedBasis;
use mlt_scenes::RayCaster;
use rayon::prelude::*;

use crate::camera::Camera;
use crate::images::RgbImage;

/// A pixel's visible surface point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfacePoint {
    pub position: [f32; 3],
    /// Shading normal, facing the camera.
    pub normal: [f32; 3],
    pub albedo: [f32; 3],
}

/// The surface point of every pixel of `camera` (rows from the top), `None` where the
/// primary ray through the pixel centre hits nothing.
pub fn surface_points(camera: &Camera, caster: &dyn RayCaster) -> Vec<Option<SurfacePoint>> {
    let w = camera.width;
    (0..camera.width * camera.height)
        .into_par_iter()
        .map(|idx| {
            let (px, py) = ((idx % w) as f32, (idx / w) as f32);
            let dir = camera.ray_direction(px + 0.5, py + 0.5);
            caster
                .intersect(camera.position, dir, 0.0, f32::INFINITY)
                .map(|hit| SurfacePoint {
                    position: hit.position.to_array(),
                    normal: hit.shading_normal.to_array(),
                    albedo: hit.albedo,
                })
        })
        .collect()
}

/// Outgoing indirect radiance `rho / pi * max(0, n . E_c)` of a vector irradiance `e`
/// (`LINK_DIM` floats: three per channel).
pub fn shade(p: &SurfacePoint, e: &[f32]) -> [f32; 3] {
    let n = p.normal;
    std::array::from_fn(|c| {
        let v = &e[3 * c..3 * c + 3];
        let irr = (n[0] * v[0] + n[1] * v[1] + n[2] * v[2]).max(0.0);
        p.albedo[c] * std::f32::consts::FRAC_1_PI * irr
    })
}

/// The indirect image from the hierarchical expansion of `i` (`LINK_DIM` per hierarchical
/// point), evaluated exactly at every pixel (Eq. 6). `width` is the image width of `points`.
pub fn exact_indirect(
    ib: &IndexedBasis,
    i: &[f32],
    points: &[Option<SurfacePoint>],
    width: u32,
) -> RgbImage {
    image(points, width, |p| {
        let mut e = [0.0f32; LINK_DIM];
        ib.reconstruct(i, LINK_DIM, 0..ib.levels(), p.position, p.normal, &mut e);
        shade(p, &e)
    })
}

/// The indirect image from the flat expansion `flat` (`LINK_DIM` per flat point), evaluated on
/// the CPU at every pixel, as the renderer's splatting computes it.
pub fn flat_indirect(
    fb: &FlatBasis,
    flat: &[f32],
    points: &[Option<SurfacePoint>],
    width: u32,
) -> RgbImage {
    image(points, width, |p| {
        let mut e = [0.0f32; LINK_DIM];
        fb.reconstruct(flat, LINK_DIM, p.position, p.normal, &mut e);
        shade(p, &e)
    })
}

/// The flat image with each covering flat point's value taken at the pixel's own normal,
/// `sum_i w_i(x, n) F(p_i, n) / sum_i w_i(x, n)` with `F` the hierarchical expansion of `i`
/// (Eq. 6), where the flat coefficients hold `F(p_i, n_i)`. Eq. 6 depends on the normal
/// through the weights' `(n . n_k)^2` (which functions of each level a surface point
/// averages), which one coefficient per flat point cannot carry; against [`exact_indirect`]
/// this image keeps everything else flattening changes (with the values not sharpened). For
/// diagnosis only: a hierarchical evaluation per covering function and pixel.
pub fn flat_indirect_at_pixel_normals(
    fb: &FlatBasis,
    ib: &IndexedBasis,
    i: &[f32],
    points: &[Option<SurfacePoint>],
    width: u32,
) -> RgbImage {
    let b = &ib.basis;
    image(points, width, |p| {
        let mut acc = [0.0f32; LINK_DIM];
        let mut e = [0.0f32; LINK_DIM];
        let sum = fb.for_each_weight(p.position, p.normal, |q, w| {
            let j = fb.source[q] as usize;
            ib.reconstruct(
                i,
                LINK_DIM,
                0..ib.levels(),
                b.positions[j],
                p.normal,
                &mut e,
            );
            for (a, v) in acc.iter_mut().zip(&e) {
                *a += w * v;
            }
        });
        if sum > mlt_format::shepard::MIN_WEIGHT_SUM {
            acc.iter_mut().for_each(|a| *a /= sum);
        } else {
            acc = [0.0; LINK_DIM];
        }
        shade(p, &acc)
    })
}

/// Number of flat functions covering each pixel (`None` where no surface is seen).
pub fn flat_coverage(fb: &FlatBasis, points: &[Option<SurfacePoint>]) -> Vec<Option<usize>> {
    points
        .par_iter()
        .map(|p| p.map(|p| fb.coverage(p.position, p.normal)))
        .collect()
}

fn image(
    points: &[Option<SurfacePoint>],
    width: u32,
    f: impl Fn(&SurfacePoint) -> [f32; 3] + Sync,
) -> RgbImage {
    let height = points.len() as u32 / width.max(1);
    let pixels = points
        .par_iter()
        .map(|p| p.as_ref().map_or([0.0; 3], &f))
        .collect();
    RgbImage {
        width,
        height,
        pixels,
    }
}

/// Smallest cosine between two pixels' normals for [`dark_pixels`] to count them as one
/// surface.
pub const SAME_SURFACE_COS: f32 = 0.9;

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Pixels of `image` (at surface pixels of `points`) darker than `fraction` times the median
/// luminance of their `(2 radius + 1)^2` neighbourhood's pixels on the same surface (normals
/// within [`SAME_SURFACE_COS`] of the pixel's), where that median is above `floor`: dark
/// blotches. Pixels of other surfaces are left out of the median: across an edge the light
/// can differ by more than `1 / fraction` (the top and the front of a block under a light near
/// the ceiling), which is no blotch; nor are pixels with fewer than half of their window on
/// their own surface (at its edges the window is one-sided). Returns their indices, ascending.
pub fn dark_pixels(
    image: &RgbImage,
    points: &[Option<SurfacePoint>],
    radius: u32,
    fraction: f32,
    floor: f32,
) -> Vec<usize> {
    let (w, h) = (image.width as i64, image.height as i64);
    let lum = |k: usize| crate::images::luminance(image.pixels[k]);
    let mut dark = Vec::new();
    let mut window = Vec::new();
    for k in 0..image.pixels.len() {
        let Some(n) = points[k].map(|p| p.normal) else {
            continue;
        };
        let (x, y) = (k as i64 % w, k as i64 / w);
        window.clear();
        let r = radius as i64;
        for yy in (y - r).max(0)..(y + r + 1).min(h) {
            for xx in (x - r).max(0)..(x + r + 1).min(w) {
                let q = (yy * w + xx) as usize;
                if points[q].is_some_and(|p| dot(p.normal, n) >= SAME_SURFACE_COS) {
                    window.push(lum(q));
                }
            }
        }
        // At an edge of its surface the window is one-sided and the median is that of the
        // surface's interior, not of the pixel's surroundings.
        if 2 * window.len() < ((2 * r + 1) * (2 * r + 1)) as usize {
            continue;
        }
        window.sort_unstable_by(f32::total_cmp);
        let median = window[window.len() / 2];
        if median > floor && lum(k) < fraction * median {
            dark.push(k);
        }
    }
    dark
}

/// How much looser the reference's own test is in [`blotches`]: a pixel of the reference
/// darker than `REFERENCE_SLACK * fraction` of its neighbourhood is dark there too. The slack
/// absorbs the reference's noise and its box filter (the image is at pixel centres).
pub const REFERENCE_SLACK: f32 = 2.0;

/// The [`dark_pixels`] of `image` where the path-traced `reference` (same camera, same
/// light) is not dark as well: blotches of the solution, not the light's own shape. A pixel
/// where a block stands on the floor can be darker than a quarter of its neighbourhood in the
/// true light (the floor there sees the unlit side of the block over half its hemisphere), and
/// a solution that resolves that contact shadow is right, not blotched; a patch the basis
/// leaves unsupported is dark in the solution alone. `image` and `reference` may be in
/// different units (irradiance, radiance): each is compared with its own neighbourhood.
pub fn blotches(
    image: &RgbImage,
    reference: &RgbImage,
    points: &[Option<SurfacePoint>],
    radius: u32,
    fraction: f32,
    floor: f32,
) -> Vec<usize> {
    assert_eq!(
        (image.width, image.height),
        (reference.width, reference.height),
        "the reference has another size"
    );
    let dark_in_reference = dark_pixels(reference, points, radius, REFERENCE_SLACK * fraction, 0.0);
    dark_pixels(image, points, radius, fraction, floor)
        .into_iter()
        .filter(|k| dark_in_reference.binary_search(k).is_err())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 9x9 view of one flat surface, every pixel lit at 1 but those given at 0.1.
    fn flat_view(dark: &[usize]) -> (RgbImage, Vec<Option<SurfacePoint>>) {
        let mut image = RgbImage::new(9, 9);
        image.pixels.fill([1.0; 3]);
        for &k in dark {
            image.pixels[k] = [0.1; 3];
        }
        let p = SurfacePoint {
            position: [0.0; 3],
            normal: [0.0, 0.0, 1.0],
            albedo: [0.5; 3],
        };
        (image, vec![Some(p); 81])
    }

    #[test]
    fn a_dark_pixel_is_a_blotch_only_where_the_reference_is_not_dark() {
        let centre = 4 * 9 + 4;
        let (solution, points) = flat_view(&[centre, centre + 1]);
        assert_eq!(
            dark_pixels(&solution, &points, 3, 0.25, 1e-3),
            vec![centre, centre + 1]
        );
        // The reference is dark at the centre as well (a contact shadow), a third as dark as
        // its neighbourhood at the next pixel (within the slack: dark too), bright elsewhere.
        let (mut reference, _) = flat_view(&[centre]);
        reference.pixels[centre + 1] = [0.45; 3];
        assert_eq!(
            blotches(&solution, &reference, &points, 3, 0.25, 1e-3),
            Vec::<usize>::new()
        );
        // A reference lit where the solution is dark: both are blotches.
        let (lit, _) = flat_view(&[]);
        assert_eq!(
            blotches(&solution, &lit, &points, 3, 0.25, 1e-3),
            vec![centre, centre + 1]
        );
        // Units do not matter: the reference in radiance, the solution in irradiance.
        let mut scaled = reference.clone();
        for p in &mut scaled.pixels {
            *p = p.map(|v| v / std::f32::consts::PI);
        }
        assert_eq!(
            blotches(&solution, &scaled, &points, 3, 0.25, 1e-3),
            Vec::<usize>::new()
        );
    }
}
