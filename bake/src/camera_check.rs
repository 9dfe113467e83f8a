//! The bake's check of its own light where the scene's camera looks ([`CameraCheck`], the
//! file's `TCAM` section).
//!
//! The other estimates of the bake weigh the basis points, each by the area its function
//! stands for. An image weighs surfaces by how much of the view they fill and by their albedo,
//! and a shortfall at the points can have the other sign in an image (a point light near a
//! wall the camera does not see). This check measures what the image will show: it traces the
//! indirect light at the pixels of the scene's camera and compares it with what the file gives
//! there.
//!
//! Through a grid of `width x height` cells over the camera's image (the camera's aspect,
//! [`GRID_WIDTH`] cells across), one primary ray through a uniformly random point of each cell
//! (a box filter over the cell, as `view reference` filters a pixel) to its first hit `x`
//! (shading normal `n`, albedo `ρ`). There:
//!
//! - the traced indirect irradiance, [`RAYS`] paths of the estimator `view reference` uses
//!   (`mlt_scenes::one_bounce`: at every vertex the one-bounce term `∫ ρ(y)/π E_d(y) cos θ dω`
//!   by multiple importance sampling of a cosine-weighted direction and a ray from the light,
//!   so a hot spot near the light is found; the path continues from the cosine sample, with
//!   roulette): the first vertex's term alone is the first bounce `E_1(x)` (the rendering
//!   equation with one bounce, Eq. 1 of the paper for diffuse surfaces), the sum every bounce;
//! - the file's first bounce `n · Σ_i (T e)_i B_i(x, n)`: T's coefficients under the
//!   representative emission `e` (the file light's direct irradiance at the sender points,
//!   sampled and pull-pushed onto the sender levels as the viewer does) expanded over every
//!   level (Eq. 6); and its every bounce, the same of what a frame of the viewer gives under
//!   `e` ([`frame_coefficients`]: `S e`, and the finer receivers' later bounces re-emitted
//!   from every sender point where the file leaves them to the viewer).
//!
//! Each times `ρ`, averaged over the cells, a miss adding zero (the image's mean radiance,
//! times `π`). A share `1 - Y(file) / Y(traced)` (Rec. 709 luminance) is what the image lacks
//! (negative: too bright). The first bounce's holds T's dropped links, the projection of the
//! direct light onto the senders and the basis' reconstruction; every bounce's also the later
//! bounces (their truncation and the paths that compute them). Neither holds the flat basis
//! the viewer splats, the viewer's shadow rays over a disk around the light (the emission here
//! has one shadow ray per sender point), nor the feedback step the viewer adds to files whose
//! bounces were chained (`--level0-paths 0`). Each share's standard error is that of the mean
//! of the cells' differences (the cells are independent samples of the image, so it holds the
//! primary rays' noise, the paths' and the per-pixel basis error's).
//!
//! The same cells by blocks of [`BLOCK`] x [`BLOCK`] ([`CameraBlocks`], the `TCBK` section):
//! per block the ratio of the baked to the traced mean of every bounce, with its standard
//! error from the block's cells (the ratio's first-order error), over the blocks whose traced
//! mean exceeds [`LIT_BLOCK`] of the image's; the worst of them is where the bake is most off
//! locally, a seam along a wall, say, that the image's mean hides.
//!
//! Each cell draws from its own stream `(seed, cell)` and the sums run in cell order, so the
//! check is the same for any thread count.

use glam::Vec3;
use mlt_format::light_model::Light;
use mlt_format::links::{Links, LINK_DIM};
use mlt_format::meta::{CameraBlocks, CameraCheck, CameraInfo};
use mlt_format::pull_push::pull_push_levels;
use mlt_format::IndexedBasis;
use mlt_scenes::one_bounce::{OneBounce, PointLight};
use mlt_scenes::RayCaster;
use rayon::prelude::*;

use crate::drop_estimate::{along, coefficients};
use crate::refine::ReceiverLinks;
use crate::rng::{Rng, Stream};

/// Cells across the grid of primary rays (its height follows the camera's aspect).
pub const GRID_WIDTH: u32 = 160;
/// Paths per cell for the traced light.
pub const RAYS: u32 = 32;
/// Side of the blocks of [`CameraBlocks`], in cells.
pub const BLOCK: u32 = 16;
/// A block counts (is *lit*) when its traced mean exceeds this share of the image's.
pub const LIT_BLOCK: f64 = 0.1;
/// The paths' bounce cap and the bounce from which roulette ends them (`view reference`'s
/// defaults).
const PATH_BOUNCES: (u32, u32) = (1024, 3);

