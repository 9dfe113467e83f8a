//! glTF 2.0 (`.gltf` / `.glb`) loading through the gltf crate.
//!
//! The default scene (or, without one, every scene's root nodes) is flattened into one
//! world-space [`Mesh`]: node transforms are applied to positions, and their inverse
//! transpose to normals; mirroring transforms flip the winding back. Only triangle-list
//! primitives are used (others are skipped with a warning). The albedo is the base colour
//! factor (already linear) times the base colour texture (sRGB, decoded to linear);
//! primitives without a material get grey 0.5, like OBJ faces without one. Texture
//! coordinates are stored unchanged: glTF's `v = 0` is the top row, as in
//! [`crate::texture`].

use std::collections::HashMap;
use std::path::Path;

use glam::{Mat3, Mat4, Vec2, Vec3};
use xxhash_rust::xxh3::Xxh3;

use crate::error::SceneError;
use crate::mesh::{Material, Mesh, DEFAULT_ALBEDO};
use crate::obj::warn;
use crate::texture::{srgb_to_linear, Texture};

/// Deeper node hierarchies than this are treated as cyclic.
const MAX_NODE_DEPTH: usize = 256;

/// Loads a glTF or GLB file, scaling world positions by `scale`. Returns the mesh
/// (zero-area triangles dropped), the warnings, and the xxh3-64 hash of the file, its buffers
/// and its decoded images.
pub fn load_gltf(path: &Path, scale: f32) -> Result<(Mesh, Vec<String>, u64), SceneError> {
    let err = |message: String| SceneError::Gltf {
        path: path.to_path_buf(),
        message,
    };
    if !scale.is_finite() || scale <= 0.0 {
        return Err(err(format!(
            "scale must be finite and positive, got {scale}"
        )));
    }
    let bytes = std::fs::read(path).map_err(|e| SceneError::io(path, e))?;
    let mut hasher = Xxh3::new();
    hasher.update(&bytes);
    let gltf::Gltf { document, blob } = parse(&bytes).map_err(err)?;
    let base = path.parent().unwrap_or(Path::new(""));
    let buffers = gltf::import_buffers(&document, Some(base), blob)
        .map_err(|e| err(format!("buffers: {e}")))?;
    for b in &buffers {
        hasher.update(&b.0);
    }
    let mut warnings = Vec::new();

    let mut mesh = Mesh::default();
    let mut loader = Loader {
        path,
        base,
        buffers: &buffers,
        document: &document,
        mesh: &mut mesh,
        warnings: &mut warnings,
        hasher: &mut hasher,
        scale,
        material_index: HashMap::new(),
        image_texture: HashMap::new(),
        default_material: None,
        skipped_modes: 0,
    };
    let roots: Vec<gltf::Node> = match document.default_scene() {
        Some(scene) => scene.nodes().collect(),
        None => {
            if document.scenes().len() > 0 {
                document.scenes().flat_map(|s| s.nodes()).collect()
            } else {
                // No scenes at all: treat nodes that are nobody's child as roots.
                let children: std::collections::HashSet<usize> = document
                    .nodes()
                    .flat_map(|n| n.children().map(|c| c.index()))
                    .collect();
                document
                    .nodes()
                    .filter(|n| !children.contains(&n.index()))
                    .collect()
            }
        }
    };
    for node in roots {
        loader.visit(&node, Mat4::IDENTITY, 0)?;
    }
    if loader.skipped_modes > 0 {
        let n = loader.skipped_modes;
        warn(
            loader.warnings,
            format!(
                "{}: skipped {n} non-triangle primitives (points, lines, strips or fans)",
                path.display()
            ),
        );
    }

    mesh.finish(path, &mut warnings)?;
    Ok((mesh, warnings, hasher.digest()))
}

/// Traversal state while flattening the node hierarchy.
struct Loader<'a> {
    path: &'a Path,
    base: &'a Path,
    buffers: &'a [gltf::buffer::Data],
    document: &'a gltf::Document,
    mesh: &'a mut Mesh,
    warnings: &'a mut Vec<String>,
    hasher: &'a mut Xxh3,
    scale: f32,
    /// glTF material index → our material index.
    material_index: HashMap<usize, u32>,
    /// glTF image index → our texture index (`None`: failed to load, warned once).
    image_texture: HashMap<usize, Option<u32>>,
    default_material: Option<u32>,
    skipped_modes: usize,
}

