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
    /// The exact indirect image's largest luminance (the scale of [`FlatCheck::darker`]'s
    /// floor and of [`FlaggedPixel`]'s values).
    pub exact_max: f32,
    /// The surface point of each pixel, the flat functions covering it, and the exact and
    /// flat indirect images.
    #[serde(skip)]
    pub points: Vec<Option<SurfacePoint>>,
    #[serde(skip)]
    pub coverage: Vec<Option<usize>>,
    #[serde(skip)]
    pub exact: RgbImage,
    #[serde(skip)]
    pub flat: RgbImage,
}

/// One pixel the check flags, with what is there.
#[derive(Clone, Debug, Serialize)]
pub struct FlaggedPixel {
    pub x: u32,
    pub y: u32,
    /// `"uncovered"` or `"darker"`.
    pub kind: &'static str,
    pub position: [f32; 3],
    pub normal: [f32; 3],
    pub coverage: usize,
    /// Luminance of the flat and the exact indirect irradiance there.
    pub flat: f32,
    pub exact: f32,
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
        let coverage = flat_coverage(fb, &points);
        let counts: Vec<usize> = coverage.iter().flatten().copied().collect();
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
            exact_max: max_lum,
            points,
            coverage,
            exact,
            flat: flat_image,
        }
    }

    /// The uncovered pixels, then the darker ones, at most `n` in all, row by row.
    pub fn flagged(&self, n: usize) -> Vec<FlaggedPixel> {
        let w = self.width as usize;
        let uncovered = (0..self.points.len()).filter(|&k| self.coverage[k] == Some(0));
        let mark = |k: usize, kind| {
            let p = self.points[k]?;
            Some(FlaggedPixel {
                x: (k % w) as u32,
                y: (k / w) as u32,
                kind,
                position: p.position,
                normal: p.normal,
                coverage: self.coverage[k].unwrap_or(0),
                flat: luminance(self.flat.pixels[k]),
                exact: luminance(self.exact.pixels[k]),
            })
        };
        uncovered
            .filter_map(|k| mark(k, "uncovered"))
            .chain(self.darker.iter().filter_map(|&k| mark(k, "darker")))
            .take(n)
            .collect()
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A 3x2 check: pixel 1 sees nothing, pixel 2 is uncovered, pixels 3 and 5 are darker
    /// than a quarter of the exact image.
    fn check() -> FlatCheck {
        let point = |x: f32| {
            Some(SurfacePoint {
                position: [x, 0.0, 0.0],
                normal: [0.0, 0.0, 1.0],
                albedo: [0.5; 3],
            })
        };
        let image = |v: [f32; 6]| RgbImage {
            width: 3,
            height: 2,
            pixels: v.iter().map(|&v| [v; 3]).collect(),
        };
        FlatCheck {
            flat_points: 4,
            hierarchical_points: 6,
            points_per_level: vec![6],
            flat_per_level: vec![4],
            width: 3,
            height: 2,
            surface_pixels: 5,
            coverage_mean: 3.2,
            histogram: [2, 3, 0, 0, 0, 0, 0, 0],
            coverage_max: 6,
            uncovered: 1,
            rel_rmse: 0.5,
            rel_rmse_at_pixel_normals: None,
            darker: vec![2, 3, 5],
            exact_max: 2.0,
            points: vec![
                point(0.0),
                None,
                point(2.0),
                point(3.0),
                point(4.0),
                point(5.0),
            ],
            coverage: vec![Some(4), None, Some(0), Some(6), Some(4), Some(2)],
            exact: image([1.0, 0.0, 1.0, 1.0, 1.0, 2.0]),
            flat: image([1.0, 0.0, 0.0, 0.2, 0.9, 0.1]),
        }
    }

    #[test]
    fn flagged_pixels_are_the_uncovered_then_the_darker_ones_with_what_is_there() {
        let c = check();
        let all = c.flagged(usize::MAX);
        let got: Vec<_> = all.iter().map(|p| (p.kind, p.x, p.y, p.coverage)).collect();
        assert_eq!(
            got,
            [
                ("uncovered", 2, 0, 0),
                ("darker", 2, 0, 0),
                ("darker", 0, 1, 6),
                ("darker", 2, 1, 2)
            ]
        );
        let last = &all[3];
        assert_eq!(last.position, [5.0, 0.0, 0.0]);
        assert!((last.flat - 0.1).abs() < 1e-6 && (last.exact - 2.0).abs() < 1e-6);
        assert_eq!(c.flagged(2).len(), 2);
        assert!(c.flagged(0).is_empty());
    }
}
