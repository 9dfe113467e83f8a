//! Opening what a subcommand looks at: a baked file, with the scene it was baked from and its
//! camera and light, or (for the reference) a scene on its own with the scene's camera and
//! light; the command-line overrides applied to both.

use std::path::Path;

use anyhow::{Context, Result};
use glam::Vec3;
use mlt_format::flat_basis::{FlatBasis, FlatRule};
use mlt_format::flat_section::StoredFlat;
use mlt_format::links::ArchivedLinks;
use mlt_format::meta::CameraInfo;
use mlt_format::{BakedFile, IndexedBasis, Meta};
use mlt_scenes::{RayCaster, Scene};
use mlt_view::{Camera, CpuRelighter, Light};

use crate::cmd::args::{BakedArgs, SceneArgs};

/// The scene with the camera and light to view it by.
pub struct Setting {
    pub scene: Scene,
    pub camera: Camera,
    pub light: Light,
}

/// A baked file opened for relighting, with its setting and the CPU relighter.
pub struct Viewing<'a> {
    pub path: &'a Path,
    pub meta: &'a Meta,
    pub ib: &'a IndexedBasis,
    pub scene: &'a Scene,
    pub caster: &'a dyn RayCaster,
    pub camera: Camera,
    pub light: Light,
    /// Sender levels of the transport operator.
    pub sender_levels: usize,
    pub relighter: CpuRelighter<'a>,
}

impl Viewing<'_> {
    /// The scene's bounding box as recorded in the file.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let s = &self.meta.scene;
        (Vec3::from(s.bounds_min), Vec3::from(s.bounds_max))
    }

    /// Radius of the light's circle in `--frames` runs: 5 % of the scene's diagonal.
    pub fn path_radius(&self) -> f32 {
        let (lo, hi) = self.bounds();
        0.05 * (hi - lo).length()
    }
}

