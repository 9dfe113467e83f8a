//! The flat basis the renderer splats against the exact per-pixel evaluation of the
//! hierarchical expansion (Eq. 6), on the built-in Cornell box's default view, on the CPU (no
//! GPU needed): every surface pixel covered by a bounded number of flat functions, the flat
//! indirect image close to the exact one, and no dark blotch in either.

mod common;

use common::{bake_to, relight_file};
use mlt_bake::BakeOptions;
use mlt_view::exact::{dark_pixels, exact_indirect, flat_coverage, flat_indirect, surface_points};
use mlt_view::images::luminance;
use mlt_view::{Camera, RgbImage};

/// Relative RMS difference of the luminances of `a` from `reference`.
fn rel_rmse(a: &RgbImage, reference: &RgbImage) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (x, y) in a.pixels.iter().zip(&reference.pixels) {
        let (x, y) = (f64::from(luminance(*x)), f64::from(luminance(*y)));
        num += (x - y).powi(2);
        den += y * y;
    }
    (num / den).sqrt()
}

/// Bakes the built-in Cornell box with `opts`, relights it with the file's light and checks
/// the flat image of its default view at `w` x `h` against the exact evaluation.
/// With `check_blotch`, also that the exact image has no pixel darker than a quarter of its
/// neighbourhood's median on its own surface (a dark blotch in the hierarchical solution
/// itself). `rmse_max` bounds the flat image's relative RMSE from the exact one.
fn check_cornell(name: &str, opts: BakeOptions, w: u32, h: u32, check_blotch: bool, rmse_max: f64) {
    let d = common::temp_dir("flat", name);
    let spec = "builtin:cornell";
    // MLT_FLAT_CORNELL names a bake to reuse (written there when missing).
    let f = match std::env::var_os("MLT_FLAT_CORNELL") {
        Some(p) if name.starts_with("default") => std::path::PathBuf::from(p),
        _ => d.join("cornell.mlt"),
    };
    if !f.exists() {
        bake_to(&f, spec, opts);
    }
    let r = relight_file(&f, spec, |l| l);
    let (frame, fb, ib, caster) = (&r.frame, &r.flat, &r.hier, r.caster.as_ref());
    assert!(fb.len() <= ib.basis.len());
    let mut camera = Camera::from_info(&r.meta.camera).unwrap();
    camera.width = w;
    camera.height = h;
    let points = surface_points(&camera, caster);
    let surface = points.iter().filter(|p| p.is_some()).count();
    assert!(surface > (w * h / 2) as usize, "{surface} surface pixels");

    // Coverage: every surface pixel, a bounded number of flat functions.
    let coverage = flat_coverage(fb, &points);
    let counts: Vec<usize> = coverage.iter().flatten().copied().collect();
    let uncovered = counts.iter().filter(|&&c| c == 0).count();
    let mean = counts.iter().sum::<usize>() as f64 / counts.len() as f64;
    let mut histogram = [0usize; 8];
    for &c in &counts {
        histogram[(c / 4).min(7)] += 1;
    }
    let exact = exact_indirect(ib, &frame.i, &points, w);
    let flat = flat_indirect(fb, &frame.flat, &points, w);
    let rmse = rel_rmse(&flat, &exact);
    let max_lum = exact
        .pixels
        .iter()
        .map(|p| luminance(*p))
        .fold(0.0, f32::max);
    let floor = 1e-3 * max_lum;
    // Flattening adds no dark spot: no flat pixel below a quarter of the exact one.
    let darker: Vec<usize> = (0..flat.pixels.len())
        .filter(|&k| {
            let e = luminance(exact.pixels[k]);
            e > floor && luminance(flat.pixels[k]) < 0.25 * e
        })
        .collect();
    let dark_exact = dark_pixels(&exact, &points, 3, 0.25, floor);
    eprintln!(
        "{name}: {} of {} points flat, {surface} surface pixels, coverage mean {mean:.2}, \
         histogram by 4 {histogram:?}, uncovered {uncovered}; flat vs exact relative RMSE \
         {rmse:.4}; flat pixels darker than a quarter of the exact {}; exact pixels darker \
         than a quarter of their neighbourhood {}",
        fb.len(),
        ib.basis.len(),
        darker.len(),
        dark_exact.len()
    );
    assert_eq!(uncovered, 0, "surface pixels without a flat function");
    assert!(mean <= 12.0, "mean coverage {mean}");
    assert!(
        rmse < rmse_max,
        "flat image differs from the exact one by {rmse}"
    );
    assert!(
        darker.is_empty(),
        "flattening darkens pixels {:?}",
        &darker[..darker.len().min(10)]
    );
    if !check_blotch {
        return;
    }
    assert!(
        dark_exact.is_empty(),
        "dark blotch in the exact image at {:?}",
        &dark_exact[..dark_exact.len().min(10)]
    );
}

#[test]
fn flat_image_of_a_small_cornell_bake_matches_the_exact_evaluation() {
    let opts = BakeOptions {
        receiver_levels: Some(4),
        coarse_count: Some(60),
        gather_rays: Some(128),
        ..Default::default()
    };
    // 128x96: at 80x60 the 7-pixel window of the blotch test spans half the short block's
    // front face, whose light falls fourfold from the floor to the top edge.
    check_cornell("small", opts, 128, 96, true, 0.02);
}

/// The blotch of the default bake in a bake of seconds: the default level-0 point count (whose
/// dart throwing leaves part of the short block's front face outside every level-0 support
/// unless the placement fills it), three levels and few gather rays. Without the coverage fill
/// the exact image is dark on that face (18 pixels at 128x96).
#[test]
fn cornell_solution_at_the_default_point_count_has_no_dark_blotch() {
    let opts = BakeOptions {
        receiver_levels: Some(3),
        gather_rays: Some(64),
        ..Default::default()
    };
    // Three levels and 64 rays make a coarser flat basis than the default bake's.
    check_cornell("small-default-count", opts, 128, 96, true, 0.05);
}

/// The default bake of the built-in Cornell box (the main job's `bake builtin:cornell`), whose
/// short block shows a dark blotch. Slow in debug builds: run with `--ignored`
/// (`MLT_FLAT_CORNELL=PATH` keeps the bake for the next run).
#[test]
#[ignore]
fn flat_image_of_the_default_cornell_bake_matches_the_exact_evaluation() {
    check_cornell("default", BakeOptions::default(), 128, 96, false, 0.02);
}

/// The blotch itself: the exact evaluation of the default bake's hierarchical solution (Eq. 6)
/// was dark on the short block's front face, where level 0 had no support; slow in debug
/// builds.
#[test]
#[ignore]
fn default_cornell_solution_has_no_dark_blotch() {
    check_cornell(
        "default-blotch",
        BakeOptions::default(),
        128,
        96,
        true,
        0.02,
    );
}