impl Loader<'_> {
    fn error(&self, message: String) -> SceneError {
        SceneError::Gltf {
            path: self.path.to_path_buf(),
            message,
        }
    }

    fn visit(&mut self, node: &gltf::Node, parent: Mat4, depth: usize) -> Result<(), SceneError> {
        if depth > MAX_NODE_DEPTH {
            return Err(self.error(format!(
                "node {} is nested more than {MAX_NODE_DEPTH} deep (cyclic hierarchy?)",
                node.index()
            )));
        }
        let local = Mat4::from_cols_array_2d(&node.transform().matrix());
        if !local.is_finite() {
            return Err(SceneError::NonFinite {
                path: self.path.to_path_buf(),
                what: format!("node {} transform", node.index()),
            });
        }
        let world = parent * local;
        if let Some(m) = node.mesh() {
            for primitive in m.primitives() {
                self.add_primitive(&m, &primitive, world)?;
            }
        }
        for child in node.children() {
            self.visit(&child, world, depth + 1)?;
        }
        Ok(())
    }

    fn add_primitive(
        &mut self,
        m: &gltf::Mesh,
        primitive: &gltf::Primitive,
        world: Mat4,
    ) -> Result<(), SceneError> {
        if primitive.mode() != gltf::mesh::Mode::Triangles {
            self.skipped_modes += 1;
            return Ok(());
        }
        let (material, tex_coord) = self.material(&primitive.material());
        let buffers = self.buffers;
        let reader = primitive.reader(|b| buffers.get(b.index()).map(|d| d.0.as_slice()));
        let Some(positions) = reader.read_positions() else {
            warn(
                self.warnings,
                format!(
                    "{}: mesh {} primitive {} has no POSITION; skipped",
                    self.path.display(),
                    m.index(),
                    primitive.index()
                ),
            );
            return Ok(());
        };
        let base = self.mesh.positions.len();
        let mut count = 0usize;
        for (k, p) in positions.enumerate() {
            let local = Vec3::from(p);
            if !local.is_finite() {
                return Err(SceneError::NonFinite {
                    path: self.path.to_path_buf(),
                    what: format!(
                        "mesh {} primitive {} vertex {k} position",
                        m.index(),
                        primitive.index()
                    ),
                });
            }
            let p = world.transform_point3(local) * self.scale;
            if !p.is_finite() {
                return Err(SceneError::NonFinite {
                    path: self.path.to_path_buf(),
                    what: format!(
                        "mesh {} primitive {} vertex {k} position (after transform)",
                        m.index(),
                        primitive.index()
                    ),
                });
            }
            self.mesh.positions.push(p);
            count += 1;
        }

        // Normals: inverse transpose of the linear part. Missing ones are "absent" (zero).
        let linear = Mat3::from_mat4(world);
        let normal_matrix = linear.inverse().transpose();
        let source_normals: Vec<Vec3> = reader
            .read_normals()
            .map(|it| it.map(Vec3::from).collect())
            .unwrap_or_default();
        // A NaN or infinite normal is an error in the file, not an absent normal (a zero one is
        // absent: the face normal stands in with a warning).
        if let Some(k) = source_normals.iter().position(|n| !n.is_finite()) {
            return Err(SceneError::NonFinite {
                path: self.path.to_path_buf(),
                what: format!(
                    "mesh {} primitive {} vertex {k} normal",
                    m.index(),
                    primitive.index()
                ),
            });
        }
        let normals: Vec<Vec3> = source_normals
            .into_iter()
            .map(|n| normal_matrix * n)
            .collect();
        let normals_ok = normals.len() == count;
        if normals_ok && self.mesh.normals.is_empty() && base > 0 {
            self.mesh.normals.resize(base, Vec3::ZERO);
        }
        if normals_ok {
            self.mesh.normals.extend(normals);
        } else if !self.mesh.normals.is_empty() {
            self.mesh
                .normals
                .extend(std::iter::repeat_n(Vec3::ZERO, count));
        }

        let uvs: Vec<Vec2> = reader
            .read_tex_coords(tex_coord)
            .map(|it| it.into_f32().map(Vec2::from).collect())
            .unwrap_or_default();
        let uvs_ok = uvs.len() == count;
        if uvs_ok && self.mesh.uvs.is_empty() && base > 0 {
            self.mesh.uvs.resize(base, Vec2::ZERO);
        }
        if uvs_ok {
            if let Some(k) = uvs.iter().position(|uv| !uv.is_finite()) {
                return Err(SceneError::NonFinite {
                    path: self.path.to_path_buf(),
                    what: format!(
                        "mesh {} primitive {} vertex {k} texture coordinate",
                        m.index(),
                        primitive.index()
                    ),
                });
            }
            self.mesh.uvs.extend(uvs);
        } else if !self.mesh.uvs.is_empty() {
            self.mesh.uvs.extend(std::iter::repeat_n(Vec2::ZERO, count));
        }

        let indices: Vec<u32> = match reader.read_indices() {
            Some(it) => it.into_u32().collect(),
            None => (0..count as u32).collect(),
        };
        if !indices.chunks_exact(3).remainder().is_empty() {
            warn(
                self.warnings,
                format!(
                    "{}: mesh {} primitive {} has {} indices, not a multiple of 3; the rest is ignored",
                    self.path.display(),
                    m.index(),
                    primitive.index(),
                    indices.len()
                ),
            );
        }
        let mirrored = linear.determinant() < 0.0;
        for tri in indices.chunks_exact(3) {
            if let Some(&index) = tri.iter().find(|&&i| i as usize >= count) {
                return Err(SceneError::IndexOutOfRange {
                    path: self.path.to_path_buf(),
                    triangle: self.mesh.triangles.len(),
                    index,
                    vertex_count: count,
                });
            }
            let b = base as u32;
            let t = if mirrored {
                [b + tri[0], b + tri[2], b + tri[1]]
            } else {
                [b + tri[0], b + tri[1], b + tri[2]]
            };
            self.mesh.triangles.push(t);
            self.mesh.triangle_material.push(material);
        }
        Ok(())
    }

    /// Our material index for a glTF material (created on first use), and the texture
    /// coordinate set its base colour texture reads.
    fn material(&mut self, material: &gltf::Material) -> (u32, u32) {
        let Some(index) = material.index() else {
            let id = match self.default_material {
                Some(id) => id,
                None => {
                    warn(
                        self.warnings,
                        format!(
                            "{}: primitives without a material; using grey {}",
                            self.path.display(),
                            DEFAULT_ALBEDO[0]
                        ),
                    );
                    self.mesh
                        .materials
                        .push(Material::plain("(default grey)", DEFAULT_ALBEDO));
                    let id = (self.mesh.materials.len() - 1) as u32;
                    self.default_material = Some(id);
                    id
                }
            };
            return (id, 0);
        };
        let pbr = material.pbr_metallic_roughness();
        let info = pbr.base_color_texture();
        let tex_coord = info.as_ref().map_or(0, |i| i.tex_coord());
        if let Some(&id) = self.material_index.get(&index) {
            return (id, tex_coord);
        }
        let name = format!("material {index}");
        let texture = info.and_then(|i| self.texture(i.texture().source().index(), &name));
        let [r, g, b, _] = pbr.base_color_factor();
        self.mesh.materials.push(Material {
            name,
            albedo: [r, g, b],
            texture,
        });
        let id = (self.mesh.materials.len() - 1) as u32;
        self.material_index.insert(index, id);
        (id, tex_coord)
    }

    /// Loads glTF image `image` as a texture once; failures are warnings.
    fn texture(&mut self, image: usize, material: &str) -> Option<u32> {
        if let Some(&t) = self.image_texture.get(&image) {
            return t;
        }
        let result = self
            .document
            .images()
            .nth(image)
            .ok_or_else(|| format!("image {image} does not exist"))
            .and_then(|img| {
                gltf::image::Data::from_source(img.source(), Some(self.base), self.buffers)
                    .map_err(|e| e.to_string())
            })
            .and_then(|data| {
                self.hasher.update(&data.pixels);
                texture_from_gltf_image(&data)
            });
        let t = match result {
            Ok(t) => {
                self.mesh.textures.push(t);
                Some((self.mesh.textures.len() - 1) as u32)
            }
            Err(message) => {
                warn(
                    self.warnings,
                    format!(
                        "{}: base colour texture (image {image}) of material '{material}': {message}; using the factor alone",
                        self.path.display()
                    ),
                );
                None
            }
        };
        self.image_texture.insert(image, t);
        t
    }
}

