//! Light stays on its side of a thin wall: the built-in two rooms, sealed (`door=0`), with the
//! light in the left room and the camera in the right one. No path reaches the right room, so
//! its indirect light must be black in every pixel: in the GPU's splat, in the CPU's
//! evaluation of the flat basis at the same G-buffer points, and in the hierarchical
//! receivers' coefficients there. The bound is 1e-4 of the lit room's mean indirect light
//! (seen from a camera in that room), far below a visible change. Without the supports'
//! clipping (`--no-support-clip`) the same bake leaks well above it, so the test can fail.

mod common;

use common::{render, small};
use glam::Vec3;
use mlt_bake::BakeOptions;
use mlt_view::images::luminance;
use mlt_view::Camera;

fn options(clip: bool) -> BakeOptions {
    BakeOptions {
        receiver_levels: Some(4),
        coarse_count: Some(80),
        gather_rays: Some(64),
        no_support_clip: !clip,
        ..Default::default()
    }
}

/// The camera in the lit room, looking at the partition from the other side.
fn in_the_lit_room(c: &Camera) -> Camera {
    let mut c = *c;
    c.position = Vec3::new(-3.6, 1.4, 2.0);
    c.target = Vec3::new(0.0, 1.2, 2.0);
    c.width = 96;
    c.height = 54;
    c
}

fn mean_luminance(img: &mlt_view::images::RgbImage) -> f64 {
    img.pixels
        .iter()
        .map(|&p| f64::from(luminance(p)))
        .sum::<f64>()
        / img.pixels.len() as f64
}

/// (largest indirect pixel of the dark room, by the GPU; the same by the CPU's flat basis at
/// the G-buffer's points; the lit room's mean indirect light).
fn leak(clip: bool) -> (f64, f64, f64) {
    let spec = "builtin:rooms?door=0";
    let name = if clip { "clipped" } else { "unclipped" };
    let (lit, ..) = render(
        spec,
        options(clip),
        None,
        in_the_lit_room,
        &format!("{name}-lit"),
    );
    let (dark, g, flat_coeffs, bases, _) = render(
        spec,
        options(clip),
        None,
        small(96, 54),
        &format!("{name}-dark"),
    );
    let gpu_max = dark
        .indirect
        .pixels
        .iter()
        .fold(0.0f64, |m, &p| m.max(f64::from(luminance(p))));
    let mut cpu_max = 0.0f64;
    for (k, p) in g.position.iter().enumerate() {
        if p[3] == 0.0 {
            continue;
        }
        let n = g.normal[k];
        let mut v = [0.0f32; 9];
        bases
            .flat
            .reconstruct(&flat_coeffs, 9, [p[0], p[1], p[2]], n, &mut v);
        for c in 0..3 {
            let e = v[3 * c] * n[0] + v[3 * c + 1] * n[1] + v[3 * c + 2] * n[2];
            // Radiance, as the image holds: rho E / pi.
            let radiance = f64::from(e.abs()) * f64::from(g.albedo[k][c]) / std::f64::consts::PI;
            cpu_max = cpu_max.max(radiance);
        }
    }
    (gpu_max, cpu_max, mean_luminance(&lit.indirect))
}

#[test]
fn a_sealed_room_behind_a_thin_wall_stays_black() {
    let (gpu, cpu, lit) = leak(true);
    assert!(lit > 0.0, "the lit room is lit");
    assert!(
        gpu <= 1e-4 * lit && cpu <= 1e-4 * lit,
        "the dark room's indirect light reaches {gpu:.3e} (GPU), {cpu:.3e} (CPU) against the lit room's mean {lit:.3e}"
    );
    let (gpu, _, lit) = leak(false);
    assert!(
        gpu > 1e-2 * lit,
        "unclipped supports leak: {gpu:.3e} against {lit:.3e}"
    );
}
