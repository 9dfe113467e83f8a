//! Scene manifests (TOML): what to load and the defaults stored with it.
//!
//! ```toml
//! [scene]
//! source = "../../shared/scenes/cornell_box/CornellBox-Original.obj" # relative to this file, or builtin:NAME
//! scale = 1.0
//! viewpoint = [0.0, 1.0, 0.5]     # one interior point the point placement starts from
//! textures = true                 # false: constant material colours, no texture maps
//! normals = "vertex"              # or "face": geometric normals, not the mesh's
//! subdivide = 0                   # N: split every triangle into 4 by its edge midpoints, N times
//! albedo_max = 0.95                # optional: scale every albedo so that the largest channel is this
//!
//! [camera]
//! position = [0.0, 1.0, 3.5]
//! target = [0.0, 1.0, 0.0]
//! up = [0.0, 1.0, 0.0]
//! fovy_deg = 40.0
//! width = 640
//! height = 480
//!
//! [light]
//! kind = "point"                 # or "spot"
//! position = [0.0, 1.9, 0.0]
//! intensity = [1.0, 1.0, 1.0]    # RGB radiant intensity, W/sr
//! # direction = [0, -1, 0]; cone_deg = 60; falloff = "hard" | "smooth"  (spot only)
//!
//! [bake]                         # any bake parameter (mlt-bake's BakeOptions), as on its command line
//! receiver_levels = 6
//! coarse_count = 339             # or coarse_radius = 1.5
//! seed = 1
//! ```
//! Positions in `[camera]`, `[light]` and `viewpoint` are in the scene's own units *before*
//! `scale` is applied; the loader scales them with the geometry. Light intensities (W/sr)
//! are not scaled. Only `[scene]` and its `source` are required; sections left out keep the
//! source's defaults (a built-in's own, or the guesses of [`scene_from_mesh_file`]). Unknown
//! keys are errors (those of `[bake]` when the bake reads the table), as are non-finite numbers
//! and unusable lights or cameras.

use std::path::{Path, PathBuf};

use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::error::SceneError;
use crate::mesh::Mesh;
use crate::obj::warn;
use crate::scene::{Geometry, Scene};
use crate::scene_options::{NormalSource, SceneOptions};

/// Default camera: right-handed, +Y up, vertical field of view in degrees.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraDesc {
    pub position: [f32; 3],
    pub target: [f32; 3],
    #[serde(default = "default_up")]
    pub up: [f32; 3],
    #[serde(default = "default_fovy")]
    pub fovy_deg: f32,
    #[serde(default = "default_width")]
    pub width: u32,
    #[serde(default = "default_height")]
    pub height: u32,
}

fn default_up() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}
fn default_fovy() -> f32 {
    45.0
}
fn default_width() -> u32 {
    640
}
fn default_height() -> u32 {
    480
}

/// The default light's description: the one type from the manifest to the file.
pub use mlt_format::light::{LightDesc, LightKind, SpotFalloff};

/// The manifest file as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ManifestFile {
    scene: SceneSection,
    camera: Option<CameraDesc>,
    light: Option<LightDesc>,
    /// Left unparsed: the bake reads it (see [`Scene::bake`]).
    bake: Option<toml::Table>,
}

/// `[scene]`: what to load.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneSection {
    /// `builtin:NAME?...` or a mesh path relative to the manifest's directory.
    source: String,
    #[serde(default = "default_scale")]
    scale: f32,
    viewpoint: Option<[f32; 3]>,
    /// See [`SceneOptions`].
    #[serde(default = "default_textures")]
    textures: bool,
    #[serde(default)]
    normals: NormalSource,
    #[serde(default)]
    subdivide: u32,
    albedo_max: Option<f32>,
}

fn default_scale() -> f32 {
    1.0
}
fn default_textures() -> bool {
    true
}

