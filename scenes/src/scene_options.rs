//! The `[scene]` options that change what a mesh is made of, for comparisons with renderers
//! that do not read everything the source holds: `textures = false` keeps each material's
//! constant colour (MTL `Kd`, glTF base colour factor) and ignores its texture map (MTL
//! `map_Kd`, glTF base colour texture); `normals = "face"` shades with each triangle's
//! geometric normal instead of the mesh's vertex normals. `subdivide = N` splits every triangle
//! into four by its edge midpoints, N times (`4^N` times the triangles, the same surface,
//! materials and shading: [`crate::subdivide`]), for measuring how costs grow with the triangle
//! count. All default to the source as it is. They are part of the scene's identity:
//! [`SceneOptions::hash_into`] adds them to the content hash (nothing is added for the
//! defaults, so a manifest without them keeps its hash).

use serde::Deserialize;

use crate::mesh::Mesh;

/// Where shading normals come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum NormalSource {
    /// The mesh's vertex normals, interpolated (the geometric normal where it has none).
    #[default]
    Vertex,
    /// Each triangle's geometric normal.
    Face,
}

/// The `[scene]` options applied to a loaded mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SceneOptions {
    /// Whether texture maps modulate the materials' colours.
    pub textures: bool,
    pub normals: NormalSource,
    /// Levels of 1-to-4 midpoint subdivision applied to the mesh (0: none).
    pub subdivide: u32,
}

impl Default for SceneOptions {
    fn default() -> Self {
        SceneOptions {
            textures: true,
            normals: NormalSource::Vertex,
            subdivide: 0,
        }
    }
}

impl SceneOptions {
    /// Applies the options to `mesh`: without textures every material keeps its constant
    /// colour and the mesh holds no texture; with face normals the mesh holds no vertex
    /// normals (triangles without them shade with their geometric normal); then every
    /// triangle is split `subdivide` times.
    pub fn apply(&self, mesh: &mut Mesh) {
        if !self.textures {
            mesh.materials.iter_mut().for_each(|m| m.texture = None);
            mesh.textures.clear();
        }
        if self.normals == NormalSource::Face {
            mesh.normals.clear();
        }
        crate::subdivide::subdivide(mesh, self.subdivide);
    }

    /// Adds the options that differ from the defaults to a content hash.
    pub fn hash_into(&self, hasher: &mut xxhash_rust::xxh3::Xxh3) {
        if !self.textures {
            hasher.update(b"scene.textures=false");
        }
        if self.normals == NormalSource::Face {
            hasher.update(b"scene.normals=face");
        }
        if self.subdivide != 0 {
            hasher.update(format!("scene.subdivide={}", self.subdivide).as_bytes());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hash(options: SceneOptions) -> u64 {
        let mut h = xxhash_rust::xxh3::Xxh3::new();
        options.hash_into(&mut h);
        h.digest()
    }

    /// The defaults add nothing to the content hash; every subdivision level is its own scene.
    #[test]
    fn subdivision_is_part_of_the_identity() {
        let empty = xxhash_rust::xxh3::Xxh3::new().digest();
        assert_eq!(hash(SceneOptions::default()), empty);
        let with = |subdivide| SceneOptions {
            subdivide,
            ..SceneOptions::default()
        };
        let (one, two) = (hash(with(1)), hash(with(2)));
        assert!(one != empty && two != empty && one != two);
    }
}
