//! How well the flat basis stands in for the hierarchical expansion in one view (section 4.1):
//! how many flat functions cover each surface pixel (the splat pass's overdraw; a pixel with
//! none would be black), and the flat indirect image against the exact per-pixel evaluation
//! of Eq. 6 ([`crate::exact`]), both on the CPU at the pixel centres' surface points.

use mlt_format::flat_basis::FlatBasis;
use mlt_format::IndexedBasis;
use mlt_scenes::RayCaster;
use serde::Serialize;

use crate::camera::Camera;
use crate::exact::{
    exact_indirect, flat_coverage, flat_indirect, flat_indirect_at_pixel_normals, surface_points,
    SurfacePoint,
};
use crate::images::{luminance, RgbImage};

/// Width of a bin of [`FlatCheck::histogram`], in covering functions.
pub const BIN: usize = 4;
/// Bins of [`FlatCheck::histogram`]; the last one holds everything above.
pub const BINS: usize = 8;

/// The figures of one view.
#[derive(Clone, Debug, Serialize)]
pub struct FlatCheck {
    pub flat_points: usize,
    pub hierarchical_points: usize,
    /// Per level of the hierarchical basis: its points, and how many of them the flat basis
    /// keeps.
    pub points_per_level: Vec<usize>,
    pub flat_per_level: Vec<usize>,
    pub width: u32,
    pub height: u32,
    /// Pixels whose centre sees a surface.
    pub surface_pixels: usize,
    /// Mean number of flat functions with a positive weight at a surface pixel.
    pub coverage_mean: f64,
    /// Surface pixels by covering functions, in bins of [`BIN`] (`0-3`, `4-7`, ...).
    pub histogram: [usize; BINS],
    /// The most functions covering one pixel.
    pub coverage_max: usize,
    /// Surface pixels no flat function covers.
    pub uncovered: usize,
    /// Relative RMS difference of the flat indirect image's luminance from the exact one's.
    pub rel_rmse: f64,
    /// The same with each flat point's value taken at the pixel's normal
    /// ([`FlatCheck::split_by_normal`]; `None` until measured): what flattening changes apart
    /// from Eq. 6's dependence on the normal.
    pub rel_rmse_at_pixel_normals: Option<f64>,
    /// Surface pixels where the flat image is below a quarter of the exact one (where that is
    /// above a thousandth of its maximum): dark spots that flattening adds.
    pub darker: Vec<usize>,
    /// The surface point of each pixel, and the exact indirect image.
    #[serde(skip)]
    pub points: Vec<Option<SurfacePoint>>,
    #[serde(skip)]
    pub exact: RgbImage,
}

/// Relative RMS difference of the luminances of `a` from `reference`.
pub fn rel_rmse(a: &RgbImage, reference: &RgbImage) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (x, y) in a.pixels.iter().zip(&reference.pixels) {
        let (x, y) = (f64::from(luminance(*x)), f64::from(luminance(*y)));
        num += (x - y).powi(2);
        den += y * y;
    }
    (num / den).sqrt()
}

impl FlatCheck {
    /// Measures the flat basis `fb` with the flat coefficients `flat` against the hierarchical
    /// basis `hier` with the receivers' coefficients `i` (`LINK_DIM` floats per point each) in
    /// the view of `camera`, whose surface points `caster` finds.
    pub fn measure(
        hier: &IndexedBasis,
        i: &[f32],
        fb: &FlatBasis,
        flat: &[f32],
        camera: &Camera,
        caster: &dyn RayCaster,
    ) -> FlatCheck {
        let w = camera.width;
        let points = surface_points(camera, caster);
        let counts: Vec<usize> = flat_coverage(fb, &points).into_iter().flatten().collect();
        let mut histogram = [0usize; BINS];
        for &c in &counts {
            histogram[(c / BIN).min(BINS - 1)] += 1;
        }
        let exact = exact_indirect(hier, i, &points, w);
        let flat_image = flat_indirect(fb, flat, &points, w);
        let max_lum = exact
            .pixels
            .iter()
            .map(|p| luminance(*p))
            .fold(0.0, f32::max);
        let floor = 1e-3 * max_lum;
        let darker = (0..flat_image.pixels.len())
            .filter(|&k| {
                let e = luminance(exact.pixels[k]);
                e > floor && luminance(flat_image.pixels[k]) < 0.25 * e
            })
            .collect();
        let b = &hier.basis;
        let mut flat_per_level = vec![0usize; b.levels()];
        for &j in &fb.source {
            flat_per_level[b.level_of(j as usize)] += 1;
        }
        FlatCheck {
            flat_points: fb.len(),
            hierarchical_points: hier.basis.len(),
            points_per_level: (0..b.levels()).map(|l| b.level_range(l).len()).collect(),
            flat_per_level,
            width: w,
            height: camera.height,
            surface_pixels: counts.len(),
            coverage_mean: counts.iter().sum::<usize>() as f64 / counts.len().max(1) as f64,
            histogram,
            coverage_max: counts.iter().copied().max().unwrap_or(0),
            uncovered: counts.iter().filter(|&&c| c == 0).count(),
            rel_rmse: rel_rmse(&flat_image, &exact),
            rel_rmse_at_pixel_normals: None,
            darker,
            points,
            exact,
        }
    }

    /// Measures [`FlatCheck::rel_rmse_at_pixel_normals`] for the hierarchical coefficients `i`
    /// and flat basis `fb` that [`FlatCheck::measure`] was given. Slow (a hierarchical
    /// evaluation per covering function and pixel: about 20 s at 640x360 on Sponza on two
    /// cores).
    pub fn split_by_normal(&mut self, hier: &IndexedBasis, i: &[f32], fb: &FlatBasis) {
        let at_normals = flat_indirect_at_pixel_normals(fb, hier, i, &self.points, self.width);
        self.rel_rmse_at_pixel_normals = Some(rel_rmse(&at_normals, &self.exact));
    }

    /// A few lines for a terminal.
    pub fn summary(&self) -> String {
        let bins: Vec<String> = (0..BINS)
            .map(|b| {
                let range = if b + 1 < BINS {
                    format!("{}-{}", b * BIN, b * BIN + BIN - 1)
                } else {
                    format!("{}+", b * BIN)
                };
                format!("{range}: {}", self.histogram[b])
            })
            .collect();
        format!(
            "flat basis: {} of {} points (per level {:?} of {:?})\n{}x{}: {} surface pixels, covered by {:.2} flat \
             functions on average (at most {}), {} uncovered\nhistogram: {}\nflat vs exact \
             indirect: relative RMSE {:.4}; {} pixels below a quarter of the exact\n",
            self.flat_points,
            self.hierarchical_points,
            self.flat_per_level,
            self.points_per_level,
            self.width,
            self.height,
            self.surface_pixels,
            self.coverage_mean,
            self.coverage_max,
            self.uncovered,
            bins.join(", "),
            self.rel_rmse,
            self.darker.len()
        ) + &self
            .rel_rmse_at_pixel_normals
            .map(|r| {
                format!(
                    "with each flat point's value taken at the pixel's normal (not sharpened): \
                     relative RMSE {r:.4}\n"
                )
            })
            .unwrap_or_default()
    }
}