/// Loads a scene manifest (see the module docs). The content hash covers the manifest's
/// bytes, everything its source was built from, and the [`SceneOptions`].
pub fn load_manifest(path: &Path) -> Result<Scene, SceneError> {
    let bytes = std::fs::read(path).map_err(|e| SceneError::io(path, e))?;
    let manifest_error = |message: String| SceneError::Manifest {
        path: path.to_path_buf(),
        message,
    };
    let text =
        std::str::from_utf8(&bytes).map_err(|e| manifest_error(format!("not UTF-8: {e}")))?;
    let file: ManifestFile = toml::from_str(text).map_err(|e| manifest_error(e.to_string()))?;

    let scale = file.scene.scale;
    if !scale.is_finite() || scale <= 0.0 {
        return Err(manifest_error(format!(
            "[scene] scale must be finite and > 0, got {scale}"
        )));
    }
    let mut scene = if let Some(rest) = file.scene.source.strip_prefix("builtin:") {
        let mut scene = crate::builtin::load_builtin(rest)?;
        if scale != 1.0 {
            scale_scene(&mut scene, scale);
        }
        scene
    } else {
        let dir = path.parent().unwrap_or(Path::new(""));
        let mesh_path: PathBuf = dir.join(&file.scene.source);
        scene_from_mesh_file(&mesh_path, scale)?
    };

    // Overrides from the manifest, in source units, then scaled.
    let mut explicit_viewpoint = false;
    if let Some(v) = file.scene.viewpoint {
        check_finite(path, "[scene] viewpoint", &v)?;
        scene.viewpoint = Vec3::from(v) * scale;
        explicit_viewpoint = true;
    }
    if let Some(mut camera) = file.camera {
        check_camera(path, &camera)?;
        camera.position = (Vec3::from(camera.position) * scale).to_array();
        camera.target = (Vec3::from(camera.target) * scale).to_array();
        scene.camera = camera;
    }
    if let Some(mut light) = file.light {
        check_light(path, &light, &mut scene.warnings)?;
        light.position = (Vec3::from(light.position) * scale).to_array();
        scene.light = light;
    }
    if let Some(bake) = file.bake {
        check_bake_table(path, &bake)?;
        scene.bake = bake;
    }
    if explicit_viewpoint {
        // The guess is replaced: drop its warning.
        scene
            .warnings
            .retain(|w| !w.contains("viewpoint is a guess"));
    }

    let options = SceneOptions {
        textures: file.scene.textures,
        normals: file.scene.normals,
        subdivide: file.scene.subdivide,
        albedo_max: file.scene.albedo_max,
    };
    if let Some(a) = options.albedo_max {
        if !(a > 0.0 && a < 1.0) {
            return Err(manifest_error(format!(
                "[scene] albedo_max must be in (0, 1) (energy must be lost at each bounce), got {a}"
            )));
        }
    }
    if options.subdivide > crate::subdivide::MAX_LEVELS {
        return Err(manifest_error(format!(
            "[scene] subdivide = {} is more than {} (each level multiplies the triangles by 4)",
            options.subdivide,
            crate::subdivide::MAX_LEVELS
        )));
    }
    if let Geometry::Mesh(mesh) = &mut scene.geometry {
        check_subdivided_size(path, mesh, options.subdivide)?;
        options.apply(mesh);
    }

    let mut hasher = xxhash_rust::xxh3::Xxh3::new();
    hasher.update(&bytes);
    hasher.update(&scene.content_hash.to_le_bytes());
    options.hash_into(&mut hasher);
    scene.content_hash = hasher.digest();
    scene.source = path.display().to_string();
    Ok(scene)
}

/// A subdivided mesh must keep its vertex indices in u32.
fn check_subdivided_size(path: &Path, mesh: &Mesh, levels: u32) -> Result<(), SceneError> {
    // Each level adds at most three vertices per triangle and multiplies the triangles by 4.
    let mut triangles = mesh.triangles.len() as u64;
    let mut vertices = mesh.positions.len() as u64;
    for _ in 0..levels {
        vertices += 3 * triangles;
        triangles *= 4;
    }
    if vertices > u64::from(u32::MAX) {
        return Err(SceneError::Manifest {
            path: path.to_path_buf(),
            message: format!(
                "[scene] subdivide = {levels} makes {triangles} triangles, more vertices than 32-bit indices hold"
            ),
        });
    }
    Ok(())
}

/// Scales a loaded scene's geometry and positions (used for a built-in under a manifest
/// `scale`); intensities are left alone.
fn scale_scene(scene: &mut Scene, s: f32) {
    match &mut scene.geometry {
        Geometry::Mesh(m) => m.positions.iter_mut().for_each(|p| *p *= s),
        Geometry::Sphere { center, radius, .. } => {
            *center *= s;
            *radius *= s;
        }
    }
    scene.viewpoint *= s;
    scene.camera.position = (Vec3::from(scene.camera.position) * s).to_array();
    scene.camera.target = (Vec3::from(scene.camera.target) * s).to_array();
    scene.light.position = (Vec3::from(scene.light.position) * s).to_array();
    scene.scale *= s;
}

/// The `[bake]` table's numbers must be finite; its keys and types are the bake's to check.
fn check_bake_table(path: &Path, bake: &toml::Table) -> Result<(), SceneError> {
    for (key, value) in bake {
        if let toml::Value::Float(v) = value {
            if !v.is_finite() {
                return Err(SceneError::NonFinite {
                    path: path.to_path_buf(),
                    what: format!("[bake] {key}"),
                });
            }
        }
    }
    Ok(())
}

fn check_finite(path: &Path, what: &str, values: &[f32]) -> Result<(), SceneError> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(SceneError::NonFinite {
            path: path.to_path_buf(),
            what: what.to_string(),
        })
    }
}

