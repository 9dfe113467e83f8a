//! The basis floor: what the meshless basis can show at best, whatever the transport.
//!
//! The indirect vector irradiance (bounces >= 1) is path-traced at every point of every level
//! ([`crate::reference::reference_vector_irradiance`], independent of the links), projected
//! onto the hierarchical basis with Eq. 7 ([`mlt_format::pull_push::project`]: `alpha_j = f_j`
//! on level 0, `alpha_j = f_j - F_{l-1}(p_j)` on level `l`), and handed to the renderer as
//! the receiver coefficients `i` of a frame: flattened with the viewer's sparse operator over
//! all points and splatted like a bake's. Its error against the path-traced image is the
//! basis' share of the error (reconstruction from point samples, the flat basis' blending,
//! plus the noise of the samples); the gap between it and the bake's image is the
//! transport's (links of T dropped at epsilon, bounces 2+ on coarse receivers only, gather
//! hits without sender support, the series truncated after the last bounce).
//!
//! [`OracleRelighter::with_levels`] takes the oracle's coefficients on some levels only and
//! the bake's on the others ([`mix_levels`]): the error of such a mix against the reference,
//! against the bake's own, says how much of the transport's share lies on those levels.

use std::ops::Range;
use std::time::Instant;

use mlt_format::flat_basis::FlatBasis;
use mlt_format::links::LINK_DIM;
use mlt_format::pull_push::{project, ProjectionReport};
use mlt_format::IndexedBasis;
use mlt_relight::flatten_op::{FlattenOp, FlattenScratch, SharpenOp, SharpenScratch};
use mlt_relight::{Frame, Light, Relight};
use mlt_scenes::RayCaster;

use crate::probe::Probe;
use crate::reference::{reference_vector_irradiance, ReferenceError, ReferenceOptions};

/// The projected oracle solution.
#[derive(Clone, Debug)]
pub struct Oracle {
    /// Hierarchical coefficients (Eq. 7), `LINK_DIM` per point.
    pub alpha: Vec<f32>,
    /// Points where Eq. 7 found no coarser support.
    pub projection: ProjectionReport,
    /// Mean over points of the standard error of the sampled irradiance along the normal
    /// (luminance), over the mean of that irradiance: the samples' relative noise.
    pub relative_noise: f64,
    /// Paths per point.
    pub spp: u32,
    /// Seconds spent path tracing and projecting.
    pub seconds: f64,
}

