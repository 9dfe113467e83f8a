//! A bounding volume hierarchy over a mesh's triangles in the flat layout a compute shader
//! walks (`shaders/relight/direct.wgsl`): the GPU relighter's shadow rays.
//!
//! Built once per file by median splits on the longest axis of the triangles' centroids, with
//! at most [`LEAF`] triangles a leaf: a shadow ray needs any hit, not the nearest, so a fast
//! build matters more than the last traversal step an SAH build would save. Node `0` is the
//! root; an inner node's children are consecutive, the first at `first`.

use glam::Vec3;

/// Triangles per leaf at most.
pub const LEAF: usize = 4;

/// A node: its box, and either its first child (`count == 0`) or its first triangle in the
/// reordered list and their count. Eight words, as the shader reads it.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Node {
    pub min: [f32; 3],
    pub first: u32,
    pub max: [f32; 3],
    pub count: u32,
}

/// The hierarchy: nodes, and the triangles' corners in leaf order (nine floats a triangle).
#[derive(Clone, Debug, Default)]
pub struct Bvh {
    pub nodes: Vec<Node>,
    pub corners: Vec<f32>,
}

impl Bvh {
    /// Builds the hierarchy over `triangles` (corner indices into `positions`); triangles with
    /// an index out of range are left out. The same nodes for the same input.
    pub fn build(positions: &[Vec3], triangles: &[[u32; 3]]) -> Bvh {
        let tris: Vec<[Vec3; 3]> = triangles
            .iter()
            .filter_map(|t| {
                let c = |k: usize| positions.get(t[k] as usize).copied();
                Some([c(0)?, c(1)?, c(2)?])
            })
            .collect();
        let mut order: Vec<u32> = (0..tris.len() as u32).collect();
        let centroids: Vec<Vec3> = tris.iter().map(|t| (t[0] + t[1] + t[2]) / 3.0).collect();
        let centroid = |i: u32| centroids[i as usize];
        let mut nodes = vec![Node::default()];
        // (node, range of `order`) still to split.
        let mut todo = vec![(0usize, 0usize, order.len())];
        while let Some((node, a, e)) = todo.pop() {
            let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
            let (mut clo, mut chi) = (lo, hi);
            for &i in &order[a..e] {
                for v in tris[i as usize] {
                    lo = lo.min(v);
                    hi = hi.max(v);
                }
                let c = centroid(i);
                clo = clo.min(c);
                chi = chi.max(c);
            }
            if a == e {
                (lo, hi) = (Vec3::ZERO, Vec3::ZERO);
            }
            nodes[node].min = lo.to_array();
            nodes[node].max = hi.to_array();
            let extent = chi - clo;
            if e - a <= LEAF || extent.max_element() <= 0.0 {
                nodes[node].first = a as u32;
                nodes[node].count = (e - a) as u32;
                continue;
            }
            let axis = if extent.x >= extent.y && extent.x >= extent.z {
                0
            } else if extent.y >= extent.z {
                1
            } else {
                2
            };
            let mid = a + (e - a) / 2;
            order[a..e].select_nth_unstable_by(mid - a, |&p, &q| {
                centroid(p)[axis]
                    .total_cmp(&centroid(q)[axis])
                    .then(p.cmp(&q))
            });
            let left = nodes.len();
            nodes.push(Node::default());
            nodes.push(Node::default());
            nodes[node].first = left as u32;
            nodes[node].count = 0;
            todo.push((left + 1, mid, e));
            todo.push((left, a, mid));
        }
        let corners = order
            .iter()
            .flat_map(|&i| tris[i as usize].iter().flat_map(|v| v.to_array()))
            .collect();
        Bvh { nodes, corners }
    }

    /// Triangles held.
    pub fn triangles(&self) -> usize {
        self.corners.len() / 9
    }