fn check_camera(path: &Path, c: &CameraDesc) -> Result<(), SceneError> {
    check_finite(path, "[camera] position", &c.position)?;
    check_finite(path, "[camera] target", &c.target)?;
    check_finite(path, "[camera] up", &c.up)?;
    check_finite(path, "[camera] fovy_deg", &[c.fovy_deg])?;
    let bad = |message: String| SceneError::Manifest {
        path: path.to_path_buf(),
        message: format!("[camera] {message}"),
    };
    if !(c.fovy_deg > 0.0 && c.fovy_deg < 180.0) {
        return Err(bad(format!(
            "fovy_deg = {} must be in (0, 180)",
            c.fovy_deg
        )));
    }
    if c.width == 0 || c.height == 0 {
        return Err(bad(format!(
            "size {}x{} must not be zero",
            c.width, c.height
        )));
    }
    let view = Vec3::from(c.target) - Vec3::from(c.position);
    if view.length_squared() == 0.0 {
        return Err(bad("position and target coincide".to_string()));
    }
    if view.cross(Vec3::from(c.up)).length_squared() == 0.0 {
        return Err(bad(
            "up is zero or parallel to the view direction".to_string()
        ));
    }
    Ok(())
}

fn check_light(path: &Path, l: &LightDesc, warnings: &mut Vec<String>) -> Result<(), SceneError> {
    check_finite(path, "[light] position", &l.position)?;
    check_finite(path, "[light] intensity", &l.intensity)?;
    let invalid = |message: String| SceneError::InvalidLight {
        path: path.to_path_buf(),
        message,
    };
    if l.intensity.iter().any(|&i| i < 0.0) {
        return Err(invalid(format!(
            "intensity {:?} must not be negative",
            l.intensity
        )));
    }
    if let Some(d) = l.direction {
        check_finite(path, "[light] direction", &d)?;
    }
    if let Some(c) = l.cone_deg {
        check_finite(path, "[light] cone_deg", &[c])?;
    }
    match l.kind {
        LightKind::Spot => {
            let d = l
                .direction
                .ok_or_else(|| invalid("a spot light needs a direction".to_string()))?;
            if Vec3::from(d).length_squared() == 0.0 {
                return Err(invalid("spot direction is zero".to_string()));
            }
            let c = l
                .cone_deg
                .ok_or_else(|| invalid("a spot light needs cone_deg".to_string()))?;
            if !(c > 0.0 && c < 180.0) {
                return Err(invalid(format!("cone_deg = {c} must be in (0, 180)")));
            }
        }
        LightKind::Point => {
            if l.direction.is_some() || l.cone_deg.is_some() {
                warn(
                    warnings,
                    format!(
                        "{}: [light] direction/cone_deg are ignored for a point light",
                        path.display()
                    ),
                );
            }
        }
    }
    Ok(())
}

/// A scene from a bare mesh file (`.obj`, `.gltf`, `.glb`) with guessed defaults: the
/// viewpoint at the centre of the bounds (warned about: it may well be inside a wall), a
/// camera on +Z looking at the centre from far enough to frame the bounds, and a point light
/// at the centre of the bounds a little below the top, with intensity `h²` (irradiance ≈ 1
/// at the half-diagonal `h`).
pub fn scene_from_mesh_file(path: &Path, scale: f32) -> Result<Scene, SceneError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    let (mesh, mut warnings, content_hash) = match ext.as_str() {
        "obj" => crate::obj::load_obj(path, scale)?,
        "gltf" | "glb" => crate::gltf_scene::load_gltf(path, scale)?,
        _ => {
            return Err(SceneError::UnknownFormat {
                path: path.to_path_buf(),
            })
        }
    };
    let (lo, hi) = mesh.bounds();
    let centre = (lo + hi) * 0.5;
    let half_diagonal = ((hi - lo).length() * 0.5).max(f32::MIN_POSITIVE);
    let fovy_deg: f32 = 45.0;
    let distance = half_diagonal / (0.5 * fovy_deg.to_radians()).tan();
    let camera = CameraDesc {
        position: (centre + Vec3::Z * (hi.z - centre.z + distance)).to_array(),
        target: centre.to_array(),
        up: default_up(),
        fovy_deg,
        width: default_width(),
        height: default_height(),
    };
    let light_pos = Vec3::new(centre.x, hi.y - 0.05 * (hi.y - lo.y), centre.z);
    let intensity = half_diagonal * half_diagonal;
    warn(
        &mut warnings,
        format!(
            "{}: no manifest; the viewpoint is a guess (centre of the bounds, {centre}) and may lie inside geometry",
            path.display()
        ),
    );
    Ok(Scene {
        source: path.display().to_string(),
        content_hash,
        geometry: Geometry::Mesh(mesh),
        viewpoint: centre,
        camera,
        light: LightDesc {
            kind: LightKind::Point,
            position: light_pos.to_array(),
            intensity: [intensity; 3],
            direction: None,
            cone_deg: None,
            falloff: SpotFalloff::Hard,
        },
        bake: toml::Table::new(),
        scale,
        warnings,
    })
}
