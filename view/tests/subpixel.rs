//! `view render --spp N`: the box filter over each pixel. The renderer's direct image of the
//! built-in Cornell box, sampled at the pixel centres and box-filtered over 4 and 16
//! sub-pixel positions, against the path-traced reference (which box-filters over the pixel
//! too): the filtered images are closer to it, and the gain is at the edges.

mod common;

use common::{bake_to, gpu, relight_file, temp_dir};
use mlt_bake::{BakeOptions, Preset};
use mlt_view::gpu::mesh::GpuMesh;
use mlt_view::gpu::{Buffers, Renderer};
use mlt_view::headless::box_filtered;
use mlt_view::images::{luminance, RgbImage};
use mlt_view::reference::{render_reference_with, ReferenceOptions};
use mlt_view::{Camera, Light};

const WIDTH: u32 = 64;
const HEIGHT: u32 = 48;

/// Root-mean-square luminance difference over the pixels `keep` selects.
fn rms(a: &RgbImage, b: &RgbImage, keep: &[bool]) -> f64 {
    let (mut sum, mut n) = (0.0f64, 0usize);
    for ((p, q), &k) in a.pixels.iter().zip(&b.pixels).zip(keep) {
        if k {
            sum += ((luminance(*p) - luminance(*q)) as f64).powi(2);
            n += 1;
        }
    }
    (sum / n.max(1) as f64).sqrt()
}

#[test]
fn box_filtered_direct_light_moves_toward_the_reference_at_edges() {
    let spec = "builtin:cornell";
    let d = temp_dir("subpixel", "cornell");
    let f = d.join("scene.mlt");
    let opts = BakeOptions {
        preset: Some(Preset::Paper),
        receiver_levels: Some(3),
        coarse_count: Some(40),
        gather_rays: Some(32),
        ..Default::default()
    };
    bake_to(&f, spec, opts);
    // A light in the middle of the box: no surface near it, so that the direct image has no
    // 1/d^2 hot spot whose sampling would drown the edges.
    let r = relight_file(&f, spec, |l| {
        Light::point(glam::Vec3::new(0.2, 0.42, 0.2), l.intensity).unwrap()
    });
    let (light, caster, ib) = (r.light, r.caster.as_ref(), &r.flat.ib);
    let mut camera = Camera::from_info(&r.meta.camera).unwrap();
    (camera.width, camera.height) = (WIDTH, HEIGHT);
    let gpu = gpu();
    let mut renderer = Renderer::new(&gpu, &GpuMesh::from_scene(&r.scene), &r.flat, 1024).unwrap();
    renderer.set_coefficients(&gpu, &r.frame.flat);
    renderer.render(&gpu, ib, &camera, &light, false).unwrap();
    let centres = renderer.read_buffers(&gpu).unwrap();
    let mut filtered =
        |spp| -> Buffers { box_filtered(&gpu, &mut renderer, ib, &camera, &light, spp).unwrap() };
    let one = filtered(1);
    let four = filtered(4);
    let sixteen = filtered(16);
    // One sample is the pixel-centre image, bit for bit.
    assert_eq!(one.direct, centres.direct);
    assert_eq!(one.final_, centres.final_);

    // The reference's direct light only (one bounce is enough: the indirect is not compared).
    let mut ro = ReferenceOptions::new(256, 1);
    ro.max_bounces = 1;
    let reference = render_reference_with(caster, &camera, &light, &ro).unwrap();
    // The reference's box filter: its direct light is noisy only at the edges.
    assert!(reference.direct_noise.rms > 0.0);

    // Edges: pixels where the centre sample and the 16-sample mean differ by more than 10 %
    // of the image's mean direct luminance (silhouettes and shadow boundaries).
    let mean = reference
        .direct
        .pixels
        .iter()
        .map(|p| luminance(*p) as f64)
        .sum::<f64>()
        / reference.direct.pixels.len() as f64;
    let edge: Vec<bool> = one
        .direct
        .pixels
        .iter()
        .zip(&sixteen.direct.pixels)
        .map(|(a, b)| ((luminance(*a) - luminance(*b)) as f64).abs() > 0.1 * mean)
        .collect();
    let edges = edge.iter().filter(|&&e| e).count();
    let all = vec![true; edge.len()];
    let (e1, e4, e16) = (
        rms(&one.direct, &reference.direct, &edge),
        rms(&four.direct, &reference.direct, &edge),
        rms(&sixteen.direct, &reference.direct, &edge),
    );
    let (a1, a16) = (
        rms(&one.direct, &reference.direct, &all),
        rms(&sixteen.direct, &reference.direct, &all),
    );
    eprintln!(
        "{edges} edge pixels of {}: direct RMSE against the reference over edges {e1:.4} (1 spp), {e4:.4} (4), {e16:.4} (16); over all pixels {a1:.4} -> {a16:.4}; mean {mean:.4}",
        edge.len()
    );
    assert!(edges > 50, "only {edges} edge pixels");
    assert!(e4 < 0.75 * e1, "4 spp: {e4} vs {e1}");
    assert!(e16 < e4, "16 spp: {e16} vs {e4}");
    assert!(a16 < 0.75 * a1, "all pixels: {a16} vs {a1}");
}
