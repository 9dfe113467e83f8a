//! Triangle meshes with per-material albedo and optional textures.

use std::path::Path;

use glam::{Vec2, Vec3};

use crate::error::SceneError;
use crate::texture::Texture;

/// The largest angle, in degrees, between a vertex normal and the face of a triangle that uses
/// it for the normal to shade that triangle ([`Mesh::drop_leaning_normals`]). Normals smoothed
/// across edges of up to about 120 degrees between faces (a cylinder of three facets) stay.
pub const MAX_NORMAL_LEAN_DEG: f32 = 60.0;

/// Albedo used where a face has no material (or the material library is missing).
pub const DEFAULT_ALBEDO: [f32; 3] = [0.5, 0.5, 0.5];

/// A Lambertian material: linear RGB albedo, optionally modulated by a texture.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    pub name: String,
    /// Linear RGB albedo (MTL `Kd`, glTF base colour factor).
    pub albedo: [f32; 3],
    /// Index into [`Mesh::textures`] of the diffuse texture (MTL `map_Kd`, glTF base colour
    /// texture), multiplied with `albedo` at hit points.
    pub texture: Option<u32>,
}

/// An indexed triangle mesh in world space (transforms and the manifest's scale applied).
///
/// Invariants established by the loaders (checked by [`Mesh::validate`]): every coordinate is
/// finite, every index is in range, no triangle has zero area (those are dropped and counted),
/// `normals` and `uvs` are empty or have one entry per position, and `triangle_material` has
/// one entry per triangle indexing `materials`.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    /// Per-vertex shading normals, or empty. Unit length where present, except at the
    /// midpoints [`crate::subdivide`] adds (the mean of two, which interpolates to the
    /// source's shading: users normalise after interpolating); a vertex whose source normal
    /// was zero or non-finite holds [`Vec3::ZERO`] ("absent"), and triangles touching it use
    /// the geometric normal.
    pub normals: Vec<Vec3>,
    /// Per-vertex texture coordinates, or empty, in the convention of
    /// [`Texture::sample`] (`v = 0` at the top row of the image; the OBJ loader flips `v`).
    pub uvs: Vec<Vec2>,
    pub triangles: Vec<[u32; 3]>,
    pub triangle_material: Vec<u32>,
    pub materials: Vec<Material>,
    pub textures: Vec<Texture>,
    /// Triangles dropped by the loader because they had zero area.
    pub degenerate_dropped: u64,
}

impl Material {
    /// A untextured material with the given albedo.
    pub fn plain(name: impl Into<String>, albedo: [f32; 3]) -> Material {
        Material {
            name: name.into(),
            albedo,
            texture: None,
        }
    }
}

impl Mesh {
    /// Checks the invariants documented on [`Mesh`]; `path` names the source in errors.
    pub fn validate(&self, path: &Path) -> Result<(), SceneError> {
        let invalid = |message: String| SceneError::InvalidMesh {
            path: path.to_path_buf(),
            message,
        };
        let non_finite = |what: String| SceneError::NonFinite {
            path: path.to_path_buf(),
            what,
        };
        if self.triangles.is_empty() {
            return Err(SceneError::NoTriangles {
                path: path.to_path_buf(),
            });
        }
        if let Some(i) = self.positions.iter().position(|p| !p.is_finite()) {
            return Err(non_finite(format!("vertex {i} position")));
        }
        if !self.normals.is_empty() {
            if self.normals.len() != self.positions.len() {
                return Err(invalid(format!(
                    "{} normals for {} vertices",
                    self.normals.len(),
                    self.positions.len()
                )));
            }
            if let Some(i) = self.normals.iter().position(|n| !n.is_finite()) {
                return Err(non_finite(format!("vertex {i} normal")));
            }
        }
        if !self.uvs.is_empty() {
            if self.uvs.len() != self.positions.len() {
                return Err(invalid(format!(
                    "{} texture coordinates for {} vertices",
                    self.uvs.len(),
                    self.positions.len()
                )));
            }
            if let Some(i) = self.uvs.iter().position(|uv| !uv.is_finite()) {
                return Err(non_finite(format!("vertex {i} texture coordinate")));
            }
        }
        let vertex_count = self.positions.len();
        for (t, tri) in self.triangles.iter().enumerate() {
            if let Some(&index) = tri.iter().find(|&&i| i as usize >= vertex_count) {
                return Err(SceneError::IndexOutOfRange {
                    path: path.to_path_buf(),
                    triangle: t,
                    index,
                    vertex_count,
                });
            }
        }
        if self.triangle_material.len() != self.triangles.len() {
            return Err(invalid(format!(
                "{} triangle materials for {} triangles",
                self.triangle_material.len(),
                self.triangles.len()
            )));
        }
        if let Some(t) = self
            .triangle_material
            .iter()
            .position(|&m| m as usize >= self.materials.len())
        {
            return Err(invalid(format!(
                "triangle {t} uses material {} of {}",
                self.triangle_material[t],
                self.materials.len()
            )));
        }
        for m in &self.materials {
            if m.albedo.iter().any(|c| !c.is_finite()) {
                return Err(non_finite(format!("material '{}' albedo", m.name)));
            }
            if m.albedo.iter().any(|&c| c < 0.0) {
                return Err(invalid(format!(
                    "material '{}' has a negative albedo {:?}",
                    m.name, m.albedo
                )));
            }
            if let Some(tex) = m.texture {
                if tex as usize >= self.textures.len() {
                    return Err(invalid(format!(
                        "material '{}' uses texture {tex} of {}",
                        m.name,
                        self.textures.len()
                    )));
                }
            }
        }
        Ok(())
    }

