//! What the view crate's test files share. (Each test file compiles this module on its own and
//! uses part of it, hence the allowance.)
#![allow(dead_code, unused_imports)]

use std::path::Path;

use mlt_bake::{bake_scene, BakeOptions, Silent};
use mlt_format::{BakedFile, WriteOptions};
use mlt_view::gpu::mesh::GpuMesh;
use mlt_view::gpu::{Buffers, GBuffer, Gpu, Renderer};
use mlt_view::{Camera, CpuRelighter, Light, Relight};

pub use mlt_test_support::{shared_scenes, TempDir};

/// Bakes the scene `spec` with `opts` into `path`.
pub fn bake_to(path: &Path, spec: &str, opts: BakeOptions) {
    let scene = mlt_scenes::load_scene(spec).unwrap();
    let out = bake_scene(&scene, &opts, &Silent).unwrap();
    mlt_format::file::write(path, &out.contents, WriteOptions::default()).unwrap();
}

/// Options of a small bake of the built-in Cornell box: `receiver_levels` levels over 40
/// coarsest points, `gather_rays` rays per gather, `bounces` (`None`: the default).
pub fn small_cornell(receiver_levels: u32, gather_rays: u32, bounces: Option<u32>) -> BakeOptions {
    BakeOptions {
        receiver_levels: Some(receiver_levels),
        coarse_count: Some(40),
        gather_rays: Some(gather_rays),
        bounces,
        ..Default::default()
    }
}

/// A fresh, empty directory for the test `name` of the test file `file`, removed on drop.
pub fn temp_dir(file: &str, name: &str) -> TempDir {
    TempDir::new(&format!("{file}-{name}"))
}

/// The headless GPU, or a panic saying what these tests need.
pub fn gpu() -> Gpu {
    Gpu::headless().unwrap_or_else(|e| {
        panic!("these tests need a Vulkan adapter (scripts/setup.sh installs Mesa's): {e}")
    })
}

/// A baked file relit once: its scene, bases and one relit frame.
pub struct Relit {
    pub meta: mlt_format::Meta,
    pub scene: mlt_scenes::Scene,
    pub caster: Box<dyn mlt_scenes::RayCaster>,
    pub hier: mlt_format::IndexedBasis,
    pub flat: mlt_format::flat_basis::FlatBasis,
    pub frame: mlt_view::Frame,
    pub light: Light,
}

/// Opens the baked file `path` of the scene `spec` and relights it with `light` applied to
/// the file's light (8 shadow rays per sender point).
pub fn relight_file(path: &Path, spec: &str, light: impl FnOnce(Light) -> Light) -> Relit {
    let file = BakedFile::open(path).unwrap();
    let meta = file.meta().unwrap();
    let hier = file.basis().unwrap();
    let tm = file.transport_meta().unwrap().unwrap();
    let lb = file.links_bytes().unwrap().unwrap();
    let links = file.access_links(&lb).unwrap();
    let scene = mlt_scenes::load_scene(spec).unwrap();
    let caster = scene.build_caster();
    let light = light(Light::from_info(&meta.light).unwrap());
    let mut relighter = CpuRelighter::new(
        &hier,
        links,
        caster.as_ref(),
        tm.params.sender_levels as usize,
        8,
    )
    .expect("relighting operators");
    // As the viewer does for this file (view/src/cmd/load.rs).
    relighter.use_bounce_corrections(&tm, None, None);
    let frame = relighter.relight(&light).clone();
    let flat = relighter.flat_basis().clone();
    drop(relighter);
    Relit {
        meta,
        scene,
        caster,
        hier,
        flat,
        frame,
        light,
    }
}

/// Bakes `spec`, relights it with `light` and renders it with `camera` (or the file's).
pub fn render(
    spec: &str,
    opts: BakeOptions,
    light: Option<Light>,
    camera: impl Fn(&Camera) -> Camera,
    name: &str,
) -> (Buffers, GBuffer, Vec<f32>, Bases, Light) {
    let d = temp_dir("render", name);
    let f = d.join("scene.mlt");
    bake_to(&f, spec, opts);
    let r = relight_file(&f, spec, |l| light.unwrap_or(l));
    let camera = camera(&Camera::from_info(&r.meta.camera).unwrap());
    let gpu = gpu();
    let mut renderer = Renderer::new(&gpu, &GpuMesh::from_scene(&r.scene), &r.flat, 512).unwrap();
    renderer.set_coefficients(&gpu, &r.frame.flat);
    renderer
        .render(&gpu, &r.flat.ib, &camera, &r.light, true)
        .unwrap();
    let buffers = renderer.read_buffers(&gpu).unwrap();
    let gbuffer = renderer.read_gbuffer(&gpu).unwrap();
    let bases = Bases {
        flat: r.flat,
        hier: r.hier,
        i: r.frame.i,
    };
    (buffers, gbuffer, r.frame.flat, bases, r.light)
}

/// The bases of a render: the flat one splatted and the hierarchical one with the receivers'
/// coefficients `i` it was flattened from.
pub struct Bases {
    pub flat: mlt_format::flat_basis::FlatBasis,
    pub hier: mlt_format::IndexedBasis,
    pub i: Vec<f32>,
}

/// The camera `c` at `w` x `h` pixels.
pub fn small(w: u32, h: u32) -> impl Fn(&Camera) -> Camera {
    move |c: &Camera| {
        let mut c = *c;
        c.width = w;
        c.height = h;
        c
    }
}