/// Rec. 709 luminance weights.
const LUMA: [f64; 3] = [0.2126, 0.7152, 0.0722];

/// The check's resolution and seed.
#[derive(Clone, Copy, Debug)]
pub struct CheckSettings {
    /// Cells across (the height follows the camera's aspect) and paths per cell.
    pub width: u32,
    pub rays: u32,
    pub seed: u64,
}

impl CheckSettings {
    /// [`GRID_WIDTH`] cells across, [`RAYS`] paths per cell, `seed`.
    pub fn new(seed: u64) -> CheckSettings {
        CheckSettings {
            width: GRID_WIDTH,
            rays: RAYS,
            seed,
        }
    }
}

/// One cell's traced and baked first bounce and the same of every bounce, each times the
/// albedo at its primary hit: `[traced first, baked first, traced all, baked all]`.
type Cell = Option<[[f64; 3]; 4]>;

/// What a frame of the viewer gives at the receivers (9 floats per point): `i = S e` from the
/// stored `links` under the sender coefficients `e` (RGB per point of the first
/// `sender_levels` levels), and with `fine` the finer receivers' bounces 2 and later as the
/// viewer adds them by default for a file whose bounces ran on the coarsest receivers only
/// (`mlt_relight::FineEmission::Senders`): the indirect light at every sender point `p`,
/// `n_p . sum_l sum_k i_k B^l_k(p)` (Eq. 6), pull-pushed onto the sender levels as the direct
/// light is, re-emitted through the rows of the receivers above level 0,
/// `i_r += sum_s S_rs y_s`. Panics unless `e` holds 3 floats per sender point.
pub fn frame_coefficients(
    ib: &IndexedBasis,
    links: &Links,
    (e, sender_levels): (&[f32], usize),
    fine: bool,
) -> Vec<f32> {
    let b = &ib.basis;
    let n0 = b.level_range(0).len();
    let mut i = vec![0.0f32; b.len() * LINK_DIM];
    let senders = b.level_offsets[sender_levels.min(b.levels())] as usize;
    assert_eq!(e.len(), 3 * senders, "one RGB emission per sender point");
    add_product(links, e, 0, &mut i);
    if fine {
        let samples: Vec<f32> = (0..senders)
            .into_par_iter()
            .flat_map_iter(|p| {
                let mut v = [0.0f32; LINK_DIM];
                ib.reconstruct(
                    &i,
                    LINK_DIM,
                    0..b.levels(),
                    b.positions[p],
                    b.normals[p],
                    &mut v,
                );
                along(&v, b.normals[p])
            })
            .collect();
        let (y, _) = pull_push_levels(ib, &samples, 3, sender_levels);
        add_product(links, &y, n0, &mut i);
    }
    i
}

/// `i_r += sum_s S_rs em_s` over the stored links of the receivers `r >= from` (`em`: RGB per
/// sender; senders it does not cover add nothing).
fn add_product(links: &Links, em: &[f32], from: usize, i: &mut [f32]) {
    for (slot, &s) in links.sender_ids.iter().enumerate() {
        let Some(es) = em.get(3 * s as usize..3 * s as usize + 3) else {
            continue;
        };
        for k in links.offsets[slot] as usize..links.offsets[slot + 1] as usize {
            let r = links.receiver_ids[k] as usize;
            if r < from {
                continue;
            }
            if let Some(out) = i.get_mut(r * LINK_DIM..(r + 1) * LINK_DIM) {
                let v = links.value(k, slot);
                for d in 0..LINK_DIM {
                    out[d] += es[d / 3] * v[d];
                }
            }
        }
    }
}

