//! The `FLT2` section (format 1.6; `FLAT` in 1.5): the one-level flat basis ([`FlatBasis`]) as
//! the bake built it, so that a viewer reads it instead of building it when it opens a file.
//!
//! The flat basis depends only on the hierarchical basis, on which receivers have links of S
//! and on the rule that builds it ([`FlatRule`]: the neighbour count, radius factor and hole
//! thresholds of [`crate::flat_basis`]). The section stores the flat points as indices of
//! the hierarchical points (Morton order), their flat radii and the flat level's R-tree (flat
//! node arrays, as `RTRE` stores a level's), with what it was built for: the number of
//! hierarchical points, a key of the link flags ([`linked_key`]) and the rule. A reader
//! validates it in place (rkyv's checked access on the mapped bytes) and then copies the
//! three arrays out (12 bytes per flat point plus the tree); positions and normals come from
//! the hierarchical basis.
//!
//! Matching: a section built by another rule is not an error (the reader builds the flat basis
//! by its own rule instead: [`StoredFlat::OtherRule`]); a section whose point count or link key
//! differs from the file's own basis and links, or whose arrays are inconsistent (an index out
//! of range or repeated, a radius not finite and positive, a tree that does not bound its
//! points), is a corrupt file. Format 1.5 stored the section under `FLAT`, with the rule
//! without `finer_cover` ([`FlatSection1_5`]); a reader takes only the rule from it, always
//! another rule than this build's (it kept every needed point), and builds the flat basis.

use xxhash_rust::xxh3::Xxh3;

use crate::error::FormatError;
use crate::flat_basis::FlatBasis;
pub use crate::flat_basis::FlatRule;
use crate::rtree::RTree;
use crate::shepard::IndexedBasis;

/// The `FLT2` section.
#[derive(Clone, Debug, PartialEq, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct FlatSection {
    /// Points of the hierarchical basis it was built on.
    pub points: u32,
    /// [`linked_key`] of the link flags it was built for.
    pub linked_key: u64,
    /// The rule it was built by.
    pub rule: FlatRule,
    /// For each flat point (Morton order), the hierarchical point it is.
    pub source: Vec<u32>,
    /// Flat support radius of each flat point.
    pub radii: Vec<f32>,
    /// The R-tree of the flat level (boxes bounding the flat support spheres).
    pub tree: RTree,
}

/// What a file's `FLT2` (or 1.5 `FLAT`) section gave a reader.
#[derive(Debug)]
pub enum StoredFlat {
    /// The stored flat basis, checked against the file's basis and links.
    Stored(Box<FlatBasis>),
    /// The file has neither section (written before format 1.5, or without transport).
    Absent,
    /// The section was built by another rule than this build's ([`FlatRule::current`]).
    OtherRule(FlatRule),
}

/// Per hierarchical point of `points`: whether it receives a link (`receiver_ids` are the
/// receivers of the links of S; ids out of range are ignored, the links' validation reports
/// them).
pub fn linked_flags(points: usize, receiver_ids: impl IntoIterator<Item = u32>) -> Vec<bool> {
    let mut linked = vec![false; points];
    for r in receiver_ids {
        if let Some(k) = linked.get_mut(r as usize) {
            *k = true;
        }
    }
    linked
}

/// xxh3-64 of the link flags (one byte per point), identifying the set of linked receivers.
pub fn linked_key(linked: &[bool]) -> u64 {
    let mut h = Xxh3::new();
    h.update(&(linked.len() as u64).to_le_bytes());
    for chunk in linked.chunks(4096) {
        let bytes: Vec<u8> = chunk.iter().map(|&b| b as u8).collect();
        h.update(&bytes);
    }
    h.digest()
}

impl FlatSection {
    /// The section of `flat`, built on `hier` for the link flags `linked` by this build's rule.
    pub fn new(hier: &IndexedBasis, linked: &[bool], flat: &FlatBasis) -> FlatSection {
        FlatSection {
            points: hier.basis.len() as u32,
            linked_key: linked_key(linked),
            rule: FlatRule::current(),
            source: flat.source.clone(),
            radii: flat.ib.basis.radii.clone(),
            tree: flat.ib.trees.first().cloned().unwrap_or_default(),
        }
    }

    /// Builds the flat basis of `hier` for the links whose receivers are `linked` and its
    /// section.
    pub fn build(hier: &IndexedBasis, linked: &[bool]) -> Result<FlatSection, FormatError> {
        let flat = FlatBasis::build(hier, Some(linked))?;
        Ok(FlatSection::new(hier, linked, &flat))
    }
}

