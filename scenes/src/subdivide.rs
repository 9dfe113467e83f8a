//! Midpoint subdivision: every triangle split into four by its edge midpoints, repeatable
//! (`levels` splits give `4^levels` triangles per source triangle). The surface, materials and
//! shading are the source's: a midpoint lies on its edge (up to f32 rounding), its UV is the
//! mean of the edge's UVs (texture coordinates are linear over a triangle, so every point maps
//! to the texel it mapped to before) and its normal the mean of the edge's normals, not
//! renormalised, so that interpolating over a child and then normalising (what every shading
//! lookup does) gives the parent's shading normal (absent where either end's is absent). It
//! makes a scene of the same light transport with more triangles, for measuring how the cost
//! grows with the triangle count.
//!
//! Midpoints are shared by the triangles on both sides of an edge, and computed as
//! `(a + b) / 2`, which floating-point addition makes symmetric: two triangles that meet along
//! an edge (by index, or by equal positions under different indices) still meet, and no crack
//! opens that the source did not have.

use std::collections::HashMap;

use glam::{Vec2, Vec3};

use crate::mesh::Mesh;

/// The most levels a scene may ask for: each multiplies the triangles by 4.
pub const MAX_LEVELS: u32 = 6;

/// Splits every triangle of `mesh` into four, `levels` times. The four children of a triangle
/// `(a, b, c)` with midpoints `ab`, `bc`, `ca` are `(a, ab, ca)`, `(ab, b, bc)`, `(ca, bc, c)`
/// and `(ab, bc, ca)`, all wound as the parent, stored in the parent's order; each keeps the
/// parent's material.
pub fn subdivide(mesh: &mut Mesh, levels: u32) {
    for _ in 0..levels {
        split_once(mesh);
    }
}

/// The vertex arrays that grow with the new midpoints.
struct Attributes<'a> {
    positions: &'a mut Vec<Vec3>,
    normals: &'a mut Vec<Vec3>,
    uvs: &'a mut Vec<Vec2>,
}

impl Attributes<'_> {
    /// Appends the midpoint of vertices `i` and `j` and returns its index.
    fn push_midpoint(&mut self, i: u32, j: u32) -> u32 {
        let (i, j) = (i as usize, j as usize);
        let index = self.positions.len() as u32;
        self.positions
            .push((self.positions[i] + self.positions[j]) * 0.5);
        if !self.normals.is_empty() {
            let (a, b) = (self.normals[i], self.normals[j]);
            let n = if a == Vec3::ZERO || b == Vec3::ZERO {
                Vec3::ZERO
            } else {
                (a + b) * 0.5
            };
            self.normals.push(n);
        }
        if !self.uvs.is_empty() {
            self.uvs.push((self.uvs[i] + self.uvs[j]) * 0.5);
        }
        index
    }
}

