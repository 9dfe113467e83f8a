//! Basis functions' supports clipped at occluders: a function does not reach through a wall.
//!
//! The weight function of Eq. 8 is an ellipsoid around its point, flattened along the normal,
//! and knows nothing of the geometry inside it. Where a thin wall stands on a floor, a
//! function of the floor on one side reaches under the wall and has the same weight on the
//! floor of the other side as on its own (the normals agree): the paper's section 5.2 names
//! this as the method's limitation ("coarse supports may leak ... through a wall between
//! adjacent rooms"). Light projected onto such a sender in one room is then emitted in the
//! other.
//!
//! A clipped support is the ellipsoid less the space behind the occluders that the point
//! sees along its own surface. The bake casts a ring of rays from just above the point,
//! in its tangent plane, out to the support radius; consecutive rays that hit the same plane
//! make one [`ClipPlane`]: that plane, facing the point, and the wedge of azimuths its rays
//! covered. A surface point `x` is cut from the function when it lies behind the plane and
//! inside the wedge. Three dot products per plane, so the CPU's evaluations and a GPU shader
//! can share the test. The point itself is never behind one of its planes (the bake keeps
//! only planes with the point in front).
//!
//! A clipped weight is `w_j(x, n) [x not cut]`; the Shepard normalisation (Eq. 2) is over the
//! functions not cut, so a level still sums to one where any of its functions remains. The
//! test is conservative: a plane stands for the whole occluder behind its hit points, so a
//! low step cuts what lies beyond it even above its top, within the wedge.

use crate::error::FormatError;

/// One occluder of a point's support: `x` is cut when `plane . (x, 1) < 0` (behind the
/// occluding surface, which faces the point), `edge0 . (x, 1) >= 0` and
/// `edge1 . (x, 1) >= 0` (inside the wedge of azimuths, at most half a turn, whose rays found
/// that surface). The plane's constant already holds the tolerance, so a point on the
/// occluding surface itself is kept.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize,
)]
pub struct ClipPlane {
    pub plane: [f32; 4],
    pub edge0: [f32; 4],
    pub edge1: [f32; 4],
}

#[inline(always)]
fn eval(p: &[f32; 4], x: [f32; 3]) -> f32 {
    p[0] * x[0] + p[1] * x[1] + p[2] * x[2] + p[3]
}

impl ClipPlane {
    /// Whether `x` lies behind the occluder, inside its wedge.
    #[inline(always)]
    pub fn cuts(&self, x: [f32; 3]) -> bool {
        eval(&self.plane, x) < 0.0 && eval(&self.edge0, x) >= 0.0 && eval(&self.edge1, x) >= 0.0
    }
}

/// The clip planes of every point of a basis, as compressed rows: point `j`'s planes are
/// `planes[offsets[j]..offsets[j + 1]]`. Empty (no offsets) means no point is clipped, as in
/// files written before format 1.9; points past the end of `offsets` are not clipped either.
#[derive(Clone, Debug, Default, PartialEq, rkyv::Archive, rkyv::Serialize, rkyv::Deserialize)]
pub struct SupportClip {
    pub offsets: Vec<u32>,
    pub planes: Vec<ClipPlane>,
}

impl SupportClip {
    /// Builds the rows from each point's planes, in point order.
    pub fn from_rows<I, R>(rows: I) -> SupportClip
    where
        I: IntoIterator<Item = R>,
        R: AsRef<[ClipPlane]>,
    {
        let mut out = SupportClip {
            offsets: vec![0],
            planes: Vec::new(),
        };
        for r in rows {
            out.planes.extend_from_slice(r.as_ref());
            out.offsets.push(out.planes.len() as u32);
        }
        out
    }

    /// Whether no point is clipped.
    pub fn is_empty(&self) -> bool {
        self.planes.is_empty()
    }

    /// The points the rows cover.
    pub fn points(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Point `j`'s planes (none past the rows' end).
    #[inline]
    pub fn planes_of(&self, j: usize) -> &[ClipPlane] {
        if j + 1 >= self.offsets.len() {
            return &[];
        }
        &self.planes[self.offsets[j] as usize..self.offsets[j + 1] as usize]
    }