impl ArchivedFlatSection {
    /// The rule the section was built by.
    pub fn rule(&self) -> FlatRule {
        FlatRule {
            neighbours: self.rule.neighbours.to_native(),
            radius_factor: self.rule.radius_factor.to_native(),
            hole_weight: self.rule.hole_weight.to_native(),
            hole_reach: self.rule.hole_reach.to_native(),
            finer_cover: self.rule.finer_cover.to_native(),
        }
    }

    /// The flat basis this section stores, checked against the hierarchical basis `hier` and
    /// link flags `linked` of the same file. `Err` carries what is inconsistent.
    pub fn flat_basis(&self, hier: &IndexedBasis, linked: &[bool]) -> Result<FlatBasis, String> {
        let n = hier.basis.len();
        let points = self.points.to_native() as usize;
        if points != n {
            return Err(format!(
                "built on {points} hierarchical points, the file's basis has {n}"
            ));
        }
        if self.linked_key.to_native() != linked_key(linked) {
            return Err("built for other linked receivers than the file's links".into());
        }
        let source: Vec<u32> = self.source.iter().map(|s| s.to_native()).collect();
        let radii: Vec<f32> = self.radii.iter().map(|r| r.to_native()).collect();
        if radii.len() != source.len() {
            return Err(format!(
                "{} radii for {} flat points",
                radii.len(),
                source.len()
            ));
        }
        let mut seen = vec![false; n];
        for &j in &source {
            match seen.get_mut(j as usize) {
                None => return Err(format!("flat point {j} out of range (0..{n})")),
                Some(true) => return Err(format!("flat point {j} repeated")),
                Some(s) => *s = true,
            }
        }
        if let Some(r) = radii.iter().find(|r| !(r.is_finite() && **r > 0.0)) {
            return Err(format!("flat radius {r} not finite and positive"));
        }
        let tree: RTree = rkyv::deserialize::<RTree, rkyv::rancor::Error>(&self.tree)
            .map_err(|e| format!("R-tree: {e}"))?;
        FlatBasis::from_parts_with_tree(hier, source, radii, tree).map_err(|e| e.to_string())
    }
}

/// The rule of a format 1.5 `FLAT` section: [`FlatRule`] without `finer_cover` (every needed
/// point was kept).
#[derive(Clone, Copy, Debug, PartialEq, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct FlatRule1_5 {
    pub neighbours: u32,
    pub radius_factor: f32,
    pub hole_weight: f32,
    pub hole_reach: f32,
}

/// The layout of the `FLAT` section in format 1.5, read for its rule only.
#[derive(Clone, Debug, PartialEq, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct FlatSection1_5 {
    pub points: u32,
    pub linked_key: u64,
    pub rule: FlatRule1_5,
    pub source: Vec<u32>,
    pub radii: Vec<f32>,
    pub tree: RTree,
}

#[cfg(any(test, feature = "test-support"))]
impl FlatSection1_5 {
    /// `section` as format 1.5 stored it (its rule less `finer_cover`); for tests of readers.
    pub fn from_current(section: &FlatSection) -> FlatSection1_5 {
        let r = section.rule;
        FlatSection1_5 {
            points: section.points,
            linked_key: section.linked_key,
            rule: FlatRule1_5 {
                neighbours: r.neighbours,
                radius_factor: r.radius_factor,
                hole_weight: r.hole_weight,
                hole_reach: r.hole_reach,
            },
            source: section.source.clone(),
            radii: section.radii.clone(),
            tree: section.tree.clone(),
        }
    }

    /// The section's bytes as format 1.5 stored them under `FLAT`; for tests of readers.
    pub fn archive(&self) -> Result<Vec<u8>, FormatError> {
        rkyv::to_bytes::<rkyv::rancor::Error>(self)
            .map(|b| b.to_vec())
            .map_err(|e| FormatError::Serialize {
                tag: "FLAT".into(),
                detail: e.to_string(),
            })
    }
}

impl ArchivedFlatSection1_5 {
    /// The section's rule as a [`FlatRule`]: `finer_cover` 0, since format 1.5 kept every
    /// needed point.
    pub fn rule(&self) -> FlatRule {
        FlatRule {
            neighbours: self.rule.neighbours.to_native(),
            radius_factor: self.rule.radius_factor.to_native(),
            hole_weight: self.rule.hole_weight.to_native(),
            hole_reach: self.rule.hole_reach.to_native(),
            finer_cover: 0.0,
        }
    }
}