/// Path-traces the indirect vector irradiance at every basis point for `light` and projects
/// it with Eq. 7.
pub fn oracle(
    ib: &IndexedBasis,
    caster: &dyn RayCaster,
    light: &Light,
    opts: &ReferenceOptions,
) -> Result<Oracle, ReferenceError> {
    let start = Instant::now();
    let b = &ib.basis;
    let points: Vec<Probe> = (0..b.len())
        .map(|j| Probe {
            position: b.positions[j].into(),
            normal: b.normals[j].into(),
        })
        .collect();
    let (samples, se) = reference_vector_irradiance(caster, light, &points, opts)?;
    let mean_lum: f64 = points
        .iter()
        .enumerate()
        .map(|(j, p)| {
            let s = &samples[j * LINK_DIM..(j + 1) * LINK_DIM];
            let e: [f32; 3] = std::array::from_fn(|c| {
                p.normal
                    .dot(glam::Vec3::new(s[c * 3], s[c * 3 + 1], s[c * 3 + 2]))
            });
            crate::images::luminance(e) as f64
        })
        .sum::<f64>()
        / points.len().max(1) as f64;
    let mean_se = se.iter().map(|&v| v as f64).sum::<f64>() / se.len().max(1) as f64;
    let (alpha, projection) = project(ib, &samples, LINK_DIM);
    Ok(Oracle {
        alpha,
        projection,
        relative_noise: if mean_lum > 0.0 {
            mean_se / mean_lum
        } else {
            0.0
        },
        spp: opts.spp,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// Puts the oracle's coefficients `oracle` into `i` (the bake's, `LINK_DIM` floats per point,
/// both) on the points of `levels`; `level_offsets` are the basis' (`Basis::level_offsets`).
/// A level's points are contiguous, so this is one copy; levels past the last are ignored. Eq.
/// 7's coefficients of a level are differences from the coarser levels' expansion, so the mix
/// is the bake's expansion with the oracle's detail on those levels.
pub fn mix_levels(level_offsets: &[u32], oracle: &[f32], levels: Range<usize>, i: &mut [f32]) {
    let last = level_offsets.len().saturating_sub(1);
    let (a, b) = (levels.start.min(last), levels.end.min(last));
    if a < b {
        let span = level_offsets[a] as usize * LINK_DIM..level_offsets[b] as usize * LINK_DIM;
        i[span.clone()].copy_from_slice(&oracle[span]);
    }
}

/// A [`Relight`] whose frames are another relighter's (direct light, `e`) with the receiver
/// coefficients replaced by the oracle's (on every level, or on the levels of
/// [`OracleRelighter::with_levels`]) and flattened on the CPU by the viewer's sparse
/// operator over every point (the bake's relighter keeps only points with links), then
/// sharpened as the inner relighter sharpens (the same number of steps, or not at all).
pub struct OracleRelighter<'a> {
    inner: &'a mut dyn Relight,
    level_offsets: Vec<u32>,
    alpha: Vec<f32>,
    /// The levels whose coefficients are the oracle's (all unless [`Self::with_levels`]).
    levels: Range<usize>,
    flat: FlatBasis,
    op: FlattenOp,
    scratch: FlattenScratch,
    /// The inner relighter's sharpening on this flat basis; `None` when it does not sharpen.
    sharpen: Option<SharpenOp>,
    sharpen_scratch: SharpenScratch,
    frame: Frame,
}

impl<'a> OracleRelighter<'a> {
    /// Builds the flat basis and the flattening operator over every point of `ib` (the oracle
    /// has detail at every level, so no point can be left out).
    pub fn new(
        ib: &IndexedBasis,
        inner: &'a mut dyn Relight,
        alpha: Vec<f32>,
    ) -> Result<OracleRelighter<'a>, mlt_relight::RelightError> {
        let flat = FlatBasis::build(ib, None)?;
        let op = FlattenOp::build(ib, &flat, None)?;
        let sharpen = match inner.sharpen_operator().map(SharpenOp::steps) {
            Some(steps) => {
                let mut op = SharpenOp::build(&flat)?;
                op.set_steps(steps)?;
                Some(op)
            }
            None => None,
        };
        Ok(OracleRelighter {
            inner,
            level_offsets: ib.basis.level_offsets.clone(),
            alpha,
            levels: 0..ib.basis.levels(),
            flat,
            op,
            scratch: FlattenScratch::default(),
            sharpen,
            sharpen_scratch: SharpenScratch::default(),
            frame: Frame::default(),
        })
    }
}

impl OracleRelighter<'_> {
    /// The oracle's coefficients on the points of `levels` only, the inner relighter's (the
    /// bake's) on the others ([`mix_levels`]).
    pub fn with_levels(mut self, levels: Range<usize>) -> Self {
        self.levels = levels;
        self
    }
}

