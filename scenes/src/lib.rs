//! Scene input and ray casting for the meshless hierarchical light transport tools.
//!
//! Everything `bake` and `view` need to know about geometry goes through this crate:
//! - [`load_scene`] turns a scene specification (an OBJ/glTF path, a `builtin:` name, or a TOML
//!   manifest) into a [`Scene`]: geometry plus the defaults stored with it (viewpoint, camera,
//!   light, bake parameters);
//! - [`RayCaster`] is the narrow interface of the paper's section 5.1: cast a ray and get a
//!   [`Hit`] (position, normals, albedo, primitive id), or test occlusion between two points.
//!   [`MeshCaster`] implements it over triangle meshes with an obvhs BVH, [`SphereCaster`]
//!   analytically for the closed sphere used in tests.

pub mod builtin;
pub mod error;
mod fsutil;
pub mod gltf_scene;
pub mod manifest;
pub mod mesh;
pub mod mesh_caster;
pub mod obj;
pub mod one_bounce;
pub mod raycast;
pub mod sampling;
pub mod scene;
pub mod scene_options;
pub mod sphere_caster;
pub mod subdivide;
pub mod texture;

pub use error::SceneError;
pub use manifest::{
    load_manifest, scene_from_mesh_file, CameraDesc, LightDesc, LightKind, SpotFalloff,
};
pub use mesh::{Material, Mesh};
pub use mesh_caster::MeshCaster;
pub use raycast::{Hit, RayCaster};
pub use scene::{load_scene, Geometry, Scene};
pub use scene_options::{NormalSource, SceneOptions};
pub use sphere_caster::SphereCaster;
pub use texture::Texture;