/// Converts decoded glTF image data (sRGB-encoded base colour) to a linear texture.
/// Parses and validates a glTF or GLB image, refusing first what the gltf crate would panic
/// on (see [`check_accessors`] and [`check_glb_length`]).
fn parse(bytes: &[u8]) -> Result<gltf::Gltf, String> {
    check_glb_length(bytes)?;
    let gltf::Gltf { document, blob } =
        gltf::Gltf::from_slice_without_validation(bytes).map_err(|e| e.to_string())?;
    let json = document.into_json();
    check_accessors(&json)?;
    let document = gltf::Document::from_json(json).map_err(|e| e.to_string())?;
    Ok(gltf::Gltf { document, blob })
}

/// What the gltf crate's validation and readers assume without checking: every accessor (and
/// sparse part) holds at least one element, every primitive attribute names an existing
/// accessor (validation indexes the POSITION accessor unchecked), and the accessors read here
/// have the layout their readers assert: positions and normals VEC3 of floats, texture
/// coordinates VEC2 of floats or normalised bytes or shorts, indices SCALAR unsigned integers.
fn check_accessors(json: &gltf::json::Root) -> Result<(), String> {
    use gltf::json::accessor::{ComponentType as C, GenericComponentType, Type};
    use gltf::json::mesh::Semantic;
    use gltf::json::validation::Checked::Valid;

    for (a, acc) in json.accessors.iter().enumerate() {
        if acc.count.0 == 0 || acc.sparse.as_ref().is_some_and(|s| s.count.0 == 0) {
            return Err(format!("accessors[{a}]: count 0 (at least 1 is required)"));
        }
    }
    let layout = |i: usize, ty: Type, types: &[C]| {
        json.accessors.get(i).is_some_and(|a| {
            a.type_ == Valid(ty)
                && matches!(a.component_type, Valid(GenericComponentType(c)) if types.contains(&c))
        })
    };
    for (m, mesh) in json.meshes.iter().enumerate() {
        for (p, primitive) in mesh.primitives.iter().enumerate() {
            let fail = |what: String| Err(format!("meshes[{m}].primitives[{p}]: {what}"));
            for (semantic, i) in &primitive.attributes {
                let i = i.value();
                if i >= json.accessors.len() {
                    return fail(format!("attribute accessor {i} does not exist"));
                }
                let ok = match semantic {
                    Valid(Semantic::Positions | Semantic::Normals) => {
                        layout(i, Type::Vec3, &[C::F32])
                    }
                    Valid(Semantic::TexCoords(_)) => {
                        layout(i, Type::Vec2, &[C::F32, C::U8, C::U16])
                    }
                    _ => true,
                };
                if !ok {
                    return fail(format!(
                        "attribute {semantic:?} has an accessor of the wrong type"
                    ));
                }
            }
            if let Some(i) = primitive.indices {
                if !layout(i.value(), Type::Scalar, &[C::U8, C::U16, C::U32]) {
                    return fail("indices must be SCALAR unsigned integers".into());
                }
            }
        }
    }
    Ok(())
}

