//! The hierarchical point set that defines the basis (Lehtinen et al. 2008, section 2.1).
//!
//! Points of all levels are enumerated with one index, level by level (`X_l = {p_j}` for
//! `N_{l-1} < j <= N_l` in the paper's notation); `level_offsets[l]..level_offsets[l + 1]` is
//! the index range of level `l`.

use std::ops::Range;

use crate::error::FormatError;

/// Points `p_j = (x_j, n_j)` with support radii `r_j`, grouped by level, coarsest first.
#[derive(Clone, Debug, Default, PartialEq, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct Basis {
    pub positions: Vec<[f32; 3]>,
    /// Unit surface normals.
    pub normals: Vec<[f32; 3]>,
    /// Support radius `r_j = C R_l` of each point's weight function (Eq. 9).
    pub radii: Vec<f32>,
    /// `levels + 1` offsets into the point arrays; the first is 0, the last the point count.
    pub level_offsets: Vec<u32>,
    /// The Poisson-disk radius `R_l` each level was placed with (Eq. 11 metric).
    pub disk_radii: Vec<f32>,
}

impl Basis {
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    pub fn levels(&self) -> usize {
        self.level_offsets.len().saturating_sub(1)
    }

    /// Index range of level `l`'s points.
    pub fn level_range(&self, l: usize) -> Range<usize> {
        self.level_offsets[l] as usize..self.level_offsets[l + 1] as usize
    }

    /// Level of point `j`.
    pub fn level_of(&self, j: usize) -> usize {
        // level_offsets is sorted; the level is the last offset <= j.
        self.level_offsets.partition_point(|&o| o as usize <= j) - 1
    }

    /// Checks the structural invariants a reader relies on; every math routine of this crate
    /// may assume a basis that passed.
    pub fn validate(&self) -> Result<(), FormatError> {
        let n = self.positions.len();
        let bad = |m: String| Err(FormatError::InvalidBasis(m));
        if self.normals.len() != n || self.radii.len() != n {
            return bad(format!(
                "{} positions but {} normals and {} radii",
                n,
                self.normals.len(),
                self.radii.len()
            ));
        }
        if self.level_offsets.first() != Some(&0)
            || self.level_offsets.last().map(|&o| o as usize) != Some(n)
            || self.level_offsets.windows(2).any(|w| w[0] > w[1])
        {
            return bad("level offsets are not a non-decreasing cover of the points".into());
        }
        if self.disk_radii.len() != self.levels() {
            return bad(format!(
                "{} levels but {} disk radii",
                self.levels(),
                self.disk_radii.len()
            ));
        }
        for j in 0..n {
            let p = self.positions[j];
            let nn = self.normals[j];
            let len2 = nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2];
            if !p.iter().all(|c| c.is_finite()) {
                return bad(format!("point {j} has a non-finite position"));
            }
            if !len2.is_finite() || (len2 - 1.0).abs() > 1e-3 {
                return bad(format!("point {j} has a normal of length^2 {len2}"));
            }
            if !(self.radii[j].is_finite() && self.radii[j] > 0.0) {
                return bad(format!("point {j} has radius {}", self.radii[j]));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tiny() -> Basis {
        Basis {
            positions: vec![[0.0; 3]; 5],
            normals: vec![[0.0, 1.0, 0.0]; 5],
            radii: vec![1.0; 5],
            level_offsets: vec![0, 1, 1, 5],
            disk_radii: vec![1.0, 0.5, 0.25],
        }
    }

    #[test]
    fn level_of_handles_empty_levels() {
        let b = tiny();
        assert_eq!(b.levels(), 3);
        assert_eq!(b.level_of(0), 0);
        assert_eq!(b.level_of(1), 2);
        assert_eq!(b.level_of(4), 2);
        assert_eq!(b.level_range(1), 1..1);
        b.validate().unwrap();
    }

    #[test]
    fn validate_rejects_broken_bases() {
        let mut b = tiny();
        b.radii[2] = 0.0;
        assert!(b.validate().is_err());
        let mut b = tiny();
        b.normals[0] = [0.0, 2.0, 0.0];
        assert!(b.validate().is_err());
        let mut b = tiny();
        b.level_offsets = vec![0, 3, 2, 5];
        assert!(b.validate().is_err());
        let mut b = tiny();
        b.positions[1][0] = f32::NAN;
        assert!(b.validate().is_err());
    }
}