/// Opens the baked file with its transport operator and links, loads its scene,
/// applies the overrides and hands the result to `f`.
pub fn with_viewing<T>(args: &BakedArgs, f: impl FnOnce(Viewing<'_>) -> Result<T>) -> Result<T> {
    let (path, relight) = (args.file.as_path(), &args.relight);
    let file = BakedFile::open(path).with_context(|| format!("opening {}", path.display()))?;
    let meta = file
        .meta()
        .with_context(|| format!("reading {}", path.display()))?;
    let ib = file
        .basis()
        .with_context(|| format!("reading {}", path.display()))?;
    let tm = file.transport_meta()?.with_context(|| {
        format!(
            "{}: no transport operator (baked with --basis-only?)",
            path.display()
        )
    })?;
    let link_bytes = file
        .links_bytes()?
        .with_context(|| format!("{}: no links section", path.display()))?;
    let links = file.access_links(&link_bytes)?;
    let setting = file_setting(path, &meta, &args.scene)?;
    let caster = setting.scene.build_caster();

    let sender_levels = tm.params.sender_levels as usize;
    let stored = match relight.flat_rule {
        Some(rule) => Some(flat_basis_by(&ib, links, rule)?),
        None => stored_flat_basis(&file, &ib, links)?,
    };
    let mut relighter = CpuRelighter::with_flat_basis(
        &ib,
        links,
        caster.as_ref(),
        sender_levels,
        relight.shadow_rays,
        stored,
    )
    .context("building the relighting operators")?;
    relighter
        .set_flat_normal_power(relight.flat_normal_power)
        .context("--flat-normal-power")?;
    relighter.adaptive_shadows = !relight.all_shadow_rays;
    relighter.support_average = !relight.point_samples;
    relighter.sharpen = !relight.no_sharpen;
    relighter.view_culling = !relight.no_view_culling;
    relighter
        .set_sharpen_steps(relight.sharpen_steps)
        .context("--sharpen-steps")?;
    // Without the fine bounces (the paper's relighting) the feedback, which re-emits their
    // light, is left out too.
    if !relight.no_fine_bounces {
        let traced = file.bounce_method()?;
        relighter.use_bounce_corrections(&tm, traced.as_ref(), relight.bounce_feedback);
        relighter.fine_emission = relight.fine_emission.emission();
        relighter.lagged_feedback = relight.feedback_lag.lagged(false, relighter.lag_pays());
    }
    if relighter.support_average {
        relighter.build_support_tables();
    }
    if relighter.flatten_op().is_some() && !relighter.load_stats().points_in_morton_order {
        eprintln!(
            "note: {} stores its points in an older order; baking it again makes CPU flattening \
             faster (about 40 % on Sponza)",
            path.display()
        );
    }
    f(Viewing {
        path,
        meta: &meta,
        ib: &ib,
        scene: &setting.scene,
        caster: caster.as_ref(),
        camera: setting.camera,
        light: setting.light,
        sender_levels,
        relighter,
    })
}

/// The flat basis stored in `file` (`FLT2`, format 1.6), checked against its basis and links;
/// `None` (build it) for older files and for a section built by another rule than this
/// build's (a 1.5 file's `FLAT` section always is). A malformed or inconsistent section is an
/// error naming the file.
fn stored_flat_basis(
    file: &BakedFile,
    ib: &IndexedBasis,
    links: &ArchivedLinks,
) -> Result<Option<FlatBasis>> {
    let linked = links.linked_flags(ib.basis.len());
    Ok(match file.flat_basis(ib, &linked)? {
        StoredFlat::Stored(flat) => Some(*flat),
        StoredFlat::Absent => None,
        StoredFlat::OtherRule(rule) => {
            eprintln!(
                "note: {} stores a flat basis built by another rule ({rule:?}); building it \
                 by this build's rule",
                file.path().display()
            );
            None
        }
    })
}

/// The flat basis of `ib` for the receivers of `links` built by `rule`.
fn flat_basis_by(ib: &IndexedBasis, links: &ArchivedLinks, rule: FlatRule) -> Result<FlatBasis> {
    let linked = links.linked_flags(ib.basis.len());
    FlatBasis::build_with(ib, Some(&linked), rule).context("building the flat basis")
}

/// The setting of `input`: a baked `.mlt` file's (its scene, camera and light) or a scene
/// specification's (manifest, mesh or `builtin:` name, with its own camera and light).
/// `--scene` replaces the scene that is loaded, not the camera and light.
pub fn input_setting(input: &str, args: &SceneArgs) -> Result<Setting> {
    if input.ends_with(".mlt") {
        let path = Path::new(input);
        let file = BakedFile::open(path).with_context(|| format!("opening {input}"))?;
        let meta = file.meta().with_context(|| format!("reading {input}"))?;
        return file_setting(path, &meta, args);
    }
    let own =
        mlt_scenes::load_scene(input).with_context(|| format!("loading the scene {input}"))?;
    let light = scene_light(&own).context("the scene's light")?;
    let c = &own.camera;
    let camera = CameraInfo {
        position: c.position,
        target: c.target,
        up: c.up,
        fovy_deg: c.fovy_deg,
        width: c.width,
        height: c.height,
    };
    let scene = match &args.scene {
        Some(spec) => load_scene(spec)?,
        None => own,
    };
    Ok(Setting {
        scene,
        camera: camera_with(&camera, args)?,
        light: light_with(light, args)?,
    })
}

/// The setting of a baked file: the scene it records (or `--scene`), warning when the scene
/// has changed since the bake.
fn file_setting(path: &Path, meta: &Meta, args: &SceneArgs) -> Result<Setting> {
    let spec = args
        .scene
        .clone()
        .unwrap_or_else(|| meta.scene.source.clone());
    let scene = load_scene(&spec)?;
    if scene.content_hash != meta.scene.content_hash {
        eprintln!(
            "warning: {spec} has changed since {} was baked (content hash {:016x}, baked {:016x})",
            path.display(),
            scene.content_hash,
            meta.scene.content_hash
        );
    }
    let light = Light::from_info(&meta.light).context("the file's light")?;
    Ok(Setting {
        scene,
        camera: camera_with(&meta.camera, args)?,
        light: light_with(light, args)?,
    })
}

fn load_scene(spec: &str) -> Result<Scene> {
    mlt_scenes::load_scene(spec)
        .with_context(|| format!("loading the scene {spec} (give --scene if it moved)"))
}

/// A scene's own light.
fn scene_light(scene: &Scene) -> Result<Light, mlt_relight::light::LightError> {
    Light::from_desc(&scene.light)
}

/// The camera `base` with the command line's overrides.
fn camera_with(base: &CameraInfo, args: &SceneArgs) -> Result<Camera> {
    Camera::new(
        args.camera_pos.unwrap_or(Vec3::from(base.position)),
        args.camera_target.unwrap_or(Vec3::from(base.target)),
        args.camera_up.unwrap_or(Vec3::from(base.up)),
        args.fovy.unwrap_or(base.fovy_deg),
        args.width.unwrap_or(base.width),
        args.height.unwrap_or(base.height),
    )
    .context("the camera (set it with --camera-pos, --camera-target, --camera-up, --fovy, --width, --height)")
}

/// The light `base` with the command line's overrides (position, intensity, spot cone), which
/// must be finite and non-negative too.
fn light_with(base: Light, args: &SceneArgs) -> Result<Light> {
    let mut light = base;
    if let Some(p) = args.light_pos {
        light.position = p;
    }
    if let Some(i) = args.light_intensity {
        light.intensity = i.to_array();
    }
    if let (Some(d), Some(c)) = (args.light_dir, args.cone_deg) {
        light = Light::spot(light.position, light.intensity, d, c, args.smooth)?;
    }
    Light::point(light.position, light.intensity)?;
    Ok(light)
}
