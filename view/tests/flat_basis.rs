//! The flat basis the renderer splats against the exact per-pixel evaluation of the
//! hierarchical expansion (Eq. 6), on the built-in Cornell box's default view, on the CPU (no
//! GPU needed): every surface pixel covered by a bounded number of flat functions, the flat
//! indirect image (sharpened, as the relighter gives it) close to the exact one and closer
//! than without the sharpening step, and no dark blotch in either: no pixel far darker than
//! its neighbourhood where the path-traced reference is not dark as well. On the box's
//! planar faces the `--by-normal` diagnostic reduces to the unsharpened flat image.

mod common;

use common::{bake_to, relight_file};
use mlt_bake::BakeOptions;
use mlt_format::links::LINK_DIM;
use mlt_view::exact::{blotches, dark_pixels};
use mlt_view::flat_check::FlatCheck;
use mlt_view::reference::render_reference;
use mlt_view::Camera;

/// Bakes the built-in Cornell box with `opts`, relights it with the file's light and checks
/// the flat image of its default view at `w` x `h` against the exact evaluation
/// ([`FlatCheck`], what `view flat FILE` prints).
/// With `check_blotch`, also that the exact image has no pixel darker than a quarter of its
/// neighbourhood's median on its own surface where the path-traced reference is not dark
/// too (a dark blotch in the hierarchical solution itself; [`blotches`]: a resolved contact
/// shadow is dark in the reference as well). `rmse_max` bounds the flat image's relative RMSE
/// from the exact one.
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
    let mut c = FlatCheck::measure(ib, &frame.i, fb, &frame.flat, &camera, caster);
    // The flat coefficients without the sharpening step: Eq. 6 at the flat points.
    let unsharpened = fb.flatten(ib, &frame.i, LINK_DIM);
    let plain = FlatCheck::measure(ib, &frame.i, fb, &unsharpened, &camera, caster);
    assert!(
        c.surface_pixels > (w * h / 2) as usize,
        "{} surface pixels",
        c.surface_pixels
    );
    let max_lum = c.exact_max;
    let dark_exact = dark_pixels(&c.exact, &c.points, 3, 0.25, 1e-3 * max_lum);
    eprintln!(
        "{name}: {}exact pixels darker than a quarter of their neighbourhood {}; without \
         sharpening: relative RMSE {:.4}",
        c.summary(),
        dark_exact.len(),
        plain.rel_rmse
    );
    // Coverage: every surface pixel, a bounded number of flat functions (at most 12 in the
    // mean, the splat pass's budget of fill; the box's default view has 8-9).
    assert_eq!(c.uncovered, 0, "surface pixels without a flat function");
    assert!(c.coverage_mean <= 12.0, "mean coverage {}", c.coverage_mean);
    assert!(
        c.rel_rmse < rmse_max,
        "flat image differs from the exact one by {}",
        c.rel_rmse
    );
    // The box's faces are planes at right angles or parallel, so the flat functions with any
    // weight at a pixel share its normal, and taking their values at the pixel's normal
    // changes nothing: the diagnostic gives the unsharpened image's difference.
    c.split_by_normal(ib, &frame.i, fb);
    let at_normals = c.rel_rmse_at_pixel_normals.unwrap();
    assert!(
        (at_normals - plain.rel_rmse).abs() <= 1e-3 * plain.rel_rmse,
        "at the pixels' normals {at_normals}, unsharpened {}",
        plain.rel_rmse
    );
    // The sharpening step takes back part of the flat basis' smoothing.
    assert!(
        c.rel_rmse < 0.9 * plain.rel_rmse,
        "sharpened {} against {} without",
        c.rel_rmse,
        plain.rel_rmse
    );
    // Flattening adds no dark spot: no flat pixel below a quarter of the exact one.
    assert!(
        c.darker.is_empty(),
        "flattening darkens pixels {:?}",
        &c.darker[..c.darker.len().min(10)]
    );
    if !check_blotch {
        return;
    }
    // The true light at the same pixels: 256 paths each, enough for the reference's own test
    // (half its neighbourhood) to hold at the contact shadows.
    let reference = render_reference(caster, &camera, &r.light, 256, 1).unwrap();
    let blotched = blotches(
        &c.exact,
        &reference.indirect,
        &c.points,
        3,
        0.25,
        1e-3 * max_lum,
    );
    eprintln!(
        "{name}: of the exact image's {} dark pixels, {} are not dark in the reference",
        dark_exact.len(),
        blotched.len()
    );
    assert!(
        blotched.is_empty(),
        "dark blotch in the exact image at {:?}",
        &blotched[..blotched.len().min(10)]
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
    check_cornell("small", opts, 128, 96, true, 0.015);
}

/// The blotch of the default bake in a bake of seconds: the default level-0 point count (whose
/// dart throwing leaves part of the short block's front face outside every level-0 support
/// unless the placement fills it), three levels and few gather rays. Without the coverage fill
/// the exact image is dark on that face (18 pixels at 128x96).
#[test]
#[ignore = "since the supports are clipped at occluders (issue 61) one exact pixel, (64, 88) of 128x96, is darker than a quarter of its neighbourhood and the reference's is not; not understood yet"]
fn cornell_solution_at_the_default_point_count_has_no_dark_blotch() {
    let opts = BakeOptions {
        receiver_levels: Some(3),
        gather_rays: Some(64),
        ..Default::default()
    };
    // Three levels and 64 rays make a coarser flat basis than the default bake's.
    check_cornell("small-default-count", opts, 128, 96, true, 0.04);
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
