//! The flat basis of section 4.1: "a single-level meshless basis constructed from the same
//! points" as the hierarchical one, into which a hierarchical expansion is resampled so that a
//! renderer accumulates one layer of functions instead of every level.
//!
//! Which points: only those the solution needs. A hierarchical coefficient can be non-zero
//! only at a receiver with links (section 3.3); where no point of level `l` or finer with links
//! has support, the expansion there is a sum of coarser levels only and the points of level
//! `l` add nothing the coarser ones do not represent. So point `j` of level `l` is kept when
//! some point of level `l` or finer that has links has a positive weight (Eq. 8) at `p_j`;
//! every point of level 0 is kept. Of those, a point of a coarser level is then left out where
//! the kept points of the finer levels already cover it ([`FINER_COVER`]): the finer points
//! represent everything the coarser one would add there, and a flat set of one density
//! interpolates better than the union of every level's points (a coarse point a few
//! millimetres from a fine one makes uneven weights) at fewer functions per pixel.
//!
//! Radii: each flat point's support radius comes from the density of the flat point set
//! around it, [`FLAT_RADIUS_FACTOR`] times the distance (Eq. 11's metric) to its
//! [`FLAT_NEIGHBOURS`]-th nearest flat neighbour, so that a surface point is covered by a
//! bounded number of functions wherever the set is fine or coarse, without level weights.
//! Where that leaves a hierarchical point of the surface without a flat function of
//! appreciable weight (at the rim of a sparse region, on a narrow face), the nearest flat
//! point's radius grows to cover it ([`HOLE_WEIGHT`]); so it does for probes around each
//! point of the finest level ([`HOLE_PROBE`]), which cover the strip between a surface's last
//! points and its rim.
//!
//! Weights: a flat function's weight is Eq. 8's times a sharper normal factor,
//! `w_i(x, n) = K(dist_i(x) / r_i) (n . n_i)^2 ((n . n_i)^(p - 2) + FLOOR)` with `p =`
//! [`FLAT_NORMAL_POWER`] ([`flat_normal_factor`]), on the same support. Eq. 6 depends on the
//! surface normal through its weights' `(n . n_k)^2`, which choose which functions of each
//! level a surface point averages, and one value per flat point, `F(p_i, n_i)`, holds that
//! choice for `n_i` only. Where the surface curves (columns, arches, smooth-shaded mouldings) a
//! pixel should then take its value mostly from the flat points that face the way it faces:
//! with `p = 2` the flat image of Sponza is 4.8 % from the exact evaluation, with `p = 12`
//! 2.7 %. [`FLAT_NORMAL_FLOOR`] keeps a pixel whose normal is far from every covering point's
//! (a narrow face with smooth-shading normals) weighted as Eq. 8 would, 1e-3 times as much, so
//! no support is lost. The support, and so the coverage and the hole test, are Eq. 8's.
//!
//! The flat points are stored as a one-level [`Basis`] (Morton order) with an R-tree, and the
//! index of the hierarchical point each one is.

use crate::basis::Basis;
use crate::error::FormatError;
use crate::kernel::poisson_distance;
use crate::morton::morton_order;
use crate::rtree::RTree;
use crate::shepard::{IndexedBasis, Support, MAX_DIM, MIN_WEIGHT_SUM};

/// The neighbour whose distance sets a flat point's radius (the k of a k-nearest search).
pub const FLAT_NEIGHBOURS: usize = 4;

/// Flat radius over the distance to the [`FLAT_NEIGHBOURS`]-th nearest flat point. Wider
/// functions smooth more but, once sharpened, interpolate better between the points; on
/// Sponza's default view at 640x360, with three sharpening steps, 1.35 / 1.45 / 1.5 / 1.55
/// give the flat image 2.07 / 1.98 / 1.95 / 1.92 % from the exact evaluation of Eq. 6 at a
/// mean coverage of 9.7 / 10.8 / 11.3 / 11.9 functions per pixel.
pub const FLAT_RADIUS_FACTOR: f32 = 1.5;

/// A hierarchical point where the flat weights sum to less than this is a hole: the nearest
/// flat point's radius grows until the point lies at [`HOLE_REACH`] of it.
pub const HOLE_WEIGHT: f32 = 0.05;

/// The fraction of the grown radius at which a hole's point then lies (weight `K(0.7)`, about
/// 0.2, times the normals' squared cosine).
pub const HOLE_REACH: f32 = 0.7;

/// Holes are also looked for around each point of the finest level, at this fraction of its
/// hierarchical radius along two tangent directions, both ways: the hierarchical points stop
/// short of a surface's rim (where a box meets the floor), and the hierarchical functions
/// still cover the strip between the last points and the rim.
pub const HOLE_PROBE: f32 = 0.5;