/// The check at `camera` under `light` of `t` (every receiver's row of T, with the
/// representative emission it was refined under) for the first bounce, and of `frame` (the
/// coefficients a frame of the viewer gives under that emission, [`frame_coefficients`]) for
/// every bounce; `None` when the camera is degenerate or the settings ask for no rays.
pub fn camera_check(
    ib: &IndexedBasis,
    caster: &dyn RayCaster,
    light: &Light,
    camera: &CameraInfo,
    (t, frame): (&ReceiverLinks, &[f32]),
    settings: CheckSettings,
) -> Option<(CameraCheck, CameraBlocks)> {
    let (w, rays) = (settings.width, settings.rays);
    if w == 0 || rays == 0 || camera.width == 0 || camera.height == 0 {
        return None;
    }
    let primary = camera.primary_rays()?;
    let h = ((w as f64 * camera.height as f64 / camera.width as f64).round() as u32).max(1);
    let first = coefficients(ib.basis.len(), t);
    let levels = ib.levels();
    let one = OneBounce::new(
        caster,
        PointLight {
            position: light.position,
            irradiance: Box::new(|x, n| light.irradiance(x, n)),
        },
    );
    let eye = Vec3::from(camera.position);
    let (sx, sy) = (
        camera.width as f32 / w as f32,
        camera.height as f32 / h as f32,
    );
    let cells: Vec<Cell> = (0..w * h)
        .into_par_iter()
        .map(|c| {
            let mut rng = Rng::new(settings.seed, Stream::Camera, c as u64);
            let px = ((c % w) as f32 + rng.next_f32()) * sx;
            let py = ((c / w) as f32 + rng.next_f32()) * sy;
            let dir = primary.direction(px, py);
            let hit = caster.intersect(eye, dir, 0.0, f32::INFINITY)?;
            let (x, n, ng) = (hit.position, hit.shading_normal, hit.geometric_normal);
            let (mut t1, mut ta) = ([0.0f64; 3], [0.0f64; 3]);
            for _ in 0..rays {
                let p = one.path(x, n, ng, PATH_BOUNCES, &mut || rng.next_f32());
                for k in 0..3 {
                    t1[k] += p.first[k] as f64;
                    ta[k] += p.all[k] as f64;
                }
            }
            let rho = hit.albedo.map(f64::from);
            let baked = |alpha: &[f32]| {
                let mut v = [0.0f32; LINK_DIM];
                ib.reconstruct(alpha, LINK_DIM, 0..levels, x.into(), n.into(), &mut v);
                let e = along(&v, n.into());
                std::array::from_fn(|k| rho[k] * e[k] as f64)
            };
            let mean = |s: [f64; 3]| std::array::from_fn(|k| rho[k] * s[k] / rays as f64);
            Some([mean(t1), baked(&first), mean(ta), baked(frame)])
        })
        .collect();
    Some((summarise(&cells, (w, h, rays)), by_blocks(&cells, w, h)))
}

/// The cells (every bounce: traced at index 2, baked at 3) by blocks (module docs).
fn by_blocks(cells: &[Cell], width: u32, height: u32) -> CameraBlocks {
    let luma = |v: &[f64; 3]| (0..3).map(|k| LUMA[k] * v[k]).sum::<f64>();
    let (w, h, b) = (width as usize, height as usize, BLOCK as usize);
    let (cols, rows) = (w.div_ceil(b), h.div_ceil(b));
    let value = |c: &Cell| c.map_or((0.0, 0.0), |v| (luma(&v[2]), luma(&v[3])));
    let image_mean = cells.iter().map(|c| value(c).0).sum::<f64>() / cells.len().max(1) as f64;
    let mut out = CameraBlocks {
        block: BLOCK,
        columns: cols as u32,
        rows: rows as u32,
        ratio_min: f64::INFINITY,
        ..Default::default()
    };
    let mut worst = -1.0f64;
    for by in 0..rows {
        for bx in 0..cols {
            let ids: Vec<usize> = (by * b..((by + 1) * b).min(h))
                .flat_map(|y| (bx * b..((bx + 1) * b).min(w)).map(move |x| y * w + x))
                .filter(|&k| k < cells.len())
                .collect();
            let n = ids.len() as f64;
            if n < 2.0 {
                continue;
            }
            let (mut t, mut k) = (0.0, 0.0);
            for &i in &ids {
                let (a, c) = value(&cells[i]);
                t += a / n;
                k += c / n;
            }
            if !(t > LIT_BLOCK * image_mean && t > 0.0) {
                continue;
            }
            let ratio = k / t;
            // The ratio's first-order standard error: that of the mean of `baked - ratio
            // traced` over the cells, divided by the traced mean.
            let var = ids
                .iter()
                .map(|&i| {
                    let (a, c) = value(&cells[i]);
                    (c - ratio * a) * (c - ratio * a)
                })
                .sum::<f64>()
                / (n - 1.0);
            out.lit += 1;
            out.ratio_min = out.ratio_min.min(ratio);
            out.ratio_max = out.ratio_max.max(ratio);
            let off = if ratio > 0.0 {
                ratio.ln().abs()
            } else {
                f64::INFINITY
            };
            if off > worst {
                worst = off;
                out.worst_column = bx as u32;
                out.worst_row = by as u32;
                out.worst_ratio = ratio;
                out.worst_std_error = (var / n).sqrt() / t;
            }
        }
    }
    if out.lit == 0 {
        out.ratio_min = 0.0;
    }
    out
}

