//! The `[scene]` options that change what a mesh is made of, for comparisons with renderers
//! that do not read everything the source holds: `textures = false` keeps each material's
//! constant colour (MTL `Kd`, glTF base colour factor) and ignores its texture map (MTL
//! `map_Kd`, glTF base colour texture); `normals = "face"` shades with each triangle's
//! geometric normal instead of the mesh's vertex normals. `subdivide = N` splits every triangle
//! into four by its edge midpoints, N times (`4^N` times the triangles, the same surface,
//! materials and shading: [`crate::subdivide`]), for measuring how costs grow with the triangle
//! count. `albedo_max = A` scales every material's colour and every texel by one factor so that
//! the largest albedo channel anywhere in the mesh is `A` (stiff cases: a bright room whose
//! interreflections converge slowly). All default to the source as it is. They are part of the scene's identity:
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
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneOptions {
    /// Whether texture maps modulate the materials' colours.
    pub textures: bool,
    pub normals: NormalSource,
    /// Levels of 1-to-4 midpoint subdivision applied to the mesh (0: none).
    pub subdivide: u32,
    /// The largest albedo channel after scaling every albedo by one factor (`None`: as loaded).
    pub albedo_max: Option<f32>,
}

impl Default for SceneOptions {
    fn default() -> Self {
        SceneOptions {
            textures: true,
            normals: NormalSource::Vertex,
            subdivide: 0,
            albedo_max: None,
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
        if let Some(target) = self.albedo_max {
            scale_albedo(mesh, target);
        }
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
        if let Some(a) = self.albedo_max {
            hasher.update(format!("scene.albedo_max={:08x}", a.to_bits()).as_bytes());
        }
    }
}

/// The largest albedo channel of `mesh`: over the materials' colours, each times the largest
/// texel of its texture when it has one.
pub fn largest_albedo(mesh: &Mesh) -> f32 {
    let texel_max = |t: u32| {
        mesh.textures.get(t as usize).map_or(1.0, |tex| {
            tex.texels().flatten().fold(0.0f32, |m, v| m.max(v))
        })
    };
    mesh.materials
        .iter()
        .map(|m| {
            let k = m.texture.map_or(1.0, texel_max);
            m.albedo.iter().fold(0.0f32, |a, &v| a.max(v * k))
        })
        .fold(0.0, f32::max)
}

/// Scales every material colour (and so every textured albedo) so that [`largest_albedo`]
/// becomes `target`; a mesh whose albedo is zero everywhere is left as it is.
fn scale_albedo(mesh: &mut Mesh, target: f32) {
    let largest = largest_albedo(mesh);
    if largest > 0.0 {
        let f = target / largest;
        for m in &mut mesh.materials {
            m.albedo = m.albedo.map(|v| v * f);
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

    /// `albedo_max` scales every albedo by one factor, textured ones included, so that the
    /// largest channel is the target; it is part of the identity.
    #[test]
    fn albedo_max_scales_every_albedo_to_the_target() {
        let scene = crate::builtin::load_builtin("cornell").expect("loads");
        let crate::Geometry::Mesh(mut mesh) = scene.geometry else {
            panic!("the Cornell box is a mesh")
        };
        let before: Vec<[f32; 3]> = mesh.materials.iter().map(|m| m.albedo).collect();
        let largest = largest_albedo(&mesh);
        assert!(largest > 0.0 && largest < 0.95, "{largest}");
        let options = SceneOptions {
            albedo_max: Some(0.95),
            ..SceneOptions::default()
        };
        options.apply(&mut mesh);
        assert!((largest_albedo(&mesh) - 0.95).abs() < 1e-6);
        let f = 0.95 / largest;
        for (m, b) in mesh.materials.iter().zip(&before) {
            for (got, was) in m.albedo.iter().zip(b) {
                assert!((got - was * f).abs() < 1e-6);
            }
        }
        // A texture's largest texel counts: a material at 0.5 over texels up to 0.8 is 0.4.
        mesh.textures.push(
            crate::texture::Texture::from_linear(1, 2, vec![[0.8, 0.1, 0.1], [0.2, 0.2, 0.2]])
                .expect("valid 1x2 texture"),
        );
        mesh.materials = vec![crate::mesh::Material {
            name: "t".into(),
            albedo: [0.5, 0.5, 0.5],
            texture: Some(0),
        }];
        assert!((largest_albedo(&mesh) - 0.4).abs() < 1e-6);
        assert!(hash(options) != hash(SceneOptions::default()));
    }
}