/// A needed point of a coarser level is left out where the kept points of the finer levels
/// have weights (Eq. 8, their hierarchical radii) summing to at least this at it: about three
/// finer functions reach it with weight 1, so the finer set is dense all around it. Lower
/// values leave out more, and at 1 to 2 a narrow step in a wall next to finer points (seen on
/// Sponza) is left uncovered where the finer points' flat radii, smaller than their
/// hierarchical ones, stop short of it.
pub const FINER_COVER: f32 = 3.0;

/// The exponent `p` of a flat function's normal factor `(n . n_i)^p` (Eq. 8 has 2): see the
/// module documentation. Measured flat against exact, one sharpening step, p = 2 / 8 / 12 /
/// 16: Sponza 4.8 / 2.9 / 2.7 / 2.7 %, Sibenik 3.6 / 1.3 / 1.2 / 1.1 %; 32 is worse again
/// (3.0 % on Sponza: too few neighbours share a pixel's normal).
pub const FLAT_NORMAL_POWER: f32 = 12.0;

/// The part of Eq. 8's normal factor a flat weight keeps whatever the normals: see
/// [`flat_normal_factor`].
pub const FLAT_NORMAL_FLOOR: f32 = 1e-3;

/// A flat function's weight over Eq. 8's, for `cos = n . n_i` and the exponent `power`:
/// `cos^(power - 2) + FLAT_NORMAL_FLOOR` (never below the floor; `power = 2` gives a
/// constant, which the Shepard normalisation cancels, so Eq. 8 itself).
#[inline(always)]
pub fn flat_normal_factor(cos: f32, power: f32) -> f32 {
    cos.max(0.0).powf(power - 2.0) + FLAT_NORMAL_FLOOR
}

/// The most neighbours [`FlatRule::neighbours`] may name.
pub const MAX_NEIGHBOURS: usize = 16;

/// The parameters of the rule that builds a flat basis ([`FlatBasis::build_with`]); stored in
/// a file's `FLT2` section with the basis it built.
#[derive(Clone, Copy, Debug, PartialEq, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct FlatRule {
    /// The neighbour whose distance sets a flat point's radius (1 to [`MAX_NEIGHBOURS`]).
    pub neighbours: u32,
    /// Flat radius over the distance to that neighbour.
    pub radius_factor: f32,
    /// A hierarchical point where the flat weights sum to less than this is a hole.
    pub hole_weight: f32,
    /// The fraction of the grown radius at which a hole's point then lies.
    pub hole_reach: f32,
    /// A needed point of a coarser level is left out where the kept finer points' weights sum
    /// to at least this at it ([`FINER_COVER`]); 0 keeps every needed point (the rule of
    /// format 1.5).
    pub finer_cover: f32,
}

impl FlatRule {
    /// The rule of this build ([`FLAT_NEIGHBOURS`], [`FLAT_RADIUS_FACTOR`], [`HOLE_WEIGHT`],
    /// [`HOLE_REACH`], [`FINER_COVER`]).
    pub fn current() -> FlatRule {
        FlatRule {
            neighbours: FLAT_NEIGHBOURS as u32,
            radius_factor: FLAT_RADIUS_FACTOR,
            hole_weight: HOLE_WEIGHT,
            hole_reach: HOLE_REACH,
            finer_cover: FINER_COVER,
        }
    }
}

/// A single-level basis on a subset of the hierarchical points.
#[derive(Clone, Debug, PartialEq)]
pub struct FlatBasis {
    /// The flat points (one level) with their flat radii, and its R-tree.
    pub ib: IndexedBasis,
    /// For each flat point, the index of the hierarchical point it is.
    pub source: Vec<u32>,
    /// The exponent of the flat weights' normal factor ([`FLAT_NORMAL_POWER`] unless set by
    /// [`FlatBasis::with_normal_power`]; at least 2).
    pub normal_power: f32,
}

impl FlatBasis {
    /// Builds the flat basis of `hier`. `linked[k]` says whether hierarchical point `k` has
    /// links (may hold a non-zero coefficient); `None` keeps every point. Points are
    /// independent, so the work is parallel (rayon) with the same result for any thread
    /// count.
    pub fn build(hier: &IndexedBasis, linked: Option<&[bool]>) -> Result<FlatBasis, FormatError> {
        Self::build_with(hier, linked, FlatRule::current())
    }

