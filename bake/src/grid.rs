//! A uniform hash grid over accepted points, so that each dart of the Poisson-disk thrower
//! looks only at the 27 cells around it: near-linear in the number of candidates.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use glam::Vec3;

use crate::rng::mix64;

/// A hasher for packed cell keys (already well distributed after [`mix64`]).
#[derive(Default)]
pub struct CellHasher(u64);

impl Hasher for CellHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = mix64(self.0 ^ b as u64);
        }
    }
    fn write_u64(&mut self, k: u64) {
        self.0 = mix64(k);
    }
}

/// Points bucketed by cells of side `cell` (at least the largest query radius).
pub struct Grid {
    inv_cell: f32,
    cells: HashMap<u64, Vec<u32>, BuildHasherDefault<CellHasher>>,
}

fn key(c: [i32; 3]) -> u64 {
    // 21 bits per axis (wrapping): collisions only merge far-apart buckets, which costs time
    // but not correctness since callers test exact distances.
    let m = (1u64 << 21) - 1;
    ((c[0] as u64) & m) | (((c[1] as u64) & m) << 21) | (((c[2] as u64) & m) << 42)
}

impl Grid {
    pub fn new(cell: f32) -> Grid {
        Grid {
            inv_cell: 1.0 / cell,
            cells: HashMap::default(),
        }
    }

    fn cell_of(&self, p: Vec3) -> [i32; 3] {
        let q = p * self.inv_cell;
        [q.x.floor() as i32, q.y.floor() as i32, q.z.floor() as i32]
    }

    pub fn insert(&mut self, p: Vec3, id: u32) {
        let c = self.cell_of(p);
        self.cells.entry(key(c)).or_default().push(id);
    }

    /// Calls `f(id)` for the points in the 27 cells around `p` until `f` returns true;
    /// returns whether it did. The point's own cell comes first: it is the likeliest to hold
    /// a conflicting point, and most darts are rejected.
    pub fn any_near(&self, p: Vec3, mut f: impl FnMut(u32) -> bool) -> bool {
        let c = self.cell_of(p);
        let mut visit = |d: [i32; 3]| {
            self.cells
                .get(&key([c[0] + d[0], c[1] + d[1], c[2] + d[2]]))
                .is_some_and(|ids| ids.iter().any(|&id| f(id)))
        };
        if visit([0, 0, 0]) {
            return true;
        }
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    if (dx, dy, dz) != (0, 0, 0) && visit([dx, dy, dz]) {
                        return true;
                    }
                }
            }
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_every_point_within_one_cell() {
        let mut g = Grid::new(0.5);
        let pts: Vec<Vec3> = (0..500)
            .map(|i| {
                let f = i as f32;
                Vec3::new(
                    (f * 0.37).sin() * 3.0,
                    (f * 0.11).cos() * 3.0,
                    (f * 0.07).sin() - 4.0,
                )
            })
            .collect();
        for (i, p) in pts.iter().enumerate() {
            g.insert(*p, i as u32);
        }
        for q in &pts {
            let mut found = Vec::new();
            g.any_near(*q, |id| {
                if pts[id as usize].distance(*q) < 0.5 {
                    found.push(id);
                }
                false
            });
            found.sort();
            let brute: Vec<u32> = (0..500u32)
                .filter(|&i| pts[i as usize].distance(*q) < 0.5)
                .collect();
            assert_eq!(found, brute);
        }
    }
}
