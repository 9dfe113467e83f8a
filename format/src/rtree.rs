//! One R-tree per level: a bounding volume hierarchy over the support spheres of the level's
//! basis functions (Lehtinen et al. 2008, section 2.1, "Efficient Reconstruction"), answering
//! "which basis functions may be non-zero at x" without allocating.
//!
//! Layout (flat arrays, depth-first order): node `i` is a leaf when `node_count[i] > 0`, and then
//! holds `items[node_first[i] .. node_first[i] + node_count[i]]`; otherwise its left child is
//! `i + 1` and its right child `node_first[i]`. Boxes bound the spheres `(x_j, r_j)`, which
//! contain the (ellipsoidal) supports of Eq. 10.

use crate::basis::Basis;

/// Most items per leaf.
pub const LEAF_SIZE: usize = 4;
/// Deepest tree a reader accepts; the builder's median split stays far below it (about
/// `log2(n / LEAF_SIZE) + 1` levels).
pub const MAX_DEPTH: usize = 64;

#[derive(Clone, Debug, Default, PartialEq, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct RTree {
    pub node_min: Vec<[f32; 3]>,
    pub node_max: Vec<[f32; 3]>,
    pub node_first: Vec<u32>,
    pub node_count: Vec<u32>,
    /// Global point indices, grouped by leaf.
    pub items: Vec<u32>,
}

impl RTree {
    /// Builds the tree over the points `range` of `basis` (one level). Deterministic: median
    /// splits along the longest axis of the centre bounds, ties broken by point index.
    pub fn build(basis: &Basis, range: std::ops::Range<usize>) -> RTree {
        let mut items: Vec<u32> = range.map(|j| j as u32).collect();
        let mut tree = RTree::default();
        if items.is_empty() {
            return tree;
        }
        let n = items.len();
        tree.items.reserve(n);
        build_node(basis, &mut items[..], &mut tree);
        tree
    }

    pub fn node_count(&self) -> usize {
        self.node_count.len()
    }

    pub fn is_empty(&self) -> bool {
        self.node_count.is_empty()
    }

    /// Calls `f(j)` for every point `j` whose support sphere's bounding box contains `x`
    /// (a superset of the functions non-zero at `x`; the caller evaluates the weight).
    /// Allocation-free: a fixed stack of [`MAX_DEPTH`] entries, guaranteed enough by
    /// [`RTree::validate`] for trees read from files and by construction for built ones.
    /// Whether `x` lies in the closed bounding box of `node`.
    #[inline]
    pub fn node_contains(&self, node: usize, x: [f32; 3]) -> bool {
        let lo = self.node_min[node];
        let hi = self.node_max[node];
        x[0] >= lo[0]
            && x[0] <= hi[0]
            && x[1] >= lo[1]
            && x[1] <= hi[1]
            && x[2] >= lo[2]
            && x[2] <= hi[2]
    }

    #[inline]
    pub fn for_each_candidate(&self, x: [f32; 3], mut f: impl FnMut(u32)) {
        if self.node_count.is_empty() {
            return;
        }
        let mut stack = [0u32; MAX_DEPTH];
        let mut sp = 0usize;
        let mut node = 0usize;
        loop {
            if self.node_contains(node, x) {
                let count = self.node_count[node] as usize;
                if count > 0 {
                    let first = self.node_first[node] as usize;
                    for &j in &self.items[first..first + count] {
                        f(j);
                    }
                } else {
                    stack[sp] = self.node_first[node];
                    sp += 1;
                    node += 1;
                    continue;
                }
            }
            if sp == 0 {
                return;
            }
            sp -= 1;
            node = stack[sp] as usize;
        }
    }