    /// [`FlatBasis::build`] by another rule than this build's.
    pub fn build_with(
        hier: &IndexedBasis,
        linked: Option<&[bool]>,
        rule: FlatRule,
    ) -> Result<FlatBasis, FormatError> {
        let b = &hier.basis;
        let valid = (1..=MAX_NEIGHBOURS as u32).contains(&rule.neighbours)
            && rule.radius_factor > 0.0
            && rule.hole_weight.is_finite()
            && rule.hole_reach > 0.0
            && rule.hole_reach <= 1.0
            && rule.finer_cover.is_finite()
            && rule.finer_cover >= 0.0;
        if !valid {
            return Err(FormatError::InvalidBasis(format!("flat rule {rule:?}")));
        }
        if let Some(m) = linked {
            if m.len() != b.len() {
                return Err(FormatError::InvalidBasis(format!(
                    "{} link flags for {} points",
                    m.len(),
                    b.len()
                )));
            }
        }
        let kept = needed_points(hier, linked, rule.finer_cover);
        let mut source: Vec<u32> = Vec::with_capacity(kept.len());
        let positions: Vec<[f32; 3]> = kept.iter().map(|&j| b.positions[j as usize]).collect();
        for i in morton_order(&positions) {
            source.push(kept[i as usize]);
        }
        let mut radii = density_radii(hier, &source, &rule);
        fill_holes(hier, &source, &mut radii, &rule);
        Self::from_parts(hier, source, radii)
    }

    /// The flat basis on the points `source` of `hier` with the flat radii `radii`.
    pub fn from_parts(
        hier: &IndexedBasis,
        source: Vec<u32>,
        radii: Vec<f32>,
    ) -> Result<FlatBasis, FormatError> {
        let flat = Self::flat_level(hier, &source, radii)?;
        let tree = RTree::build(&flat, 0..source.len());
        Ok(FlatBasis {
            ib: IndexedBasis {
                basis: flat,
                trees: vec![tree],
                clip: source_clip(hier, &source),
            },
            source,
            normal_power: FLAT_NORMAL_POWER,
        })
    }

    /// [`FlatBasis::from_parts`] with the flat level's R-tree given (as a file stores it);
    /// the tree is validated against the flat points.
    pub fn from_parts_with_tree(
        hier: &IndexedBasis,
        source: Vec<u32>,
        radii: Vec<f32>,
        tree: RTree,
    ) -> Result<FlatBasis, FormatError> {
        let flat = Self::flat_level(hier, &source, radii)?;
        Ok(FlatBasis {
            ib: IndexedBasis::from_parts(flat, vec![tree])?
                .with_clip(source_clip(hier, &source))?,
            source,
            normal_power: FLAT_NORMAL_POWER,
        })
    }

    /// The one-level [`Basis`] of the points `source` of `hier` with the radii `radii`.
    fn flat_level(
        hier: &IndexedBasis,
        source: &[u32],
        radii: Vec<f32>,
    ) -> Result<Basis, FormatError> {
        let b = &hier.basis;
        if radii.len() != source.len() || source.iter().any(|&j| j as usize >= b.len()) {
            return Err(FormatError::InvalidBasis(
                "flat points out of range or radii of another length".into(),
            ));
        }
        let m = source.len();
        let disk = b.disk_radii.last().copied().unwrap_or(1.0);
        let flat = Basis {
            positions: source.iter().map(|&j| b.positions[j as usize]).collect(),
            normals: source.iter().map(|&j| b.normals[j as usize]).collect(),
            radii,
            level_offsets: vec![0, m as u32],
            disk_radii: vec![disk],
        };
        flat.validate()?;
        Ok(flat)
    }

    /// The same basis with the flat weights' normal factor raised to `power` (2: Eq. 8's
    /// weights; for measuring what the sharper factor changes). Powers below 2 and non-finite
    /// ones are an error.
    pub fn with_normal_power(mut self, power: f32) -> Result<FlatBasis, FormatError> {
        if !(power.is_finite() && power >= 2.0) {
            return Err(FormatError::InvalidBasis(format!(
                "flat normal power {power} (must be at least 2)"
            )));
        }
        self.normal_power = power;
        Ok(self)
    }

    /// Calls `f(i, w_i(x, n))` for every flat function with a positive weight at the surface
    /// point `(x, n)` (Eq. 8 times [`flat_normal_factor`]); returns the sum of those weights.
    #[inline]
    pub fn for_each_weight(&self, x: [f32; 3], n: [f32; 3], mut f: impl FnMut(usize, f32)) -> f32 {
        let normals = &self.ib.basis.normals;
        let power = self.normal_power;
        let mut sum = 0.0f32;
        self.ib.for_each_clipped_weight(0, x, n, |i, w| {
            let m = normals[i];
            let w = w * flat_normal_factor(n[0] * m[0] + n[1] * m[1] + n[2] * m[2], power);
            sum += w;
            f(i, w);
        });
        sum
    }

    /// The level in `hier` (the hierarchical basis it was built on) of the point each flat
    /// point is.
    pub fn source_levels(&self, hier: &Basis) -> Vec<u32> {
        self.source
            .iter()
            .map(|&j| hier.level_of(j as usize) as u32)
            .collect()
    }

    /// Number of flat points.
    pub fn len(&self) -> usize {
        self.source.len()
    }

    pub fn is_empty(&self) -> bool {
        self.source.is_empty()
    }

