//! The GPU relighter against the CPU one, stage by stage (on Mesa's software driver here and in
//! CI): the sender coefficients `e`, the receiver coefficients `i`, the fine bounces' emission
//! and the flat coefficients, for a moving light, exact and lagged, and the final image of two
//! views.
//!
//! Tolerances. The shadow rays follow the same pattern on both, through another hierarchy of
//! the same triangles, and the pull-push sums the same products in the same order (only fused
//! multiply-adds may differ): `e` within 1e-3 of the largest coefficient and 1e-4 relative RMS
//! (a ray grazing an edge may decide otherwise). In `S e` the CPU rounds each
//! sender's weight to half-float precision (a relative change of at most 2^-11, about 4.9e-4;
//! its mean over many senders is near zero) and skips senders below 1e-4 of the largest, which
//! the GPU does not, and sums each row in another order (64 partial sums): the receiver and flat
//! coefficients agree to 2e-3 of the largest entry-wise and 1e-3 in relative RMS over the whole
//! vector, several times the rounding's RMS (2^-11 / sqrt(3), 2.8e-4) and far below a visible
//! change; the final image within 1 % relative RMS, as the issue asks.

mod common;

use common::{bake_to, gpu, small, temp_dir};
use glam::Vec3;
use mlt_bake::BakeOptions;
use mlt_format::BakedFile;
use mlt_view::gpu::mesh::GpuMesh;
use mlt_view::gpu::{GpuArray, GpuRelighter, Renderer};
use mlt_view::{Camera, CpuRelighter, Light, Relight};

fn options() -> BakeOptions {
    BakeOptions {
        receiver_levels: Some(4),
        coarse_count: Some(60),
        gather_rays: Some(128),
        ..Default::default()
    }
}

/// Frame `k` of a light moving 4 cm per frame under the Cornell box's ceiling.
fn moving_light(k: usize) -> Light {
    let p = Vec3::new(0.3 + 0.04 * k as f32, 0.5, 0.3 - 0.02 * k as f32);
    Light::point(p, [0.3, 0.25, 0.2]).unwrap()
}

fn largest(v: &[f32]) -> f32 {
    v.iter().fold(0.0f32, |m, x| m.max(x.abs()))
}

fn rel_rms(a: &[f32], b: &[f32]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| f64::from(x - y).powi(2)).sum();
    let den: f64 = b.iter().map(|y| f64::from(*y).powi(2)).sum();
    (num / den).sqrt()
}

/// `gpu` within `entry` of `cpu`'s largest entry everywhere and `rms` in relative RMS.
fn assert_close(what: &str, gpu: &[f32], cpu: &[f32], entry: f32, rms: f64) {
    assert_eq!(gpu.len(), cpu.len(), "{what}: lengths");
    let scale = largest(cpu);
    assert!(scale > 0.0, "{what}: all zero");
    for (k, (g, c)) in gpu.iter().zip(cpu).enumerate() {
        assert!(
            (g - c).abs() <= entry * scale,
            "{what}: entry {k}: GPU {g} vs CPU {c} (largest {scale})"
        );
    }
    let r = rel_rms(gpu, cpu);
    assert!(r <= rms, "{what}: relative RMS {r}");
}

/// A bake of the built-in Cornell box, opened for relighting.
struct Cornell<'a> {
    file: &'a BakedFile,
    scene: &'a mlt_scenes::Scene,
    ib: &'a mlt_format::IndexedBasis,
    tm: &'a mlt_format::meta::TransportMeta,
    links: &'a mlt_format::links::ArchivedLinks,
    caster: &'a dyn mlt_scenes::RayCaster,
}

impl Cornell<'_> {
    /// A CPU relighter of the file, 4 shadow rays a sender point.
    fn relighter(&self) -> CpuRelighter<'_> {
        let levels = self.tm.params.sender_levels as usize;
        CpuRelighter::new(self.ib, self.links, self.caster, levels, 4).unwrap()
    }
}