    /// Walks the tree depth first, left child before right: calls `descend(min, max)` with
    /// the box of each node reached and enters the node only when it returns true, reaching
    /// its children or, in a leaf, calling `leaf(j)` for each of its points in stored order.
    /// Returns the number of nodes reached (every node `descend` saw). Allocation-free, with
    /// the fixed stack of [`RTree::for_each_candidate`].
    pub fn visit(
        &self,
        mut descend: impl FnMut([f32; 3], [f32; 3]) -> bool,
        mut leaf: impl FnMut(u32),
    ) -> usize {
        if self.node_count.is_empty() {
            return 0;
        }
        let mut stack = [0u32; MAX_DEPTH];
        let mut sp = 0usize;
        let mut node = 0usize;
        let mut reached = 0usize;
        loop {
            reached += 1;
            if descend(self.node_min[node], self.node_max[node]) {
                let count = self.node_count[node] as usize;
                if count == 0 {
                    stack[sp] = self.node_first[node];
                    sp += 1;
                    node += 1;
                    continue;
                }
                let first = self.node_first[node] as usize;
                self.items[first..first + count]
                    .iter()
                    .for_each(|&j| leaf(j));
            }
            if sp == 0 {
                return reached;
            }
            sp -= 1;
            node = stack[sp] as usize;
        }
    }

    /// Calls `f(first, count, min, max)` for every node at `depth` (or leaf above it), the
    /// granularity at which a renderer culls groups of basis functions.
    pub fn for_each_node_at_depth(
        &self,
        depth: usize,
        mut f: impl FnMut(&[u32], [f32; 3], [f32; 3]),
    ) {
        if self.node_count.is_empty() {
            return;
        }
        let mut stack = [(0u32, 0u32); MAX_DEPTH];
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let (node, d) = stack[sp];
            let node = node as usize;
            let count = self.node_count[node] as usize;
            if count > 0 || d as usize >= depth {
                let items = self.subtree_items(node);
                f(items, self.node_min[node], self.node_max[node]);
            } else {
                stack[sp] = (self.node_first[node], d + 1);
                stack[sp + 1] = (node as u32 + 1, d + 1);
                sp += 2;
            }
        }
    }

    /// All items under `node`: contiguous in depth-first order, from the leftmost leaf
    /// (reached through left children, `i + 1`) to the rightmost (through right children).
    fn subtree_items(&self, node: usize) -> &[u32] {
        let mut lo = node;
        while self.node_count[lo] == 0 {
            lo += 1;
        }
        let mut hi = node;
        while self.node_count[hi] == 0 {
            hi = self.node_first[hi] as usize;
        }
        let start = self.node_first[lo] as usize;
        let end = self.node_first[hi] as usize + self.node_count[hi] as usize;
        &self.items[start..end]
    }

    /// Checks that the arrays form a well-shaped tree over exactly the points of `range`
    /// whose boxes contain their items' support spheres; required before querying a tree read
    /// from a file.
    pub fn validate(&self, basis: &Basis, range: std::ops::Range<usize>) -> Result<(), String> {
        let n = self.node_count.len();
        if self.node_min.len() != n || self.node_max.len() != n || self.node_first.len() != n {
            return Err("node arrays differ in length".into());
        }
        if self.items.len() != range.len() {
            return Err(format!(
                "{} items for a level of {} points",
                self.items.len(),
                range.len()
            ));
        }
        if n == 0 {
            return if range.is_empty() {
                Ok(())
            } else {
                Err("no nodes for a non-empty level".into())
            };
        }
        let mut seen = vec![false; range.len()];
        let mut next_item = 0usize;
        // Iterative depth-first walk that must visit nodes in index order.
        let mut stack: Vec<(usize, usize)> = vec![(0, 1)];
        let mut expected = 0usize;
        while let Some((node, depth)) = stack.pop() {
            if node != expected || node >= n {
                return Err(format!("node {node} is out of depth-first order"));
            }
            if depth > MAX_DEPTH {
                return Err(format!("tree deeper than {MAX_DEPTH}"));
            }
            expected += 1;
            let count = self.node_count[node] as usize;
            let first = self.node_first[node] as usize;
            if count > 0 {
                if first != next_item || first + count > self.items.len() {
                    return Err(format!("leaf {node} has a bad item range"));
                }
                next_item += count;
                for &j in &self.items[first..first + count] {
                    let j = j as usize;
                    if !range.contains(&j) || std::mem::replace(&mut seen[j - range.start], true) {
                        return Err(format!("leaf {node} holds point {j} out of place"));
                    }
                    let (lo, hi) = (self.node_min[node], self.node_max[node]);
                    let (c, r) = (basis.positions[j], basis.radii[j]);
                    for a in 0..3 {
                        if !(c[a] - r >= lo[a] && c[a] + r <= hi[a]) {
                            return Err(format!("leaf {node} does not bound point {j}"));
                        }
                    }
                }
            } else {
                if first <= node + 1 || first >= n {
                    return Err(format!(
                        "interior node {node} has a bad right child {first}"
                    ));
                }
                stack.push((first, depth + 1));
                stack.push((node + 1, depth + 1));
            }
        }
        if expected != n || next_item != self.items.len() {
            return Err("unreachable nodes or items".into());
        }
        Ok(())
    }
}

