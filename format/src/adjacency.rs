//! Neighbours, parents and children of basis functions (section 2.1): for `B_i` on level `l`,
//! neighbours are the other level-`l` functions `B_n` with `B_i(p_n) != 0`, children the
//! level-`l+1` functions `B_j` with `B_i(p_j) != 0`, parents the level-`l-1` functions `B_k`
//! with `B_k(p_i) != 0`. Stored as compressed sparse rows.

use crate::shepard::IndexedBasis;

/// Compressed sparse rows: row `i` is `indices[offsets[i]..offsets[i + 1]]`, sorted.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Csr {
    pub offsets: Vec<u32>,
    pub indices: Vec<u32>,
}

impl Csr {
    pub fn row(&self, i: usize) -> &[u32] {
        &self.indices[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    pub fn rows(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    fn from_pairs(rows: usize, mut pairs: Vec<(u32, u32)>) -> Csr {
        pairs.sort_unstable();
        let mut offsets = vec![0u32; rows + 1];
        for &(r, _) in &pairs {
            offsets[r as usize + 1] += 1;
        }
        for i in 0..rows {
            offsets[i + 1] += offsets[i];
        }
        Csr {
            offsets,
            indices: pairs.into_iter().map(|(_, c)| c).collect(),
        }
    }
}

/// Neighbour lists of every point (a point is not its own neighbour).
pub fn neighbors(ib: &IndexedBasis) -> Csr {
    let b = &ib.basis;
    let mut pairs = Vec::new();
    for l in 0..b.levels() {
        for n in b.level_range(l) {
            ib.for_each_weight(l, b.positions[n], b.normals[n], |i, _| {
                if i != n {
                    pairs.push((i as u32, n as u32));
                }
            });
        }
    }
    Csr::from_pairs(b.len(), pairs)
}

/// Parent lists of every point (empty on level 0).
pub fn parents(ib: &IndexedBasis) -> Csr {
    let b = &ib.basis;
    let mut pairs = Vec::new();
    for l in 1..b.levels() {
        for i in b.level_range(l) {
            ib.for_each_weight(l - 1, b.positions[i], b.normals[i], |k, _| {
                pairs.push((i as u32, k as u32));
            });
        }
    }
    Csr::from_pairs(b.len(), pairs)
}

/// Child lists of every point (empty on the finest level): the transpose of [`parents`].
pub fn children(ib: &IndexedBasis) -> Csr {
    let p = parents(ib);
    let mut pairs = Vec::with_capacity(p.indices.len());
    for i in 0..p.rows() {
        for &k in p.row(i) {
            pairs.push((k, i as u32));
        }
    }
    Csr::from_pairs(ib.basis.len(), pairs)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernel::weight;
    use crate::test_support::plane_basis;

    #[test]
    fn relations_match_their_definitions() {
        let ib = plane_basis(3, 2);
        let b = &ib.basis;
        let nb = neighbors(&ib);
        let pa = parents(&ib);
        let ch = children(&ib);
        let w = |i: usize, j: usize| {
            weight(
                b.positions[j],
                b.normals[j],
                b.positions[i],
                b.normals[i],
                b.radii[i],
            )
        };
        for i in 0..b.len() {
            let l = b.level_of(i);
            let expect_nb: Vec<u32> = b
                .level_range(l)
                .filter(|&n| n != i && w(i, n) > 0.0)
                .map(|n| n as u32)
                .collect();
            assert_eq!(nb.row(i), &expect_nb[..], "neighbours of {i}");
            let expect_ch: Vec<u32> = if l + 1 < b.levels() {
                b.level_range(l + 1)
                    .filter(|&c| w(i, c) > 0.0)
                    .map(|c| c as u32)
                    .collect()
            } else {
                vec![]
            };
            assert_eq!(ch.row(i), &expect_ch[..], "children of {i}");
            for &k in pa.row(i) {
                assert!(ch.row(k as usize).contains(&(i as u32)));
            }
        }
        assert!(pa.row(0).is_empty());
    }
}