/// Bakes the built-in Cornell box, opens it and runs `check` on it.
fn with_cornell(name: &str, check: impl FnOnce(&Cornell<'_>)) {
    let d = temp_dir("gpu_relight", name);
    let f = d.join("cornell.mlt");
    bake_to(&f, "builtin:cornell", options());
    let file = BakedFile::open(&f).unwrap();
    let scene = mlt_scenes::load_scene("builtin:cornell").unwrap();
    let ib = file.basis().unwrap();
    let tm = file.transport_meta().unwrap().unwrap();
    let lb = file.links_bytes().unwrap().unwrap();
    let links = file.access_links(&lb).unwrap();
    let caster = scene.build_caster();
    check(&Cornell {
        file: &file,
        scene: &scene,
        ib: &ib,
        tm: &tm,
        links,
        caster: caster.as_ref(),
    });
}

#[test]
fn every_stage_matches_the_cpu_relighter_for_a_moving_light_exact_and_lagged() {
    with_cornell("stages", |c| {
        let make = |lagged: bool| {
            let mut r = c.relighter();
            // The fine bounces from every sender point, whatever the file needs: both paths
            // then run every kernel.
            r.fine_bounces = true;
            r.lagged_feedback = lagged;
            r
        };
        let gpu = gpu();
        for lagged in [false, true] {
            let mut cpu = make(lagged);
            let source = make(lagged);
            let mut on_gpu = GpuRelighter::new(&gpu, &source, None).unwrap();
            on_gpu.timed = true;
            for k in 0..4 {
                let light = moving_light(k);
                let c = cpu.relight(&light).clone();
                let g = on_gpu.relight_on(&gpu, &light).unwrap().clone();
                assert!(
                    !g.reused && g.e.is_empty() && g.i.is_empty(),
                    "the arrays stay on the GPU"
                );
                assert!(
                    on_gpu.direct_on_gpu(),
                    "the box has triangles: its rays go on the GPU"
                );
                // Timed frames count the GPU's rays: the same rays, but for a penumbra decided
                // otherwise at a grazing edge.
                let (gr, cr) = (g.shadow_rays as f64, c.shadow_rays as f64);
                assert!(
                    cr > 0.0 && (gr - cr).abs() <= 0.01 * cr,
                    "rays {gr} against {cr}"
                );
                let what = |s: &str| format!("{s}, frame {k}, lagged {lagged}");
                let e = on_gpu.read(&gpu, GpuArray::Senders).unwrap();
                assert_close(&what("e"), &e, &c.e, 1e-3, 1e-4);
                let i = on_gpu.read(&gpu, GpuArray::Receivers).unwrap();
                assert_close(&what("i"), &i, &c.i, 2e-3, 1e-3);
                let flat = on_gpu.read(&gpu, GpuArray::Flat).unwrap();
                assert_close(&what("flat"), &flat, &c.flat, 2e-3, 1e-3);
                // The fine bounces add light at the finer receivers: without them `i` differs.
                let mut plain = make(false);
                plain.fine_bounces = false;
                let without = plain.relight(&light).i.clone();
                assert!(
                    rel_rms(&i, &without) > 1e-2,
                    "{}",
                    what("the fine bounces add nothing")
                );
            }
            // The same light again: reused once settled (the lagged path relights once more).
            let last = moving_light(3);
            let mut again = on_gpu.relight_on(&gpu, &last).unwrap().reused;
            if lagged {
                assert!(
                    !again,
                    "a lagged frame under a new light is relit once more"
                );
                again = on_gpu.relight_on(&gpu, &last).unwrap().reused;
            }
            assert!(again, "a settled frame is reused");
        }
        // Links split into buffers of 5,000 (as large scenes need): the same coefficients.
        let source = make(false);
        let mut whole = GpuRelighter::new(&gpu, &source, None).unwrap();
        let mut split = GpuRelighter::with_link_chunks(&gpu, &source, None, Some(5_000)).unwrap();
        whole.relight_on(&gpu, &moving_light(1)).unwrap();
        split.relight_on(&gpu, &moving_light(1)).unwrap();
        let (a, b) = (
            whole.read(&gpu, GpuArray::Receivers).unwrap(),
            split.read(&gpu, GpuArray::Receivers).unwrap(),
        );
        assert!(c.links.link_count() > 20_000, "too few links to split");
        assert_close("split links", &b, &a, 1e-6, 1e-6);
        // The lagged emission is the previous frame's bounce light: reading it after a frame
        // gives the emission of that frame's `i`, as the CPU's reconstruction computes it.
        let cpu = make(false);
        let source = make(true);
        let mut on_gpu = GpuRelighter::new(&gpu, &source, None).unwrap();
        on_gpu.relight_on(&gpu, &moving_light(0)).unwrap();
        let i = on_gpu.read(&gpu, GpuArray::Receivers).unwrap();
        let y = on_gpu.read(&gpu, GpuArray::Emission).unwrap();
        let want = cpu.feedback_op().emission(cpu.pull_push_op(), &i);
        assert_close("emission", &y, &want, 1e-5, 1e-5);
    });
}

#[test]
fn the_gpu_relighters_image_is_the_cpu_relighters_within_one_percent() {
    with_cornell("image", |c| {
        let make = || {
            let mut r = c.relighter();
            r.use_bounce_corrections(c.tm, c.file.bounce_method().unwrap().as_ref(), None);
            r
        };
        let gpu = gpu();
        let mut cpu = make();
        let flat = cpu.flat_basis().clone();
        let mesh = GpuMesh::from_scene(c.scene);
        let mut with_cpu = Renderer::new(&gpu, &mesh, &flat, 256).unwrap();
        let mut with_gpu = Renderer::new(&gpu, &mesh, &flat, 256).unwrap();
        let source = make();
        let mut on_gpu =
            GpuRelighter::new(&gpu, &source, Some(with_gpu.coefficient_buffer())).unwrap();
        let camera = small(160, 120)(&Camera::from_info(&c.file.meta().unwrap().camera).unwrap());
        // The camera turned 0.4 rad about its up axis.
        let mut turned = camera;
        turned.target = camera.position
            + glam::Quat::from_axis_angle(camera.up.normalize(), 0.4)
                * (camera.target - camera.position);
        for (k, cam) in [camera, turned].iter().enumerate() {
            let light = moving_light(2 * k);
            with_cpu.set_coefficients(&gpu, &cpu.relight(&light).flat);
            on_gpu.relight_on(&gpu, &light).unwrap();
            with_cpu.render(&gpu, &flat.ib, cam, &light, false).unwrap();
            with_gpu.render(&gpu, &flat.ib, cam, &light, false).unwrap();
            let a = with_cpu.read_buffers(&gpu).unwrap();
            let b = with_gpu.read_buffers(&gpu).unwrap();
            let px = |img: &mlt_view::RgbImage| {
                img.pixels.iter().flatten().copied().collect::<Vec<f32>>()
            };
            let r = rel_rms(&px(&b.final_), &px(&a.final_));
            assert!(r < 0.01, "view {k}: final image relative RMS {r}");
            let r = rel_rms(&px(&b.indirect), &px(&a.indirect));
            assert!(r < 0.01, "view {k}: indirect image relative RMS {r}");
            assert!(largest(&px(&b.indirect)) > 0.0);
        }
    });
}

/// `view render --relight gpu` and `--relight cpu` write the same images (within 1 %), and
/// `view timings --relight gpu` reports the GPU's stages.
#[test]
fn render_and_timings_run_the_gpu_relighter_from_the_command_line() {
    let d = temp_dir("gpu_relight", "cli");
    let f = d.join("cornell.mlt");
    bake_to(&f, "builtin:cornell", options());
    let view = || std::process::Command::new(env!("CARGO_BIN_EXE_view"));
    let render = |relight: &str| {
        let out = d.join(relight);
        let o = view()
            .arg("render")
            .arg(&f)
            .arg("--out")
            .arg(&out)
            .args([
                "--width",
                "96",
                "--height",
                "72",
                "--frames",
                "3",
                "--relight",
                relight,
            ])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let timings: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("timings.json")).unwrap()).unwrap();
        assert_eq!(timings["relight"], relight);
        mlt_view::RgbImage::read_exr(&out.join("final.exr")).unwrap()
    };
    let (gpu_img, cpu_img) = (render("gpu"), render("cpu"));
    let px = |img: &mlt_view::RgbImage| img.pixels.iter().flatten().copied().collect::<Vec<f32>>();
    let r = rel_rms(&px(&gpu_img), &px(&cpu_img));
    assert!(r < 0.01, "final images differ by {r} relative RMS");
    let o = view()
        .arg("timings")
        .arg(&f)
        .args(["--frames", "3", "--relight", "gpu"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(json["relight"], "gpu");
    assert!(json["median_ms"]["transport"].as_f64().unwrap() > 0.0);
}

/// A file whose level-0 bounces are chained (`--level0-paths 0`) needs the bounce-light
/// feedback, which the GPU relighter does not run: `--relight gpu` says so and writes nothing,
/// `--relight cpu` renders it.
#[test]
fn what_the_gpu_does_not_run_is_refused_by_name() {
    let d = temp_dir("gpu_relight", "chained");
    let f = d.join("chained.mlt");
    bake_to(
        &f,
        "builtin:cornell",
        BakeOptions {
            level0_paths: Some(0),
            ..options()
        },
    );
    let render = |relight: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_view"))
            .arg("render")
            .arg(&f)
            .arg("--out")
            .arg(d.join(relight))
            .args(["--width", "48", "--height", "36", "--relight", relight])
            .output()
            .unwrap()
    };
    let o = render("gpu");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("bounce-light feedback"),
        "{err}"
    );
    assert!(!d.join("gpu").join("final.exr").exists());
    let o = render("cpu");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}