impl Relight for OracleRelighter<'_> {
    fn flat_basis(&self) -> &FlatBasis {
        &self.flat
    }

    fn relight(&mut self, light: &Light) -> &Frame {
        let mut frame = self.inner.relight(light).clone();
        frame.i.resize(self.alpha.len(), 0.0);
        mix_levels(
            &self.level_offsets,
            &self.alpha,
            self.levels.clone(),
            &mut frame.i,
        );
        frame.reused = false;
        frame.flat.resize(self.op.points() * LINK_DIM, 0.0);
        self.op
            .apply(&frame.i, LINK_DIM, &mut frame.flat, &mut self.scratch);
        if let Some(sharpen) = &self.sharpen {
            sharpen.apply(&mut frame.flat, LINK_DIM, &mut self.sharpen_scratch);
        }
        self.frame = frame;
        &self.frame
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mlt_format::test_support::plane_basis;

    /// An inner relighter with no light of its own that sharpens with `steps` steps (or not).
    struct Inner {
        flat: FlatBasis,
        sharpen: Option<SharpenOp>,
        frame: Frame,
    }

    impl Relight for Inner {
        fn relight(&mut self, _: &Light) -> &Frame {
            &self.frame
        }
        fn flat_basis(&self) -> &FlatBasis {
            &self.flat
        }
        fn sharpen_operator(&self) -> Option<&SharpenOp> {
            self.sharpen.as_ref()
        }
    }

    #[test]
    fn the_oracle_sharpens_as_the_inner_relighter_does() {
        let ib = plane_basis(3, 3);
        let flat = FlatBasis::build(&ib, None).unwrap();
        // Coefficients that vary over the plane, so that sharpening changes them.
        let alpha: Vec<f32> = (0..ib.basis.len() * LINK_DIM)
            .map(|k| {
                let p = ib.basis.positions[k / LINK_DIM];
                1.0 + p[0] * p[0] + 3.0 * p[1] + (k % LINK_DIM) as f32
            })
            .collect();
        // The oracle flattens with the viewer's operator over every point.
        let op = FlattenOp::build(&ib, &flat, None).unwrap();
        let mut plain = vec![0.0f32; op.points() * LINK_DIM];
        op.apply(&alpha, LINK_DIM, &mut plain, &mut FlattenScratch::default());
        let scale = plain.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let light = Light::point(glam::Vec3::Y, [1.0; 3]).unwrap();
        let mut images = Vec::new();
        for steps in [None, Some(1), Some(3)] {
            let sharpen = steps.map(|k| {
                let mut op = SharpenOp::build(&flat).unwrap();
                op.set_steps(k).unwrap();
                op
            });
            let mut want = plain.clone();
            if let Some(op) = &sharpen {
                op.apply(&mut want, LINK_DIM, &mut SharpenScratch::default());
            }
            let mut inner = Inner {
                flat: flat.clone(),
                sharpen,
                frame: Frame::default(),
            };
            let mut oracle = OracleRelighter::new(&ib, &mut inner, alpha.clone()).unwrap();
            let got = oracle.relight(&light).flat.clone();
            assert_eq!(got, want, "{steps:?}");
            images.push(got);
        }
        // Each choice gives a different image: the steps are followed, not a fixed number.
        let differ =
            |a: &[f32], b: &[f32]| a.iter().zip(b).any(|(x, y)| (x - y).abs() > 1e-3 * scale);
        assert!(differ(&images[0], &images[1]) && differ(&images[1], &images[2]));
    }

    /// Three levels of 2, 3 and 4 points.
    const LEVEL_OFFSETS: [u32; 4] = [0, 2, 5, 9];

    fn values(n: usize, v: f32) -> Vec<f32> {
        (0..n * LINK_DIM).map(|k| v + k as f32).collect()
    }

    #[test]
    fn mix_takes_the_oracle_on_the_named_levels_only() {
        let (bake, oracle) = (values(9, 0.0), values(9, 1000.0));
        let mix = |levels: Range<usize>| {
            let mut out = bake.clone();
            mix_levels(&LEVEL_OFFSETS, &oracle, levels, &mut out);
            out
        };
        let out = mix(1..2);
        for j in 0..9 {
            let from = if (2..5).contains(&j) { &oracle } else { &bake };
            let span = j * LINK_DIM..(j + 1) * LINK_DIM;
            assert_eq!(out[span.clone()], from[span], "point {j}");
        }
        let out = mix(0..0);
        assert_eq!(out, bake);
        // A range past the last level is clipped to the levels there are.
        let out = mix(0..7);
        assert_eq!(out, oracle);
        let out = mix(2..3);
        assert_eq!(out[..5 * LINK_DIM], bake[..5 * LINK_DIM]);
        assert_eq!(out[5 * LINK_DIM..], oracle[5 * LINK_DIM..]);
    }
}
