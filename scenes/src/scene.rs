//! A loaded scene: geometry plus the defaults that travel with it.

use std::path::Path;

use glam::Vec3;

use crate::error::SceneError;
use crate::manifest::{CameraDesc, LightDesc};
use crate::mesh::Mesh;
use crate::raycast::RayCaster;

/// The geometry of a scene: a triangle mesh, or an analytic closed sphere (seen from inside).
#[derive(Clone, Debug)]
pub enum Geometry {
    Mesh(Mesh),
    Sphere {
        center: Vec3,
        radius: f32,
        albedo: [f32; 3],
    },
}

/// A scene ready for baking or viewing.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The specification it was loaded from, as given (path, `builtin:` name with parameters,
    /// or manifest path).
    pub source: String,
    /// xxh3-64 of every byte the scene was built from (mesh, material and texture files, and
    /// the manifest; for built-ins, the canonical name with its parameters).
    pub content_hash: u64,
    pub geometry: Geometry,
    /// The interior viewpoint from which point placement traces importance particles.
    pub viewpoint: Vec3,
    pub camera: CameraDesc,
    pub light: LightDesc,
    /// The manifest's `[bake]` table as written (empty for other scenes): bake parameters
    /// that the bake parses and checks, and that its command line overrides.
    pub bake: toml::Table,
    /// Scale applied to the source geometry (already applied to everything here).
    pub scale: f32,
    /// Human-readable warnings raised while loading (also sent to the `log` crate).
    pub warnings: Vec<String>,
}

impl Scene {
    /// Number of triangles (0 for analytic geometry).
    pub fn triangle_count(&self) -> u64 {
        match &self.geometry {
            Geometry::Mesh(m) => m.triangles.len() as u64,
            Geometry::Sphere { .. } => 0,
        }
    }

    /// Builds the ray caster for this scene's geometry (BVH build for meshes).
    pub fn build_caster(&self) -> Box<dyn RayCaster> {
        match &self.geometry {
            Geometry::Mesh(m) => Box::new(crate::mesh_caster::MeshCaster::new(m.clone())),
            Geometry::Sphere {
                center,
                radius,
                albedo,
            } => Box::new(crate::sphere_caster::SphereCaster::new(
                *center, *radius, *albedo,
            )),
        }
    }
}

/// Loads a scene from a specification: a `.toml` manifest, an `.obj`/`.gltf`/`.glb` path, or a
/// `builtin:NAME?key=value&...` name. Errors name the file and what is wrong with it.
pub fn load_scene(spec: &str) -> Result<Scene, SceneError> {
    if let Some(rest) = spec.strip_prefix("builtin:") {
        return crate::builtin::load_builtin(rest);
    }
    let path = Path::new(spec);
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "toml" => crate::manifest::load_manifest(path),
        "obj" | "gltf" | "glb" => crate::manifest::scene_from_mesh_file(path, 1.0),
        _ => Err(SceneError::UnknownFormat {
            path: path.to_path_buf(),
        }),
    }
}