    /// Flat coefficients `c_i = F_L(p_i)` (Eq. 6 at each flat point) of the hierarchical
    /// coefficients `alpha` (`dim` floats per hierarchical point), `dim` floats per flat point.
    pub fn flatten(&self, hier: &IndexedBasis, alpha: &[f32], dim: usize) -> Vec<f32> {
        use rayon::prelude::*;
        let b = &hier.basis;
        let d = dim.max(1);
        let mut flat = vec![0.0f32; self.len() * dim];
        flat.par_chunks_mut(d * 256)
            .enumerate()
            .for_each(|(chunk, out)| {
                for (k, o) in out.chunks_mut(d).enumerate() {
                    let j = self.source[chunk * 256 + k] as usize;
                    hier.reconstruct(
                        alpha,
                        dim,
                        0..hier.levels(),
                        b.positions[j],
                        b.normals[j],
                        o,
                    );
                }
            });
        flat
    }

    /// Evaluates the flat expansion `sum_i c_i B^flat_i(x, n)` (Eq. 2 on the one flat level)
    /// into `out[..dim]`, as the renderer's splatting does per pixel; 0 without support.
    pub fn reconstruct(
        &self,
        flat: &[f32],
        dim: usize,
        x: [f32; 3],
        n: [f32; 3],
        out: &mut [f32],
    ) -> Support {
        assert!(dim <= MAX_DIM && out.len() >= dim && flat.len() >= self.len() * dim);
        let mut acc = [0.0f32; MAX_DIM];
        let sum = self.for_each_weight(x, n, |i, w| {
            for k in 0..dim {
                acc[k] += w * flat[i * dim + k];
            }
        });
        if sum > MIN_WEIGHT_SUM {
            for k in 0..dim {
                out[k] = acc[k] / sum;
            }
            Support {
                supported: 1,
                unsupported: 0,
            }
        } else {
            out[..dim].fill(0.0);
            Support {
                supported: 0,
                unsupported: 1,
            }
        }
    }

    /// Number of flat functions with a positive weight at `(x, n)`.
    pub fn coverage(&self, x: [f32; 3], n: [f32; 3]) -> usize {
        let mut count = 0;
        self.ib.for_each_clipped_weight(0, x, n, |_, _| count += 1);
        count
    }
}

/// The hierarchical points the flat basis keeps (ascending): all of level 0, and a point of
/// level `l` where a point of level `l` or finer with links has support; then, with
/// `finer_cover > 0`, a point of a coarser level is left out where the kept points of the
/// finer levels have weights summing to at least `finer_cover` at it. Without link flags every
/// point is kept (the basis-floor oracle has detail at every level).
fn needed_points(hier: &IndexedBasis, linked: Option<&[bool]>, finer_cover: f32) -> Vec<u32> {
    let needed = linked_support(hier, linked);
    if finer_cover <= 0.0 || linked.is_none() {
        return needed;
    }
    covered_by_finer(hier, needed, finer_cover)
}

/// [`needed_points`]'s first step: the points of level 0 and those where a point of the same
/// or a finer level with links has support.
fn linked_support(hier: &IndexedBasis, linked: Option<&[bool]>) -> Vec<u32> {
    use rayon::prelude::*;
    let b = &hier.basis;
    let Some(linked) = linked else {
        return (0..b.len() as u32).collect();
    };
    let levels = hier.levels();
    (0..b.len())
        .into_par_iter()
        .filter(|&j| {
            let l = b.level_of(j);
            if l == 0 {
                return true;
            }
            let (x, n) = (b.positions[j], b.normals[j]);
            (l..levels).any(|m| {
                let mut found = false;
                hier.for_each_weight(m, x, n, |k, _| found |= linked[k]);
                found
            })
        })
        .map(|j| j as u32)
        .collect()
}

/// [`needed_points`]'s second step: the points of `needed` (ascending) less those of a level
/// above the finest where the other points of `needed` of the finer levels have weights
/// summing to at least `finer_cover`. Each point is judged against the same set, so the result
/// does not depend on the order or the thread count.
fn covered_by_finer(hier: &IndexedBasis, needed: Vec<u32>, finer_cover: f32) -> Vec<u32> {
    use rayon::prelude::*;
    let b = &hier.basis;
    let levels = hier.levels();
    let mut is_needed = vec![false; b.len()];
    for &j in &needed {
        is_needed[j as usize] = true;
    }
    needed
        .into_par_iter()
        .filter(|&j| {
            let j = j as usize;
            let (x, n) = (b.positions[j], b.normals[j]);
            let mut sum = 0.0f32;
            for m in b.level_of(j) + 1..levels {
                hier.for_each_weight(m, x, n, |k, w| {
                    if is_needed[k] {
                        sum += w;
                    }
                });
            }
            sum < finer_cover
        })
        .collect()
}