    /// Axis-aligned bounds (min, max) of the vertices used by triangles; zero when empty.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for tri in &self.triangles {
            for &i in tri {
                if let Some(&p) = self.positions.get(i as usize) {
                    lo = lo.min(p);
                    hi = hi.max(p);
                }
            }
        }
        if lo.cmple(hi).all() {
            (lo, hi)
        } else {
            (Vec3::ZERO, Vec3::ZERO)
        }
    }

    /// The three corner positions of triangle `tri`.
    pub fn corners(&self, tri: u32) -> [Vec3; 3] {
        let [a, b, c] = self.triangles[tri as usize];
        [
            self.positions[a as usize],
            self.positions[b as usize],
            self.positions[c as usize],
        ]
    }

    /// Linear RGB albedo of triangle `tri` at barycentric coordinates `bary = (u, v)`, the
    /// weights of the second and third corner (the first has `1 - u - v`): the material's
    /// albedo times its texture sampled at the interpolated UV.
    pub fn albedo_at(&self, tri: u32, bary: (f32, f32)) -> [f32; 3] {
        let material = self
            .triangle_material
            .get(tri as usize)
            .and_then(|&m| self.materials.get(m as usize));
        let Some(material) = material else {
            return DEFAULT_ALBEDO;
        };
        let mut albedo = material.albedo;
        let texture = material.texture.and_then(|t| self.textures.get(t as usize));
        if let (Some(texture), Some(tri)) = (texture, self.triangles.get(tri as usize)) {
            let uv = |i: u32| self.uvs.get(i as usize).copied();
            if let (Some(a), Some(b), Some(c)) = (uv(tri[0]), uv(tri[1]), uv(tri[2])) {
                let (u, v) = bary;
                let st = a * (1.0 - u - v) + b * u + c * v;
                let t = texture.sample(st);
                for k in 0..3 {
                    albedo[k] *= t[k];
                }
            }
        }
        albedo
    }

    /// Interpolated, renormalised vertex normal of triangle `tri` at `bary` (see
    /// [`Mesh::albedo_at`]), not oriented. `None` when the mesh has no normals, a corner's
    /// normal is absent, or the interpolation degenerates; callers then use the geometric
    /// normal.
    pub fn shading_normal(&self, tri: u32, bary: (f32, f32)) -> Option<Vec3> {
        let tri = self.triangles.get(tri as usize)?;
        let n = |i: u32| {
            self.normals
                .get(i as usize)
                .copied()
                .filter(|n| *n != Vec3::ZERO)
        };
        let (a, b, c) = (n(tri[0])?, n(tri[1])?, n(tri[2])?);
        let (u, v) = bary;
        let s = (a * (1.0 - u - v) + b * u + c * v).normalize_or_zero();
        (s != Vec3::ZERO && s.is_finite()).then_some(s)
    }

    /// The last step of every loader: sanitises normals (with a warning naming `path` when
    /// some were unusable: zero, non-finite, or leaning too far from a face that uses them),
    /// drops zero-area triangles and validates the result.
    pub fn finish(&mut self, path: &Path, warnings: &mut Vec<String>) -> Result<(), SceneError> {
        let absent = self.sanitize_normals();
        let leaning = self.drop_leaning_normals();
        let why = [
            (absent, "are zero or non-finite".to_string()),
            (
                leaning,
                format!("lean more than {MAX_NORMAL_LEAN_DEG} degrees from a face that uses them"),
            ),
        ];
        for (count, why) in why {
            if count > 0 {
                crate::obj::warn(
                    warnings,
                    format!(
                        "{}: {count} vertex normals {why}; those vertices use the face normal",
                        path.display()
                    ),
                );
            }
        }
        self.drop_degenerate_triangles(path);
        self.validate(path)
    }

    /// Renormalises the vertex normals; zero-length or non-finite ones become
    /// [`Vec3::ZERO`] ("absent"). Returns how many were absent.
    pub fn sanitize_normals(&mut self) -> usize {
        let mut absent = 0;
        for n in &mut self.normals {
            let u = n.normalize_or_zero();
            *n = if u.is_finite() { u } else { Vec3::ZERO };
            if *n == Vec3::ZERO {
                absent += 1;
            }
        }
        absent
    }

    /// Marks absent ([`Vec3::ZERO`]) every vertex normal that leans more than
    /// [`MAX_NORMAL_LEAN_DEG`] from the face of a triangle that uses it (either side of the
    /// face: a normal is turned to the geometric side where it is used). Such a normal is not a
    /// shading normal of that face: it comes from averaging across a sharp edge (the corner of
    /// a box whose walls, floor and roof share one vertex normal) and tilts the face's shading
    /// hemisphere nearly into its plane, so that the face shades almost black where it should
    /// be lit, and the smooth light a basis can hold cannot follow a normal that turns by 90
    /// degrees across one triangle. The triangles using it then shade with the face normal, as
    /// for a missing normal. Returns how many were marked.
    pub fn drop_leaning_normals(&mut self) -> usize {
        if self.normals.is_empty() {
            return 0;
        }
        let min_cos = MAX_NORMAL_LEAN_DEG.to_radians().cos();
        let mut leaning = vec![false; self.normals.len()];
        for tri in &self.triangles {
            let p = |i: u32| self.positions.get(i as usize).copied();
            let (Some(a), Some(b), Some(c)) = (p(tri[0]), p(tri[1]), p(tri[2])) else {
                continue;
            };
            let face = (b - a).cross(c - a).normalize_or_zero();
            if face == Vec3::ZERO || !face.is_finite() {
                continue;
            }
            for &i in tri {
                if let Some(n) = self.normals.get(i as usize) {
                    if *n != Vec3::ZERO && n.dot(face).abs() < min_cos {
                        leaning[i as usize] = true;
                    }
                }
            }
        }
        let mut count = 0;
        for (n, lean) in self.normals.iter_mut().zip(leaning) {
            if lean {
                *n = Vec3::ZERO;
                count += 1;
            }
        }
        count
    }

    /// Drops triangles of zero area (edge cross product exactly zero in f32, or a
    /// non-finite one), with their material entries; counts them in
    /// [`Mesh::degenerate_dropped`] and logs the count. Returns how many were dropped now.
    /// Call after all transforms and scaling. Triangles with out-of-range indices are kept
    /// for [`Mesh::validate`] to report.
    pub fn drop_degenerate_triangles(&mut self, source: &Path) -> u64 {
        let positions = &self.positions;
        let keep: Vec<bool> = self
            .triangles
            .iter()
            .map(|tri| {
                let p = |i: u32| positions.get(i as usize).copied();
                match (p(tri[0]), p(tri[1]), p(tri[2])) {
                    (Some(a), Some(b), Some(c)) => {
                        let n = (b - a).cross(c - a);
                        n != Vec3::ZERO && n.length_squared().is_finite()
                    }
                    _ => true,
                }
            })
            .collect();
        let dropped = keep.iter().filter(|k| !**k).count() as u64;
        if dropped == 0 {
            return 0;
        }
        let has_materials = self.triangle_material.len() == self.triangles.len();
        let mut i = 0;
        self.triangles.retain(|_| {
            i += 1;
            keep[i - 1]
        });
        if has_materials {
            let mut i = 0;
            self.triangle_material.retain(|_| {
                i += 1;
                keep[i - 1]
            });
        }
        self.degenerate_dropped += dropped;
        log::info!(
            "{}: dropped {dropped} zero-area triangles ({} left)",
            source.display(),
            self.triangles.len()
        );
        dropped
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn one_triangle() -> Mesh {
        Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            triangles: vec![[0, 1, 2]],
            triangle_material: vec![0],
            materials: vec![Material::plain("m", [0.2, 0.4, 0.6])],
            ..Default::default()
        }
    }

    #[test]
    fn validate_reports_bad_index_and_nan() {
        let path = Path::new("t.obj");
        let mut m = one_triangle();
        assert!(m.validate(path).is_ok());
        m.triangles[0][2] = 7;
        let e = m.validate(path).unwrap_err();
        assert!(
            matches!(e, SceneError::IndexOutOfRange { index: 7, .. }),
            "{e}"
        );
        let mut m = one_triangle();
        m.positions[1].y = f32::NAN;
        let e = m.validate(path).unwrap_err().to_string();
        assert!(e.contains("t.obj") && e.contains("vertex 1"), "{e}");
    }

    #[test]
    fn degenerate_triangles_are_dropped_with_materials() {
        let mut m = one_triangle();
        m.positions.push(Vec3::new(2.0, 0.0, 0.0));
        m.triangles.push([0, 1, 3]); // collinear
        m.triangles.push([1, 1, 2]); // coincident corners
        m.triangle_material.extend([0, 0]);
        assert_eq!(m.drop_degenerate_triangles(Path::new("t")), 2);
        assert_eq!(m.triangles, vec![[0, 1, 2]]);
        assert_eq!(m.triangle_material.len(), 1);
        assert_eq!(m.degenerate_dropped, 2);
    }

    #[test]
    fn normals_leaning_past_the_limit_from_a_face_are_dropped() {
        // A triangle in z = 0 (face normal +Z); each corner's normal leans a given angle from
        // +Z toward +X. Up to 60 degrees a normal stays (either side of the face: -Z leans 0),
        // beyond it the vertex uses the face normal, in every triangle that uses it.
        let lean = |deg: f32| {
            let r = deg.to_radians();
            Vec3::new(r.sin(), 0.0, r.cos())
        };
        let mut m = one_triangle();
        m.normals = vec![lean(59.0), -Vec3::Z, lean(61.0)];
        assert_eq!(m.drop_leaning_normals(), 1);
        assert_eq!(m.normals[0], lean(59.0));
        assert_eq!(m.normals[1], -Vec3::Z);
        assert_eq!(m.normals[2], Vec3::ZERO);
        assert_eq!(m.shading_normal(0, (0.2, 0.2)), None);
        // The corner of a box: one normal shared by two perpendicular faces leans 45 degrees
        // from each and stays; the normal of one face used by the other leans 90 and goes.
        let mut m = Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
            normals: vec![
                Vec3::new(0.0, 1.0, 1.0).normalize(),
                Vec3::Z,
                Vec3::Z,
                Vec3::Z,
            ],
            triangles: vec![[0, 1, 2], [0, 3, 1]],
            triangle_material: vec![0, 0],
            materials: vec![Material::plain("m", [0.5; 3])],
            ..Default::default()
        };
        assert_eq!(m.drop_leaning_normals(), 2);
        assert_ne!(m.normals[0], Vec3::ZERO);
        assert_eq!(m.normals[1], Vec3::ZERO, "+Z used by the face y = 0");
        assert_eq!(m.normals[2], Vec3::Z);
        assert_eq!(
            m.normals[3],
            Vec3::ZERO,
            "+Z at (0, 0, 1) lies in the face y = 0"
        );
    }

    #[test]
    fn shading_normal_needs_all_corners() {
        let mut m = one_triangle();
        assert_eq!(m.shading_normal(0, (0.2, 0.2)), None);
        m.normals = vec![Vec3::Z * 2.0, Vec3::Z, Vec3::ZERO];
        assert_eq!(m.sanitize_normals(), 1);
        assert_eq!(m.shading_normal(0, (0.2, 0.2)), None);
        m.normals[2] = Vec3::Z;
        assert_eq!(m.shading_normal(0, (0.2, 0.2)), Some(Vec3::Z));
        assert_eq!(m.albedo_at(0, (0.3, 0.3)), [0.2, 0.4, 0.6]);
    }
}