    /// Whether the segment from `a` to `b`, less `eps` at each end, meets a triangle: the walk
    /// the shader does, for tests.
    #[cfg(test)]
    pub fn occluded(&self, a: Vec3, b: Vec3, eps: f32) -> bool {
        let d = b - a;
        let len = d.length();
        if !len.is_finite() || len <= 2.0 * eps || self.nodes.is_empty() {
            return false;
        }
        let dir = d / len;
        let (t0, t1) = (eps, len - eps);
        let inv = dir.recip();
        let mut stack = vec![0u32];
        while let Some(k) = stack.pop() {
            let n = &self.nodes[k as usize];
            if !slab(Vec3::from(n.min), Vec3::from(n.max), a, inv, t0, t1) {
                continue;
            }
            if n.count == 0 {
                stack.extend([n.first, n.first + 1]);
                continue;
            }
            for t in n.first..n.first + n.count {
                let c = &self.corners[9 * t as usize..9 * t as usize + 9];
                let v = |k: usize| Vec3::new(c[3 * k], c[3 * k + 1], c[3 * k + 2]);
                if let Some(t) = intersect(a, dir, v(0), v(1), v(2)) {
                    if t > t0 && t < t1 {
                        return true;
                    }
                }
            }
        }
        false
    }
}

/// Whether the ray `o + t d` (`inv` = 1 / d) meets the box for some `t` in `[t0, t1]`.
#[cfg(test)]
fn slab(lo: Vec3, hi: Vec3, o: Vec3, inv: Vec3, t0: f32, t1: f32) -> bool {
    let (a, b) = ((lo - o) * inv, (hi - o) * inv);
    let (near, far) = (
        a.min(b).max_element().max(t0),
        a.max(b).min_element().min(t1),
    );
    near <= far
}

/// Möller-Trumbore: the ray parameter of the hit with the triangle `v0 v1 v2`, either side.
#[cfg(test)]
fn intersect(o: Vec3, d: Vec3, v0: Vec3, v1: Vec3, v2: Vec3) -> Option<f32> {
    let (e1, e2) = (v1 - v0, v2 - v0);
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-12 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - v0;
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    Some(e2.dot(q) * inv)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_walk_finds_what_a_test_of_every_triangle_finds() {
        // A grid of small quads (two triangles each) on z = 0 with holes.
        let mut positions = Vec::new();
        let mut triangles = Vec::new();
        for i in 0..20 {
            for j in 0..20 {
                if (i * 7 + j * 3) % 5 == 0 {
                    continue;
                }
                let o = Vec3::new(i as f32, j as f32, 0.0);
                let b = positions.len() as u32;
                positions.extend([
                    o,
                    o + Vec3::X * 0.9,
                    o + Vec3::Y * 0.9,
                    o + Vec3::new(0.9, 0.9, 0.0),
                ]);
                triangles.extend([[b, b + 1, b + 2], [b + 1, b + 3, b + 2]]);
            }
        }
        let bvh = Bvh::build(&positions, &triangles);
        assert_eq!(bvh.triangles(), triangles.len());
        assert!(bvh.nodes.iter().all(|n| n.count as usize <= LEAF));
        let brute = |a: Vec3, b: Vec3, eps: f32| {
            let (d, len) = ((b - a).normalize(), (b - a).length());
            triangles.iter().any(|t| {
                let v = |k: usize| positions[t[k] as usize];
                intersect(a, d, v(0), v(1), v(2)).is_some_and(|t| t > eps && t < len - eps)
            })
        };
        let mut hits = 0;
        for k in 0..500 {
            let f = |m: u32| ((k * m + 17) % 211) as f32 / 211.0;
            let a = Vec3::new(20.0 * f(13), 20.0 * f(29), 1.0 + f(7));
            let b = Vec3::new(20.0 * f(31), 20.0 * f(11), -1.0 - f(5));
            let want = brute(a, b, 1e-4);
            assert_eq!(bvh.occluded(a, b, 1e-4), want, "segment {k}");
            hits += usize::from(want);
            // A segment that stops short of the plane meets nothing.
            assert!(!bvh.occluded(a, a.lerp(b, 0.2), 1e-4));
        }
        assert!(hits > 100 && hits < 500, "{hits}");
    }
}