/// Flat radius of each point of `source`: [`FLAT_RADIUS_FACTOR`] times the Eq. 11 distance to
/// its [`FLAT_NEIGHBOURS`]-th nearest flat point. Neighbours are searched within each flat
/// point's hierarchical support sphere; a point with fewer neighbours there keeps its
/// hierarchical radius.
fn density_radii(hier: &IndexedBasis, source: &[u32], rule: &FlatRule) -> Vec<f32> {
    use rayon::prelude::*;
    let b = &hier.basis;
    let m = source.len();
    let hier_radii = source.iter().map(|&j| b.radii[j as usize]).collect();
    let (search, tree) = search_basis(hier, source, hier_radii);
    let k = rule.neighbours as usize;
    (0..m)
        .into_par_iter()
        .map(|i| {
            let (x, n) = (search.positions[i], search.normals[i]);
            let mut buffer = [f32::INFINITY; MAX_NEIGHBOURS];
            let nearest = &mut buffer[..k];
            tree.for_each_candidate(x, |q| {
                let q = q as usize;
                if q == i {
                    return;
                }
                let d = poisson_distance(x, n, search.positions[q], search.normals[q]);
                if d < nearest[k - 1] && d <= search.radii[q] {
                    let mut at = k - 1;
                    while at > 0 && nearest[at - 1] > d {
                        nearest[at] = nearest[at - 1];
                        at -= 1;
                    }
                    nearest[at] = d;
                }
            });
            let own = search.radii[i];
            let kth = nearest[k - 1];
            if kth.is_finite() && kth > 0.0 {
                (rule.radius_factor * kth).min(own)
            } else {
                own
            }
        })
        .collect()
}

/// The clip planes of the flat points of `source`: their hierarchical points' (a flat radius
/// never exceeds its point's hierarchical one, so the planes cover the flat support).
fn source_clip(hier: &IndexedBasis, source: &[u32]) -> crate::support_clip::SupportClip {
    if hier.clip.is_empty() {
        return Default::default();
    }
    crate::support_clip::SupportClip::from_rows(
        source.iter().map(|&j| hier.clip.planes_of(j as usize)),
    )
}

/// The flat points of `source` with `radii`, and their R-tree: with the hierarchical radii,
/// the candidate search of [`density_radii`] and [`fill_holes`].
fn search_basis(hier: &IndexedBasis, source: &[u32], radii: Vec<f32>) -> (Basis, RTree) {
    let b = &hier.basis;
    let m = source.len();
    let search = Basis {
        positions: source.iter().map(|&j| b.positions[j as usize]).collect(),
        normals: source.iter().map(|&j| b.normals[j as usize]).collect(),
        radii,
        level_offsets: vec![0, m as u32],
        disk_radii: vec![1.0],
    };
    let tree = RTree::build(&search, 0..m);
    (search, tree)
}

/// Two unit vectors spanning the plane normal to `n`.
fn tangents(n: [f32; 3]) -> [[f32; 3]; 2] {
    let a = if n[0].abs() < 0.6 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let cross = |u: [f32; 3], v: [f32; 3]| {
        [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ]
    };
    let t = cross(n, a);
    let len = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2])
        .sqrt()
        .max(f32::MIN_POSITIVE);
    let t = [t[0] / len, t[1] / len, t[2] / len];
    [t, cross(n, t)]
}

/// Where holes are looked for around hierarchical point `j`: the point itself and, on the
/// finest level, four probes in its tangent plane at [`HOLE_PROBE`] of its radius.
fn hole_probes(b: &Basis, j: usize) -> ([[f32; 3]; 5], usize) {
    let x = b.positions[j];
    let mut probes = [x; 5];
    if b.level_of(j) + 1 < b.levels() {
        return (probes, 1);
    }
    let step = HOLE_PROBE * b.radii[j];
    for (k, t) in tangents(b.normals[j]).iter().enumerate() {
        for (m, sign) in [1.0f32, -1.0].iter().enumerate() {
            probes[1 + 2 * k + m] = std::array::from_fn(|a| x[a] + sign * step * t[a]);
        }
    }
    (probes, 5)
}