/// A binary glTF's header must state a length of at least the header's 12 bytes (the gltf
/// crate subtracts them unchecked, which panics on a shorter one).
fn check_glb_length(bytes: &[u8]) -> Result<(), String> {
    match (bytes.get(..4), bytes.get(8..12)) {
        (Some(b"glTF"), Some(len)) => {
            let len = u32::from_le_bytes([len[0], len[1], len[2], len[3]]);
            if len < 12 {
                return Err(format!(
                    "the GLB header states a length of {len} bytes, less than the header itself"
                ));
            }
            Ok(())
        }
        _ => Ok(()),
    }
}

fn texture_from_gltf_image(data: &gltf::image::Data) -> Result<Texture, String> {
    use gltf::image::Format as F;
    let (w, h) = (data.width, data.height);
    let bad = || format!("malformed {w}x{h} image data ({:?})", data.format);
    let (channels, bytes_per_channel) = match data.format {
        F::R8 => (1, 1),
        F::R8G8 => (2, 1),
        F::R8G8B8 => (3, 1),
        F::R8G8B8A8 => (4, 1),
        F::R16 => (1, 2),
        F::R16G16 => (2, 2),
        F::R16G16B16 => (3, 2),
        F::R16G16B16A16 => (4, 2),
        F::R32G32B32FLOAT => (3, 4),
        F::R32G32B32A32FLOAT => (4, 4),
    };
    if bytes_per_channel == 1 {
        return Texture::from_srgb8_channels(w, h, &data.pixels, channels).ok_or_else(bad);
    }
    let values: Vec<f32> = match bytes_per_channel {
        2 => data
            .pixels
            .chunks_exact(2)
            .map(|b| f32::from(u16::from_ne_bytes([b[0], b[1]])) / 65535.0)
            .collect(),
        _ => data
            .pixels
            .chunks_exact(4)
            .map(|b| f32::from_ne_bytes([b[0], b[1], b[2], b[3]]).clamp(0.0, 1.0))
            .collect(),
    };
    let texels = values
        .chunks_exact(channels)
        .map(|p| {
            let rgb = if channels < 3 {
                [p[0]; 3]
            } else {
                [p[0], p[1], p[2]]
            };
            rgb.map(srgb_to_linear)
        })
        .collect();
    Texture::from_linear(w, h, texels).ok_or_else(bad)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Minimal standard base64 encoder for building data URIs in tests.
    fn base64(data: &[u8]) -> String {
        const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut out = String::new();
        for chunk in data.chunks(3) {
            let b = [
                chunk[0],
                chunk.get(1).copied().unwrap_or(0),
                chunk.get(2).copied().unwrap_or(0),
            ];
            let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
            for k in 0..4 {
                if k <= chunk.len() {
                    out.push(A[((n >> (18 - 6 * k)) & 63) as usize] as char);
                } else {
                    out.push('=');
                }
            }
        }
        out
    }

    /// One triangle (positions + normals + u16 indices) under a translated, scaled parent
    /// node with a child node that mirrors x, plus a POINTS primitive to be skipped.
    fn write_test_gltf(dir: &Path) -> std::path::PathBuf {
        let buf = test_buffer();
        let uri = format!("data:application/octet-stream;base64,{}", base64(&buf));
        let json = test_json(&format!(r#""byteLength": {}, "uri": "{uri}""#, buf.len()));
        let path = dir.join("tri.gltf");
        std::fs::write(&path, json).expect("write gltf");
        path
    }

    /// The same asset as a binary .glb: a JSON chunk and a BIN chunk holding the buffer.
    fn write_test_glb(dir: &Path) -> std::path::PathBuf {
        let mut bin = test_buffer();
        let mut json = test_json(&format!(r#""byteLength": {}"#, bin.len())).into_bytes();
        while !json.len().is_multiple_of(4) {
            json.push(b' ');
        }
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        let total = 12 + 8 + json.len() + 8 + bin.len();
        let mut glb = Vec::with_capacity(total);
        glb.extend_from_slice(b"glTF");
        glb.extend_from_slice(&2u32.to_le_bytes());
        glb.extend_from_slice(&(total as u32).to_le_bytes());
        glb.extend_from_slice(&(json.len() as u32).to_le_bytes());
        glb.extend_from_slice(&0x4E4F_534Au32.to_le_bytes());
        glb.extend_from_slice(&json);
        glb.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        glb.extend_from_slice(&0x004E_4942u32.to_le_bytes());
        glb.extend_from_slice(&bin);
        let path = dir.join("tri.glb");
        std::fs::write(&path, glb).expect("write glb");
        path
    }

    fn test_buffer() -> Vec<u8> {
        let mut buf = Vec::new();
        for p in [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
            for c in p {
                buf.extend_from_slice(&c.to_le_bytes());
            }
        }
        for _ in 0..3 {
            for c in [0.0f32, 0.0, 1.0] {
                buf.extend_from_slice(&c.to_le_bytes());
            }
        }
        for i in [0u16, 1, 2] {
            buf.extend_from_slice(&i.to_le_bytes());
        }
        buf.extend_from_slice(&[0, 0]);
        buf
    }

    /// The asset's JSON with `buffer` as the fields of its one buffer.
    fn test_json(buffer: &str) -> String {
        format!(
            r#"{{
  "asset": {{"version": "2.0"}},
  "scene": 0,
  "scenes": [{{"nodes": [0]}}],
  "nodes": [
    {{"translation": [10, 0, 0], "scale": [2, 2, 2], "mesh": 0, "children": [1]}},
    {{"scale": [-1, 1, 1], "mesh": 0}}
  ],
  "materials": [{{"name": "red", "pbrMetallicRoughness": {{"baseColorFactor": [0.8, 0.1, 0.1, 1]}}}}],
  "meshes": [{{"primitives": [
    {{"attributes": {{"POSITION": 0, "NORMAL": 1}}, "indices": 2, "material": 0}},
    {{"attributes": {{"POSITION": 0}}, "mode": 0}}
  ]}}],
  "buffers": [{{{buffer}}}],
  "bufferViews": [
    {{"buffer": 0, "byteOffset": 0, "byteLength": 36}},
    {{"buffer": 0, "byteOffset": 36, "byteLength": 36}},
    {{"buffer": 0, "byteOffset": 72, "byteLength": 6}}
  ],
  "accessors": [
    {{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0,0,0], "max": [1,1,0]}},
    {{"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC3"}},
    {{"bufferView": 2, "componentType": 5123, "count": 3, "type": "SCALAR"}}
  ]
}}"#
        )
    }

    #[test]
    fn node_transforms_are_applied() {
        let dir = mlt_test_support::TempDir::new("gltf");
        let path = write_test_gltf(&dir);
        let (mesh, warnings, _) = load_gltf(&path, 0.5).expect("loads");
        assert_eq!(mesh.triangles.len(), 2);
        let scaled = |v: Vec3| v * 0.5;
        // Parent: translate (10,0,0) after scale 2.
        assert_eq!(
            mesh.corners(0),
            [
                scaled(Vec3::new(10.0, 0.0, 0.0)),
                scaled(Vec3::new(12.0, 0.0, 0.0)),
                scaled(Vec3::new(10.0, 2.0, 0.0)),
            ]
        );
        // Child mirrors x inside the parent; winding swapped back.
        assert_eq!(
            mesh.corners(1),
            [
                scaled(Vec3::new(10.0, 0.0, 0.0)),
                scaled(Vec3::new(10.0, 2.0, 0.0)),
                scaled(Vec3::new(8.0, 0.0, 0.0)),
            ]
        );
        // Normals are unit length after the scale; winding and normal still agree.
        for t in 0..2 {
            let [a, b, c] = mesh.corners(t);
            let face = (b - a).cross(c - a).normalize();
            let n = mesh.shading_normal(t, (0.3, 0.3)).expect("has normals");
            assert!((n.length() - 1.0).abs() < 1e-5);
            assert!(face.dot(n) > 0.99, "triangle {t}: face {face} normal {n}");
        }
        assert_eq!(mesh.albedo_at(0, (0.2, 0.2)), [0.8, 0.1, 0.1]);
        assert!(warnings.iter().any(|w| w.contains("non-triangle")));
    }

    #[test]
    fn glb_loads_like_gltf() {
        let dir = mlt_test_support::TempDir::new("glb");
        let (a, _, _) = load_gltf(&write_test_gltf(&dir), 1.0).expect("gltf loads");
        let (b, _, _) = load_gltf(&write_test_glb(&dir), 1.0).expect("glb loads");
        assert_eq!(a.triangles.len(), 2);
        assert_eq!(a.positions, b.positions);
        assert_eq!(a.triangles, b.triangles);
    }

    #[test]
    fn nan_in_buffers_is_rejected_naming_the_file_and_the_attribute() {
        let dir = mlt_test_support::TempDir::new("gltf-nan");
        // Byte offsets in test_buffer(): positions 0..36, normals 36..72.
        for (offset, value, what) in [
            (4usize, f32::NAN, "vertex 0 position"),
            (12, f32::INFINITY, "vertex 1 position"),
            (36 + 8, f32::NAN, "vertex 0 normal"),
            (36 + 12, f32::NEG_INFINITY, "vertex 1 normal"),
        ] {
            let mut buf = test_buffer();
            buf[offset..offset + 4].copy_from_slice(&value.to_le_bytes());
            let uri = format!("data:application/octet-stream;base64,{}", base64(&buf));
            let json = test_json(&format!(r#""byteLength": {}, "uri": "{uri}""#, buf.len()));
            let path = dir.join("nan.gltf");
            std::fs::write(&path, json).expect("write gltf");
            let e = load_gltf(&path, 1.0).unwrap_err();
            let msg = e.to_string();
            assert!(matches!(e, SceneError::NonFinite { .. }), "{msg}");
            assert!(msg.contains("nan.gltf") && msg.contains(what), "{msg}");
        }
        // A non-finite base colour cannot be written in JSON; an overflowing one is refused
        // by the parser, naming the file.
        let buf = test_buffer();
        let uri = format!("data:application/octet-stream;base64,{}", base64(&buf));
        let json = test_json(&format!(r#""byteLength": {}, "uri": "{uri}""#, buf.len()))
            .replace("[0.8, 0.1, 0.1, 1]", "[1e999, 0.1, 0.1, 1]");
        let path = dir.join("inf_colour.gltf");
        std::fs::write(&path, json).expect("write gltf");
        let e = load_gltf(&path, 1.0).unwrap_err().to_string();
        assert!(e.contains("inf_colour.gltf"), "{e}");
    }

    #[test]
    fn broken_gltf_names_the_file() {
        let dir = mlt_test_support::TempDir::new("gltf-bad");
        let path = dir.join("broken.gltf");
        std::fs::write(&path, "{ not json").expect("write");
        let e = load_gltf(&path, 1.0).unwrap_err().to_string();
        assert!(e.contains("broken.gltf"), "{e}");
        // A POSITION attribute naming a missing accessor.
        let path = write_test_gltf(&dir);
        let text = std::fs::read_to_string(&path).expect("read");
        std::fs::write(
            &path,
            text.replace("\"POSITION\": 0, \"NORMAL\"", "\"POSITION\": 9, \"NORMAL\""),
        )
        .expect("write");
        let e = load_gltf(&path, 1.0).unwrap_err().to_string();
        assert!(e.contains("accessor 9 does not exist"), "{e}");
        // A GLB header stating a length below its own 12 bytes.
        let glb = dir.join("short.glb");
        std::fs::write(&glb, b"glTF\x02\0\0\0\x04\0\0\0").expect("write");
        let e = load_gltf(&glb, 1.0).unwrap_err().to_string();
        assert!(e.contains("short.glb") && e.contains("length of 4"), "{e}");
    }

    #[test]
    fn sixteen_bit_images_are_decoded() {
        let data = gltf::image::Data {
            pixels: [u16::MAX, 0, 0]
                .iter()
                .flat_map(|v| v.to_ne_bytes())
                .collect(),
            format: gltf::image::Format::R16G16B16,
            width: 1,
            height: 1,
        };
        let t = texture_from_gltf_image(&data).expect("converts");
        assert_eq!(t.texels().collect::<Vec<_>>(), vec![[1.0, 0.0, 0.0]]);
    }
}