/// The share one side of the cells lacks against the other (`traced` at index `a`, `baked` at
/// `a + 1`) and its standard error, from the cells' luminance differences.
fn share(cells: &[Cell], a: usize, traced: &[f64; 3], baked: &[f64; 3]) -> (f64, f64) {
    let count = cells.len().max(1) as f64;
    let luma = |v: &[f64; 3]| (0..3).map(|k| LUMA[k] * v[k]).sum::<f64>();
    let (yt, yb) = (luma(traced), luma(baked));
    if yt <= 0.0 {
        return (0.0, 0.0);
    }
    let mean_d = yt - yb;
    let var: f64 = cells
        .iter()
        .map(|c| c.map_or(0.0, |v| luma(&v[a]) - luma(&v[a + 1])) - mean_d)
        .map(|d| d * d)
        .sum::<f64>()
        / (count - 1.0).max(1.0);
    // The share's error is the mean difference's, over the traced mean.
    (mean_d / yt, (var / count).sqrt() / yt)
}

/// The means over all cells (a miss counts as zero), the shares and their standard errors.
fn summarise(cells: &[Cell], (width, height, rays): (u32, u32, u32)) -> CameraCheck {
    let count = cells.len().max(1) as f64;
    let mut m = [[0.0f64; 3]; 4];
    let mut cells_hit = 0u64;
    for v in cells.iter().flatten() {
        cells_hit += 1;
        for (acc, x) in m.iter_mut().zip(v) {
            for k in 0..3 {
                acc[k] += x[k] / count;
            }
        }
    }
    let (share_first, error_first) = share(cells, 0, &m[0], &m[1]);
    let (share_all, error_all) = share(cells, 2, &m[2], &m[3]);
    CameraCheck {
        width,
        height,
        rays,
        cells_hit,
        traced: m[0],
        baked: m[1],
        share: share_first,
        std_error: error_first,
        traced_all: m[2],
        baked_all: m[3],
        share_all,
        std_error_all: error_all,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_find_the_block_that_is_off_where_the_mean_is_right() {
        // A 32 x 16 grid (two blocks): the left too bright by a third, the right too dark by
        // a third, so that the image's mean is right; one cell missed.
        let cell = |traced: f64, baked: f64| -> Cell {
            Some([[0.0; 3], [0.0; 3], [traced; 3], [baked; 3]])
        };
        let mut cells: Vec<Cell> = (0..32 * 16)
            .map(|k| {
                if k % 32 < 16 {
                    cell(3.0, 4.0)
                } else {
                    cell(3.0, 2.0)
                }
            })
            .collect();
        cells[40] = None;
        let c = summarise(&cells, (32, 16, 1));
        assert!(c.share_all.abs() < 0.01, "{}", c.share_all);
        let b = by_blocks(&cells, 32, 16);
        assert_eq!((b.columns, b.rows, b.lit), (2, 1, 2));
        assert!((b.ratio_min - 2.0 / 3.0).abs() < 1e-12 && (b.ratio_max - 4.0 / 3.0).abs() < 1e-12);
        // ln(2/3) is farther from 0 than ln(4/3): the right block is the worst.
        assert_eq!((b.worst_column, b.worst_row), (1, 0));
        assert!((b.worst_ratio - 2.0 / 3.0).abs() < 1e-12);
        // Every cell of that block agrees: no spread, no error.
        assert!(b.worst_std_error < 1e-12, "{}", b.worst_std_error);
        // A dark block (below a tenth of the image's mean) does not count.
        let dim: Vec<Cell> = (0..32 * 16)
            .map(|k| {
                if k % 32 < 16 {
                    cell(3.0, 3.0)
                } else {
                    cell(0.01, 1.0)
                }
            })
            .collect();
        let b = by_blocks(&dim, 32, 16);
        assert_eq!((b.lit, b.worst_column), (1, 0));
        assert!((b.worst_ratio - 1.0).abs() < 1e-12);
    }

    #[test]
    fn the_share_is_what_the_baked_light_lacks_and_its_error_shrinks_with_the_cells() {
        // Half the cells see twice the light they are baked with, half miss; every bounce is
        // baked right.
        let cells: Vec<Cell> = (0..100)
            .map(|i| (i % 2 == 0).then_some([[2.0; 3], [1.0; 3], [3.0; 3], [3.0; 3]]))
            .collect();
        let c = summarise(&cells, (10, 10, 1));
        assert_eq!(c.cells_hit, 50);
        assert!((c.traced[0] - 1.0).abs() < 1e-12 && (c.baked[1] - 0.5).abs() < 1e-12);
        assert!((c.share - 0.5).abs() < 1e-12);
        // Differences 1 and 0 in equal numbers: sd 0.5025, over sqrt(100) and the mean 1.
        assert!((c.std_error - 0.050252).abs() < 1e-5, "{}", c.std_error);
        assert!(c.share_all.abs() < 1e-12 && c.std_error_all < 1e-12);
        // Too bright: a negative share.
        let cells: Vec<Cell> = vec![Some([[1.0; 3], [1.25; 3], [1.0; 3], [0.5; 3]]); 16];
        let c = summarise(&cells, (4, 4, 1));
        assert!((c.share + 0.25).abs() < 1e-12 && c.std_error < 1e-12);
        assert!((c.share_all - 0.5).abs() < 1e-12);
    }

    #[test]
    fn a_frame_adds_the_finer_receivers_bounces_from_every_sender_point() {
        use mlt_format::links::SenderLinks;
        use mlt_format::test_support::plane_basis;
        let ib = plane_basis(2, 2);
        let b = &ib.basis;
        let (n0, len) = (b.level_range(0).len(), b.len());
        assert!(n0 >= 1 && len > n0);
        // Sender 0 lights itself (1 along +z per channel) and the first finer point (0.5).
        let unit = |a: f32| {
            let mut v = [0.0f32; LINK_DIM];
            for c in 0..3 {
                v[3 * c + 2] = a;
            }
            v
        };
        let col = [(0u32, unit(1.0)), (n0 as u32, unit(0.5))];
        let (links, _) = Links::pack(
            len as u32,
            n0 as u32,
            [SenderLinks {
                sender: 0,
                links: &col,
            }],
        );
        let mut e = vec![0.0f32; 3 * n0];
        e[..3].copy_from_slice(&[2.0, 2.0, 2.0]);
        let plain = frame_coefficients(&ib, &links, (&e, 1), false);
        let fine = frame_coefficients(&ib, &links, (&e, 1), true);
        let z = |v: &[f32], p: usize| v[p * LINK_DIM + 2];
        assert_eq!((z(&plain, 0), z(&plain, n0)), (2.0, 1.0));
        // The emission at sender 0 is the frame's irradiance there, over every level (level
        // 0's 2 and the finer point's 1 where its function reaches), pull-pushed onto the one
        // sender level; re-emitted through the 0.5 link to the finer point. Level 0 itself
        // gets nothing more.
        let samples: Vec<f32> = (0..n0)
            .flat_map(|p| {
                let mut w = [0.0f32; LINK_DIM];
                ib.reconstruct(
                    &plain,
                    LINK_DIM,
                    0..b.levels(),
                    b.positions[p],
                    b.normals[p],
                    &mut w,
                );
                along(&w, b.normals[p])
            })
            .collect();
        let (y, _) = pull_push_levels(&ib, &samples, 3, 1);
        assert_eq!(b.normals[0], [0.0, 0.0, 1.0]);
        assert!(y[0] > 1.0, "{y:?}");
        assert_eq!(z(&fine, 0), 2.0);
        assert!(
            (z(&fine, n0) - (1.0 + 0.5 * y[0])).abs() < 1e-6,
            "{}",
            z(&fine, n0)
        );
        // The finer points without links get nothing.
        assert!((n0 + 1..len).all(|p| z(&fine, p) == 0.0));
    }
}