    /// Whether `x` is cut from point `j`'s support.
    #[inline]
    pub fn cuts(&self, j: usize, x: [f32; 3]) -> bool {
        if self.planes.is_empty() {
            return false;
        }
        self.planes_of(j).iter().any(|p| p.cuts(x))
    }

    /// Points with at least one plane.
    pub fn clipped_points(&self) -> usize {
        self.offsets.windows(2).filter(|w| w[1] > w[0]).count()
    }

    /// Checks the rows against a basis of `points` points: monotone offsets that end at the
    /// plane count, no more rows than points, finite planes.
    pub fn validate(&self, points: usize) -> Result<(), FormatError> {
        let bad = |m: String| Err(FormatError::InvalidBasis(format!("support clip: {m}")));
        if self.offsets.is_empty() {
            return if self.planes.is_empty() {
                Ok(())
            } else {
                bad(format!("{} planes without rows", self.planes.len()))
            };
        }
        if self.offsets[0] != 0 || self.offsets.windows(2).any(|w| w[1] < w[0]) {
            return bad("row offsets do not start at 0 and grow".into());
        }
        if *self.offsets.last().unwrap_or(&0) as usize != self.planes.len() {
            return bad(format!(
                "rows end at {} but there are {} planes",
                self.offsets.last().unwrap_or(&0),
                self.planes.len()
            ));
        }
        if self.points() > points {
            return bad(format!(
                "{} rows for a basis of {points} points",
                self.points()
            ));
        }
        let finite = |p: &[f32; 4]| p.iter().all(|c| c.is_finite());
        if let Some(k) = self
            .planes
            .iter()
            .position(|p| !(finite(&p.plane) && finite(&p.edge0) && finite(&p.edge1)))
        {
            return bad(format!("plane {k} is not finite"));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A wall at x = 0.01 facing -x, seen from the origin over the wedge of azimuths
    /// between -45 and +45 degrees about +x in the floor's plane (normal +y).
    fn wall() -> ClipPlane {
        let s = std::f32::consts::FRAC_1_SQRT_2;
        ClipPlane {
            plane: [-1.0, 0.0, 0.0, 0.01],
            // Directions at angle in [-45, 135] from +x about +y, and in [-135, 45].
            edge0: [s, 0.0, s, 0.0],
            edge1: [s, 0.0, -s, 0.0],
        }
    }

    #[test]
    fn a_plane_cuts_behind_it_inside_its_wedge_only() {
        let w = wall();
        assert!(w.cuts([0.5, 0.0, 0.0]), "behind, straight ahead");
        assert!(
            w.cuts([0.5, 1.0, 0.3]),
            "behind, above the floor, in the wedge"
        );
        assert!(!w.cuts([0.005, 0.0, 0.0]), "in front of the wall");
        assert!(!w.cuts([0.01, 0.0, 0.0]), "on the wall");
        assert!(
            !w.cuts([0.5, 0.0, 0.8]),
            "behind the plane but outside the wedge"
        );
        assert!(!w.cuts([-0.5, 0.0, 0.0]), "the other way");
    }

    #[test]
    fn rows_cut_only_their_own_point() {
        let c = SupportClip::from_rows([vec![], vec![wall()], vec![]]);
        assert_eq!((c.points(), c.clipped_points()), (3, 1));
        assert!(c.cuts(1, [0.5, 0.0, 0.0]));
        assert!(!c.cuts(0, [0.5, 0.0, 0.0]));
        assert!(!c.cuts(2, [0.5, 0.0, 0.0]));
        assert!(!c.cuts(7, [0.5, 0.0, 0.0]), "past the rows");
        assert!(!SupportClip::default().cuts(0, [0.5, 0.0, 0.0]));
        c.validate(3).unwrap();
        assert!(c.validate(2).is_err());
        let mut broken = c.clone();
        broken.planes[0].plane[3] = f32::NAN;
        assert!(broken.validate(3).is_err());
        let mut broken = c;
        broken.offsets[2] = 5;
        assert!(broken.validate(3).is_err());
        SupportClip::default().validate(0).unwrap();
    }
}
