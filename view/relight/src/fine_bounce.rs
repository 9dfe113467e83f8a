//! Bounces 2 and later at the finer receivers, applied per frame ([`FineBounceOp`]), from the
//! level-0 coefficients: the viewer's cheaper choice (`crate::cpu::FineEmission::Level0`)
//! and the one the bounce-light feedback builds on. By default the viewer re-emits the bounce
//! light from every sender point instead (`crate::cpu::FineEmission::Senders`), which gives
//! the surfaces that no level-0 point faces their own bounce light.
//!
//! The bake computes bounces 2 and later on the coarsest receivers only (section 3.2, as the
//! paper does): bounce `b` at a level-0 receiver is `K (n . X_{b-1})`, with `K` the level-0
//! block of T and `n_j . X_{b-1}[j]` the previous bounce's irradiance at level-0 point `j`
//! used as the emission of the level-0 sender on that point. `S`'s finer rows are T's: the
//! first bounce only. The later bounces are then reconstructed from level-0 coefficients
//! alone, and vector irradiance turns with the surface normal: where a level-0 function
//! spans faces that look different ways (a pillar, an arcade, the underside of an arch) the
//! reconstruction `n(x) . v_j` of a neighbour's vector irradiance falls short. Finer
//! receivers' links are the Eq. 17 differences that correct it, and they exist: T's finer rows
//! link to the level-0 senders wherever the correction passed refinement's test. The bake
//! does not chain bounces through them, because each product link of a finer receiver to each
//! original sender is tiny and would be cut at epsilon.
//!
//! Per frame the chain is cheap: `i = S e` gives the level-0 receivers every bounce, so the
//! level-0 senders' emission of bounces 1 and later is `y_j = n_j . i_j` (per colour channel)
//! and the finer receivers' bounces 2 and later are `T_fine,0 y`, the product of their links to
//! level-0 senders with `y`:
//!
//! `i_r += sum_{j in level 0} T_rj y_j`   for every receiver `r` above level 0.
//!
//! With `B` bounces in `S` the finer levels get bounces 2 to `B + 1` (one more than the
//! coarsest, below the bounce tolerance of a converged bake). A file whose bounces already ran
//! on every receiver (`bounces_on_all_receivers`), or that has one bounce, must not get this
//! step ([`FineBounceOp::applies_to`]).

use mlt_format::links::{ArchivedLinks, LINK_DIM};
use mlt_format::meta::TransportMeta;
use mlt_format::IndexedBasis;

use crate::receiver_links::ReceiverLinks;

/// The finer receivers' links to level-0 senders, receiver-major, with the level-0 normals.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FineBounceOp {
    /// Normals of the level-0 points (the senders the links reach).
    normals: Vec<[f32; 3]>,
    links: ReceiverLinks,
}

impl FineBounceOp {
    /// Whether a file's `S` leaves bounces 2 and later out of its finer rows: bounces were
    /// computed on the coarsest receivers only and there is more than one.
    pub fn applies_to(tm: &TransportMeta) -> bool {
        !tm.params.bounces_on_all_receivers && tm.stats.bounces >= 2
    }

    /// Collects the links of receivers above level 0 to level-0 senders from validated
    /// `links` (receivers are `ib`'s points).
    pub fn build(ib: &IndexedBasis, links: &ArchivedLinks) -> FineBounceOp {
        let coarsest = ib.basis.level_range(0).len();
        let c = coarsest as u32;
        FineBounceOp {
            normals: ib.basis.normals[..coarsest].to_vec(),
            links: ReceiverLinks::build_where(links, |s, r| s < c && r >= c),
        }
    }

    /// Links held.
    pub fn link_count(&self) -> usize {
        self.links.link_count()
    }

    /// Heap bytes held.
    pub fn bytes(&self) -> usize {
        self.links.bytes() + 12 * self.normals.len()
    }

    /// Adds the finer receivers' bounces 2 and later to `i = S e` (9 floats per point):
    /// `i_r += sum_j T_rj (n_j . i_j)` over level-0 points `j`. The same bits for any thread
    /// count. Panics unless `i` holds 9 floats per receiver of the links.
    pub fn apply(&self, i: &mut [f32]) {
        let y = level0_emission(&self.normals, i);
        // Receivers of these links are above level 0, so the level-0 part of `i` read above
        // is not written.
        self.links.apply_add(&y, 0.0, i);
    }

    /// [`FineBounceOp::apply`] with the level-0 coefficients taken from `level0` (9 floats per
    /// level-0 point) instead of from `i`: the finer receivers' next bounces of light added at
    /// level 0 after `S e` (as [`crate::BounceFeedbackOp`] adds it).
    pub fn apply_from(&self, level0: &[f32], i: &mut [f32]) {
        let y = level0_emission(&self.normals, level0);
        self.links.apply_add(&y, 0.0, i);
    }
}

/// The bake's chain's emission of level-0 senders, `y_j = n_j . v_j` per colour channel, for
/// the level-0 points with `normals` (the first points of `v`, 9 floats each).
pub(crate) fn level0_emission(normals: &[[f32; 3]], v: &[f32]) -> Vec<f32> {
    let mut y = vec![0.0f32; 3 * normals.len()];
    for (j, n) in normals.iter().enumerate() {
        y[3 * j..3 * j + 3].copy_from_slice(&along_normal(*n, &v[j * LINK_DIM..]));
    }
    y
}

/// The irradiance `n . v_c` per colour channel `c` of a point's vector irradiance `v` (its 9
/// floats first in `v`, RGB-major): what the surface there receives, and re-emits as a
/// sender's coefficient.
#[inline]
pub(crate) fn along_normal(n: [f32; 3], v: &[f32]) -> [f32; 3] {
    std::array::from_fn(|c| n[0] * v[3 * c] + n[1] * v[3 * c + 1] + n[2] * v[3 * c + 2])
}