/// Grows flat radii over holes: every hierarchical point (they sample every surface at the
/// finest spacing), and the probes around the finest ones ([`hole_probes`]), where the flat
/// weights sum to less than [`HOLE_WEIGHT`] makes the nearest flat point (Eq. 11, among those
/// whose hierarchical support holds it) reach it at [`HOLE_REACH`] of its radius.
/// Deterministic: the proposals are combined by maximum.
fn fill_holes(hier: &IndexedBasis, source: &[u32], radii: &mut [f32], rule: &FlatRule) {
    use rayon::prelude::*;
    let b = &hier.basis;
    let (flat, flat_tree) = search_basis(hier, source, radii.to_vec());
    let hier_radii = source.iter().map(|&j| b.radii[j as usize]).collect();
    let (search, tree) = search_basis(hier, source, hier_radii);
    let flat_ib = IndexedBasis {
        basis: flat,
        trees: vec![flat_tree],
        clip: source_clip(hier, source),
    };
    let grow: Vec<(u32, f32)> = (0..b.len())
        .into_par_iter()
        .flat_map_iter(|j| {
            let (probes, count) = hole_probes(b, j);
            (0..count).map(move |p| (probes[p], b.normals[j]))
        })
        .filter_map(|(x, n)| {
            if flat_ib.for_each_clipped_weight(0, x, n, |_, _| {}) >= rule.hole_weight {
                return None;
            }
            let mut best = (f32::INFINITY, u32::MAX);
            tree.for_each_candidate(x, |q| {
                let qu = q as usize;
                if hier.clip.cuts(source[qu] as usize, x) {
                    // Behind an occluder from that point: growing it would not cover `x`.
                    return;
                }
                let d = poisson_distance(x, n, search.positions[qu], search.normals[qu]);
                if d < best.0 && d <= search.radii[qu] {
                    best = (d, q);
                }
            });
            (best.1 != u32::MAX).then(|| {
                let q = best.1 as usize;
                let d = crate::kernel::squashed_distance(x, search.positions[q], search.normals[q]);
                (best.1, (d / rule.hole_reach).min(search.radii[q]))
            })
        })
        .collect();
    for (q, r) in grow {
        let r0 = &mut radii[q as usize];
        *r0 = r0.max(r);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pull_push::project;
    use crate::test_support::plane_basis;

    /// The rule of this build less the second step: every needed point kept.
    fn keep_every_needed_point() -> FlatRule {
        FlatRule {
            finer_cover: 0.0,
            ..FlatRule::current()
        }
    }

    /// The projection (Eq. 7) of a smooth function sampled at `ib`'s points.
    fn smooth_solution(ib: &IndexedBasis) -> Vec<f32> {
        let f = |p: [f32; 3]| 2.0 + (3.0 * p[0]).sin() * (2.0 * p[1]).cos();
        let samples: Vec<f32> = ib.basis.positions.iter().map(|&p| f(p)).collect();
        project(ib, &samples, 1).0
    }

    /// Surface points of the plane `z = 0` on the segment from `from` by `count` steps of
    /// `step`, with the plane's normal.
    fn segment(from: [f32; 2], step: [f32; 2], count: usize) -> Vec<([f32; 3], [f32; 3])> {
        (0..count)
            .map(|q| {
                let t = q as f32;
                (
                    [from[0] + step[0] * t, from[1] + step[1] * t, 0.0],
                    [0.0, 0.0, 1.0],
                )
            })
            .collect()
    }

    /// The largest relative difference, over `points`, of `fb`'s flat expansion of `alpha`
    /// (one value per hierarchical point) from the hierarchical one of every level; asserts
    /// that the flat basis supports each point.
    fn worst_difference(
        ib: &IndexedBasis,
        fb: &FlatBasis,
        alpha: &[f32],
        points: &[([f32; 3], [f32; 3])],
    ) -> f32 {
        let flat = fb.flatten(ib, alpha, 1);
        let (mut h, mut f) = ([0.0], [0.0]);
        let mut worst = 0.0f32;
        for &(x, n) in points {
            ib.reconstruct(alpha, 1, 0..ib.levels(), x, n, &mut h);
            assert_eq!(fb.reconstruct(&flat, 1, x, n, &mut f).supported, 1);
            worst = worst.max((h[0] - f[0]).abs() / h[0]);
        }
        worst
    }

    #[test]
    fn without_link_flags_every_point_is_kept_once() {
        let ib = plane_basis(3, 3);
        let fb = FlatBasis::build(&ib, None).unwrap();
        assert_eq!(fb.len(), ib.basis.len());
        let mut seen = fb.source.clone();
        seen.sort_unstable();
        assert!(seen.iter().enumerate().all(|(i, &j)| i == j as usize));
        // Radii from the density: never above the hierarchical radius, and the finest
        // level's density sets them where it has points.
        for (i, &j) in fb.source.iter().enumerate() {
            assert!(fb.ib.basis.radii[i] <= ib.basis.radii[j as usize]);
        }
    }

    #[test]
    fn points_without_linked_finer_support_are_left_out() {
        let ib = plane_basis(3, 3);
        let n = ib.basis.len();
        // Only the coarsest level has links: the flat basis is level 0.
        let linked: Vec<bool> = (0..n).map(|k| ib.basis.level_of(k) == 0).collect();
        let fb = FlatBasis::build(&ib, Some(&linked)).unwrap();
        assert_eq!(fb.len(), ib.basis.level_range(0).len());
        // Links on the finest level everywhere: every point is needed (and, by the default
        // rule, the coarser ones are then covered by the finer ones: the next test).
        let linked = vec![true; n];
        let fb = FlatBasis::build_with(&ib, Some(&linked), keep_every_needed_point()).unwrap();
        assert_eq!(fb.len(), n);
        assert!(FlatBasis::build(&ib, Some(&linked[1..])).is_err());
    }

    #[test]
    fn coarser_points_that_finer_ones_cover_are_left_out() {
        let ib = plane_basis(4, 3);
        let b = &ib.basis;
        let n = b.len();
        let linked = vec![true; n];
        let fb = FlatBasis::build(&ib, Some(&linked)).unwrap();
        let finest = b.level_range(3);
        let mut kept = vec![false; n];
        for &j in &fb.source {
            kept[j as usize] = true;
        }
        // The finest level is kept whole; of the coarser levels, only points near the square's
        // rim (where fewer finer functions reach) may stay.
        assert!(finest.clone().all(|j| kept[j]));
        let coarser: Vec<usize> = (0..finest.start).filter(|&j| kept[j]).collect();
        assert!(
            coarser.len() * 4 < finest.start,
            "{} coarser kept",
            coarser.len()
        );
        for &j in &coarser {
            let mut sum = 0.0;
            for m in b.level_of(j) + 1..4 {
                sum += ib.weight_sum(m, b.positions[j], b.normals[j]);
            }
            assert!(sum < FINER_COVER, "point {j} kept under {sum}");
        }
        // Every surface point stays covered, and a smooth solution is flattened as well as
        // with every point kept.
        let all = FlatBasis::build_with(&ib, Some(&linked), keep_every_needed_point()).unwrap();
        let alpha = smooth_solution(&ib);
        let line = segment([0.1, 0.85], [0.004, -0.0035], 200);
        let worst = |fb: &FlatBasis| worst_difference(&ib, fb, &alpha, &line);
        let (pruned, every) = (worst(&fb), worst(&all));
        assert!(
            pruned < 0.02 && pruned <= every * 1.1,
            "{pruned} against {every}"
        );
        for j in 0..n {
            assert!(fb.coverage(b.positions[j], b.normals[j]) >= 1, "point {j}");
        }
    }

    #[test]
    fn a_coarse_only_solution_is_reproduced_from_the_coarse_points() {
        let ib = plane_basis(3, 3);
        let n = ib.basis.len();
        let linked: Vec<bool> = (0..n).map(|k| ib.basis.level_of(k) == 0).collect();
        let fb = FlatBasis::build(&ib, Some(&linked)).unwrap();
        let mut alpha = vec![0.0f32; n];
        for k in ib.basis.level_range(0) {
            let p = ib.basis.positions[k];
            alpha[k] = 1.0 + 0.3 * p[0] - 0.2 * p[1];
        }
        let line = segment([0.2, 0.75], [0.006, -0.005], 100);
        let worst = worst_difference(&ib, &fb, &alpha, &line);
        assert!(worst < 0.03, "{worst}");
    }

    #[test]
    fn flat_reconstruction_tracks_the_hierarchical_one_with_bounded_coverage() {
        let ib = plane_basis(4, 3);
        let fb = FlatBasis::build(&ib, None).unwrap();
        let line = segment([0.1, 0.85], [0.004, -0.0035], 200);
        let worst = worst_difference(&ib, &fb, &smooth_solution(&ib), &line);
        let mut covered = 0usize;
        for &(x, n) in &line {
            let c = fb.coverage(x, n);
            assert!(c >= 1);
            covered += c;
        }
        assert!(worst < 0.02, "flat and hierarchical differ by {worst}");
        let mean = covered as f64 / 200.0;
        assert!(mean <= 12.0, "mean coverage {mean}");
    }

    /// Links on level 0 and on the finest level (3) in the left half only: fine points there,
    /// coarse ones elsewhere, and a seam between them.
    fn left_half_fine(ib: &IndexedBasis) -> Vec<bool> {
        let fine = ib.basis.level_range(3);
        (0..ib.basis.len())
            .map(|k| {
                ib.basis.level_of(k) == 0 || (fine.contains(&k) && ib.basis.positions[k][0] < 0.5)
            })
            .collect()
    }

    #[test]
    fn every_hierarchical_point_is_covered_where_fine_and_coarse_regions_meet() {
        let ib = plane_basis(4, 3);
        let n = ib.basis.len();
        let linked = left_half_fine(&ib);
        let fb = FlatBasis::build(&ib, Some(&linked)).unwrap();
        assert!(fb.len() < n);
        for j in 0..n {
            let (x, nn) = (ib.basis.positions[j], ib.basis.normals[j]);
            assert!(fb.coverage(x, nn) >= 1, "point {j} at {x:?} uncovered");
        }
    }

    #[test]
    fn every_point_of_the_surface_is_covered_up_to_its_rim() {
        // The points sample [0, 1]^2 (jittered); take the surface to reach half the finest
        // spacing further, as the points stop short of a real surface's rim, where the
        // hierarchical functions still cover it. (On this plane the density radii alone
        // cover the strip; the probes matter where several levels' points crowd a rim.)
        let ib = plane_basis(4, 3);
        let linked = left_half_fine(&ib);
        let fb = FlatBasis::build(&ib, Some(&linked)).unwrap();
        let nn = [0.0, 0.0, 1.0];
        for iy in 0..=100 {
            for ix in 0..=100 {
                let rim = 0.5 / 24.0;
                let at = |i: i32| -rim + (1.0 + 2.0 * rim) * i as f32 / 100.0;
                let x = [at(ix), at(iy), 0.0];
                assert!(ib.weight_sum(0, x, nn) > MIN_WEIGHT_SUM);
                assert!(fb.coverage(x, nn) >= 1, "{x:?} uncovered");
            }
        }
    }

    /// A one-level basis of `n` points around a cylinder of radius 1 (axis z), normals
    /// outwards, and its flat basis on every point (radius 0.5: about three neighbours).
    fn cylinder(n: usize) -> FlatBasis {
        let mut b = Basis::default();
        for i in 0..n {
            let a = i as f32 / n as f32 * std::f32::consts::TAU;
            b.positions.push([a.cos(), a.sin(), 0.0]);
            b.normals.push([a.cos(), a.sin(), 0.0]);
            b.radii.push(0.5);
        }
        b.level_offsets = vec![0, n as u32];
        b.disk_radii = vec![0.2];
        let ib = IndexedBasis::build(b).unwrap();
        FlatBasis::from_parts(&ib, (0..n as u32).collect(), vec![0.5; n]).unwrap()
    }

    #[test]
    fn flat_weights_are_eq_8_times_the_normal_factor() {
        let fb = cylinder(32);
        assert_eq!(fb.normal_power, FLAT_NORMAL_POWER);
        let b = &fb.ib.basis;
        // Between points 3 and 4, with a normal turned towards point 3.
        let x = [0.98 * 0.6f32.cos(), 0.98 * 0.6f32.sin(), 0.02];
        let n = [0.66f32.cos(), 0.66f32.sin(), 0.0];
        let (mut count, mut total) = (0, 0.0f32);
        let sum = fb.for_each_weight(x, n, |i, w| {
            let eq8 = crate::kernel::weight(x, n, b.positions[i], b.normals[i], b.radii[i]);
            let c = n[0] * b.normals[i][0] + n[1] * b.normals[i][1];
            let expected = eq8 * (c.powf(FLAT_NORMAL_POWER - 2.0) + FLAT_NORMAL_FLOOR);
            assert!(
                eq8 > 0.0 && (w - expected).abs() <= 1e-6 * expected,
                "{i}: {w} {expected}"
            );
            count += 1;
            total += w;
        });
        assert!(count >= 3, "{count} functions");
        assert_eq!(sum, total);
        assert_eq!(count, fb.coverage(x, n), "the support is Eq. 8's");
        assert!(fb.clone().with_normal_power(1.5).is_err());
        assert!(fb.clone().with_normal_power(f32::NAN).is_err());
    }

    #[test]
    fn the_sharper_normal_factor_favours_the_points_facing_the_pixels_way() {
        // Coefficient 1 at the point whose normal a pixel between two points has, 0 elsewhere:
        // the flat value there is that point's share of the weight, larger with the sharper
        // factor; with power 2 it is Eq. 8's Shepard value.
        let fb = cylinder(32);
        let mut c = vec![0.0f32; fb.len()];
        c[4] = 1.0;
        let a = 4.0 / 32.0 * std::f32::consts::TAU;
        let x = [0.995 * (a - 0.05).cos(), 0.995 * (a - 0.05).sin(), 0.0];
        let n = [a.cos(), a.sin(), 0.0];
        let value = |basis: &FlatBasis| {
            let mut out = [0.0f32];
            basis.reconstruct(&c, 1, x, n, &mut out);
            out[0]
        };
        let eq8 = fb.clone().with_normal_power(2.0).unwrap();
        let mut sum = 0.0f32;
        let mut own = 0.0f32;
        fb.ib.for_each_weight(0, x, n, |i, w| {
            sum += w;
            if i == 4 {
                own = w;
            }
        });
        assert!(own > 0.0 && (value(&eq8) - own / sum).abs() < 1e-6);
        assert!(
            value(&fb) > value(&eq8) + 0.05,
            "power {}: {} against Eq. 8's {}",
            fb.normal_power,
            value(&fb),
            value(&eq8)
        );
    }

    #[test]
    fn flat_constant_is_exact() {
        let ib = plane_basis(3, 3);
        let fb = FlatBasis::build(&ib, None).unwrap();
        let flat = vec![0.75f32; fb.len()];
        let mut out = [0.0];
        let s = fb.reconstruct(&flat, 1, [0.3, 0.3, 0.0], [0.0, 0.0, 1.0], &mut out);
        assert_eq!(s.supported, 1);
        assert!((out[0] - 0.75).abs() < 1e-6);
    }
}