/// One level of the split.
fn split_once(mesh: &mut Mesh) {
    let mut attributes = Attributes {
        positions: &mut mesh.positions,
        normals: &mut mesh.normals,
        uvs: &mut mesh.uvs,
    };
    let mut midpoints: HashMap<(u32, u32), u32> = HashMap::with_capacity(mesh.triangles.len() * 2);
    let mut midpoint = |i: u32, j: u32| -> u32 {
        let key = (i.min(j), i.max(j));
        *midpoints
            .entry(key)
            .or_insert_with(|| attributes.push_midpoint(key.0, key.1))
    };
    let mut triangles = Vec::with_capacity(mesh.triangles.len() * 4);
    for &[a, b, c] in &mesh.triangles {
        let (ab, bc, ca) = (midpoint(a, b), midpoint(b, c), midpoint(c, a));
        triangles.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
    }
    mesh.triangles = triangles;
    mesh.triangle_material = mesh
        .triangle_material
        .iter()
        .flat_map(|&m| [m; 4])
        .collect();
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::Material;
    use std::path::Path;

    /// Two triangles sharing an edge, not coplanar, with normals, UVs and two materials.
    fn two_triangles() -> Mesh {
        Mesh {
            positions: vec![
                Vec3::ZERO,
                Vec3::new(2.0, 0.0, 0.0),
                Vec3::new(0.0, 3.0, 0.0),
                Vec3::new(1.0, 1.0, 2.0),
            ],
            normals: vec![Vec3::Z, Vec3::Z, Vec3::X, Vec3::Y],
            uvs: vec![
                Vec2::ZERO,
                Vec2::new(1.0, 0.0),
                Vec2::new(0.0, 1.0),
                Vec2::new(1.0, 1.0),
            ],
            triangles: vec![[0, 1, 2], [1, 3, 2]],
            triangle_material: vec![0, 1],
            materials: vec![
                Material::plain("a", [0.2, 0.4, 0.6]),
                Material::plain("b", [0.7, 0.7, 0.7]),
            ],
            ..Default::default()
        }
    }

    fn area(m: &Mesh, t: u32) -> f64 {
        let [a, b, c] = m.corners(t);
        0.5 * (b - a).cross(c - a).length() as f64
    }

    fn normal(m: &Mesh, t: u32) -> Vec3 {
        let [a, b, c] = m.corners(t);
        (b - a).cross(c - a).normalize()
    }

    #[test]
    fn keeps_area_normals_materials_and_counts() {
        let source = two_triangles();
        for levels in 0..=3 {
            let mut m = source.clone();
            subdivide(&mut m, levels);
            m.validate(Path::new("t")).expect("valid");
            let per_parent = 4usize.pow(levels);
            assert_eq!(m.triangles.len(), 2 * per_parent);
            // The two triangles form a disk, which keeps V - E + F = 1 unless a midpoint is
            // duplicated (a crack) or missing.
            let edges: std::collections::HashSet<(u32, u32)> = m
                .triangles
                .iter()
                .flat_map(|&[a, b, c]| [(a, b), (b, c), (c, a)])
                .map(|(i, j)| (i.min(j), i.max(j)))
                .collect();
            let euler = m.positions.len() as i64 - edges.len() as i64 + m.triangles.len() as i64;
            assert_eq!(
                euler, 1,
                "levels {levels}: a crack or a duplicated midpoint"
            );
            for parent in 0..2u32 {
                let children = parent as usize * per_parent..(parent as usize + 1) * per_parent;
                let sum: f64 = children.clone().map(|t| area(&m, t as u32)).sum();
                let want = area(&source, parent);
                assert!((sum - want).abs() <= 1e-6 * want, "{sum} vs {want}");
                for t in children {
                    assert_eq!(m.triangle_material[t], parent);
                    let d = normal(&m, t as u32).dot(normal(&source, parent));
                    assert!(d > 1.0 - 1e-6, "child {t} of {parent} turned: {d}");
                }
            }
        }
    }

    /// Shading normal and texture coordinates at a point of a child agree with the parent's at
    /// the same point: both are linear over the parent.
    #[test]
    fn interpolates_uvs_and_normals() {
        let source = two_triangles();
        let mut m = source.clone();
        subdivide(&mut m, 1);
        // Child 3 of parent 0 is (ab, bc, ca); its corners are the parent's midpoints.
        let [ab, bc, ca] = m.triangles[3];
        assert_eq!(m.uvs[ab as usize], Vec2::new(0.5, 0.0));
        assert_eq!(m.uvs[bc as usize], Vec2::new(0.5, 0.5));
        assert_eq!(m.uvs[ca as usize], Vec2::new(0.0, 0.5));
        assert_eq!(m.normals[ab as usize], Vec3::Z);
        assert_eq!(m.normals[bc as usize], (Vec3::Z + Vec3::X) * 0.5);
        // The centroid of the parent is the centroid of child 3.
        let parent = source.shading_normal(0, (1.0 / 3.0, 1.0 / 3.0)).expect("n");
        let child = m.shading_normal(3, (1.0 / 3.0, 1.0 / 3.0)).expect("n");
        assert!((parent - child).length() < 1e-6, "{parent} vs {child}");
        // An absent normal stays absent at the midpoints next to it.
        let mut holes = source.clone();
        holes.normals[1] = Vec3::ZERO;
        subdivide(&mut holes, 1);
        assert_eq!(holes.normals[holes.triangles[3][0] as usize], Vec3::ZERO);
    }

    #[test]
    fn meshes_without_attributes_stay_without() {
        let mut m = two_triangles();
        m.normals.clear();
        m.uvs.clear();
        subdivide(&mut m, 2);
        assert!(m.normals.is_empty() && m.uvs.is_empty());
        m.validate(Path::new("t")).expect("valid");
    }
}
