//! The bake's check of its light at the scene's camera (`TCAM`) against the reference path
//! tracer through the same camera: the check's traced figures are the image's mean
//! first-bounce and whole indirect radiance times `π` (albedo-weighted, a miss counting
//! zero), which is what `view reference --max-bounces 1` and `view reference` render,
//! averaged over their pixels.

mod common;

use common::bake_to;
use mlt_format::BakedFile;
use mlt_view::reference::{render_reference_with, ReferenceOptions};
use mlt_view::{Camera, Light};

#[test]
fn the_camera_check_traces_what_the_reference_renders_through_the_camera() {
    let d = common::temp_dir("camera_check", "cornell");
    let f = d.join("cornell.mlt");
    let spec = "builtin:cornell";
    bake_to(&f, spec, common::small_cornell(3, 16, Some(1)));
    let file = BakedFile::open(&f).unwrap();
    let meta = file.meta().unwrap();
    let check = file
        .camera_check()
        .unwrap()
        .expect("the bake checks its first bounce at the camera");
    assert!(check.cells_hit > 0 && check.std_error > 0.0);
    // Its blocks (`TCBK`): the camera's 160-cell grid in 16-cell blocks, the worst among the
    // lit ones and within their range.
    let blocks = file.camera_blocks().unwrap().expect("the check by blocks");
    assert_eq!(
        (blocks.block, blocks.columns),
        (16, check.width.div_ceil(16))
    );
    assert!(blocks.lit > 0 && blocks.lit <= blocks.columns * blocks.rows);
    assert!(blocks.ratio_min <= blocks.worst_ratio && blocks.worst_ratio <= blocks.ratio_max);
    assert!(blocks.worst_std_error > 0.0);
    // The reference at a small image of the camera's aspect.
    let mut info = meta.camera.clone();
    let scale = 48.0 / info.width.max(info.height) as f32;
    info.width = ((info.width as f32 * scale).round() as u32).max(1);
    info.height = ((info.height as f32 * scale).round() as u32).max(1);
    let camera = Camera::from_info(&info).unwrap();
    let light = Light::from_info(&meta.light).unwrap();
    let caster = mlt_scenes::load_scene(spec).unwrap().build_caster();
    let luma = [0.2126, 0.7152, 0.0722];
    let y = |v: &[f64; 3]| (0..3).map(|c| luma[c] * v[c]).sum::<f64>();
    // The first bounce alone, then every bounce (the reference's default path length).
    for (max_bounces, traced) in [(1, &check.traced), (1024, &check.traced_all)] {
        let opts = ReferenceOptions {
            max_bounces,
            ..ReferenceOptions::new(64, 7)
        };
        let r = render_reference_with(caster.as_ref(), &camera, &light, &opts).unwrap();
        let n = r.indirect.pixels.len() as f64;
        let reference: f64 = r
            .indirect
            .pixels
            .iter()
            .map(|p| y(&p.map(f64::from)))
            .sum::<f64>()
            / n;
        let traced = y(traced) / std::f64::consts::PI;
        let ratio = traced / reference;
        assert!(
            (ratio - 1.0).abs() < 0.03,
            "bounces up to {max_bounces}: the check's traced light {traced} against the reference's {reference} (ratio {ratio})"
        );
    }
}