fn sphere_bounds(basis: &Basis, items: &[u32]) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for &j in items {
        let c = basis.positions[j as usize];
        let r = basis.radii[j as usize];
        for a in 0..3 {
            lo[a] = lo[a].min(c[a] - r);
            hi[a] = hi[a].max(c[a] + r);
        }
    }
    (lo, hi)
}

fn build_node(basis: &Basis, items: &mut [u32], tree: &mut RTree) {
    let (lo, hi) = sphere_bounds(basis, items);
    let node = tree.node_count.len();
    tree.node_min.push(lo);
    tree.node_max.push(hi);
    if items.len() <= LEAF_SIZE {
        tree.node_first.push(tree.items.len() as u32);
        tree.node_count.push(items.len() as u32);
        tree.items.extend_from_slice(items);
        return;
    }
    tree.node_first.push(0);
    tree.node_count.push(0);
    // Split along the longest axis of the centres' bounds at the median.
    let mut clo = [f32::INFINITY; 3];
    let mut chi = [f32::NEG_INFINITY; 3];
    for &j in items.iter() {
        let c = basis.positions[j as usize];
        for a in 0..3 {
            clo[a] = clo[a].min(c[a]);
            chi[a] = chi[a].max(c[a]);
        }
    }
    let ext = [chi[0] - clo[0], chi[1] - clo[1], chi[2] - clo[2]];
    let axis = if ext[0] >= ext[1] && ext[0] >= ext[2] {
        0
    } else if ext[1] >= ext[2] {
        1
    } else {
        2
    };
    let mid = items.len() / 2;
    items.select_nth_unstable_by(mid, |&a, &b| {
        let ca = basis.positions[a as usize][axis];
        let cb = basis.positions[b as usize][axis];
        ca.total_cmp(&cb).then(a.cmp(&b))
    });
    let (left, right) = items.split_at_mut(mid);
    build_node(basis, left, tree);
    tree.node_first[node] = tree.node_count.len() as u32;
    build_node(basis, right, tree);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random_basis(n: usize, seed: u64) -> Basis {
        let mut s = seed;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 40) as f32) / (1u64 << 24) as f32
        };
        let mut b = Basis::default();
        for _ in 0..n {
            b.positions
                .push([next() * 10.0, next() * 10.0, next() * 10.0]);
            b.normals.push([0.0, 1.0, 0.0]);
            b.radii.push(0.2 + next());
        }
        b.level_offsets = vec![0, n as u32];
        b.disk_radii = vec![1.0];
        b
    }

    #[test]
    fn query_matches_brute_force() {
        let b = random_basis(1000, 7);
        let t = RTree::build(&b, 0..1000);
        t.validate(&b, 0..1000).unwrap();
        let mut found = Vec::new();
        for q in 0..200 {
            let x = [q as f32 * 0.05, 5.0 - q as f32 * 0.01, (q % 10) as f32];
            found.clear();
            t.for_each_candidate(x, |j| {
                let c = b.positions[j as usize];
                let d2: f32 = (0..3).map(|a| (x[a] - c[a]).powi(2)).sum();
                if d2 < b.radii[j as usize].powi(2) {
                    found.push(j);
                }
            });
            found.sort();
            let brute: Vec<u32> = (0..1000u32)
                .filter(|&j| {
                    let c = b.positions[j as usize];
                    let d2: f32 = (0..3).map(|a| (x[a] - c[a]).powi(2)).sum();
                    d2 < b.radii[j as usize].powi(2)
                })
                .collect();
            assert_eq!(found, brute, "query {q}");
        }
    }

    #[test]
    fn empty_level_builds_and_queries_nothing() {
        let b = random_basis(3, 1);
        let t = RTree::build(&b, 3..3);
        assert!(t.is_empty());
        t.validate(&b, 3..3).unwrap();
        let mut hits = 0;
        t.for_each_candidate([0.0; 3], |_| hits += 1);
        assert_eq!(hits, 0);
    }

    #[test]
    fn validate_rejects_a_tampered_tree() {
        let b = random_basis(100, 3);
        let t = RTree::build(&b, 0..100);
        let mut bad = t.clone();
        bad.node_first[0] = 0; // a right child pointing at itself
        assert!(bad.validate(&b, 0..100).is_err());
        let mut bad = t.clone();
        bad.items[0] = bad.items[1]; // a point twice
        assert!(bad.validate(&b, 0..100).is_err());
        let mut bad = t.clone();
        let leaf = bad.node_count.iter().position(|&c| c > 0).unwrap();
        bad.node_max[leaf][0] -= 5.0; // a box that does not bound its points
        assert!(bad.validate(&b, 0..100).is_err());
    }

    #[test]
    fn groups_at_a_depth_cover_every_item_once() {
        let b = random_basis(500, 11);
        let t = RTree::build(&b, 0..500);
        for depth in [0, 1, 3, 6, 40] {
            let mut all = Vec::new();
            t.for_each_node_at_depth(depth, |items, _, _| all.extend_from_slice(items));
            all.sort();
            assert_eq!(all, (0..500u32).collect::<Vec<_>>(), "depth {depth}");
        }
    }

    #[test]
    fn visit_prunes_by_box_and_reaches_the_points_of_every_box_entered() {
        let b = random_basis(700, 13);
        let t = RTree::build(&b, 0..700);
        // Entering every node reaches every node once and every point once, in stored order.
        let mut all = Vec::new();
        assert_eq!(t.visit(|_, _| true, |j| all.push(j)), t.node_count());
        assert_eq!(all, t.items);
        // Refusing the root reaches it alone.
        let mut none = 0;
        assert_eq!(t.visit(|_, _| false, |_| none += 1), 1);
        assert_eq!(none, 0);
        // A query box: the points reached whose spheres' boxes overlap it are exactly those of
        // a brute-force search, and pruning skips part of the tree.
        let (qlo, qhi) = ([2.0, 3.0, 1.0], [4.5, 6.0, 3.5]);
        let overlaps =
            |lo: [f32; 3], hi: [f32; 3]| (0..3).all(|a| lo[a] <= qhi[a] && hi[a] >= qlo[a]);
        let sphere_box = |j: u32| {
            let (c, r) = (b.positions[j as usize], b.radii[j as usize]);
            (
                [c[0] - r, c[1] - r, c[2] - r],
                [c[0] + r, c[1] + r, c[2] + r],
            )
        };
        let mut found = Vec::new();
        let reached = t.visit(overlaps, |j| {
            let (lo, hi) = sphere_box(j);
            if overlaps(lo, hi) {
                found.push(j);
            }
        });
        found.sort();
        let brute: Vec<u32> = (0..700u32)
            .filter(|&j| {
                let (lo, hi) = sphere_box(j);
                overlaps(lo, hi)
            })
            .collect();
        assert!(!brute.is_empty());
        assert_eq!(found, brute);
        assert!(reached < t.node_count(), "{reached} of {}", t.node_count());
        assert_eq!(
            RTree::default().visit(|_, _| true, |_| panic!("no points")),
            0
        );
    }

    #[test]
    fn build_is_deterministic_with_ties() {
        let mut b = random_basis(64, 5);
        for p in &mut b.positions {
            *p = [1.0, 1.0, 1.0];
        }
        assert_eq!(RTree::build(&b, 0..64), RTree::build(&b, 0..64));
    }
}
