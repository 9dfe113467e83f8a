//! The scene's light prepared for evaluation: a point or spot light of RGB radiant intensity
//! `I` (W/sr) whose direct irradiance is `E = I max(0, cos) / d^2 V`, inside the spot's cone.
//!
//! The light is described by [`LightDesc`] ([`crate::light`]), from the manifest to the file;
//! [`Light`] is built from that description once (checked, the cone's cosines precomputed)
//! and is what the bake's estimates, the relighting, the renderer and the reference evaluate.

use crate::light::{LightDesc, LightKind, SpotFalloff};
use crate::meta::LightInfo;
use glam::Vec3;

/// How a spot light's intensity falls off towards the edge of its cone.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Cone {
    /// A point light: no cone.
    None,
    /// Full intensity within `half_angle` of the axis, none beyond.
    Hard { axis: Vec3, cos_half: f32 },
    /// glTF KHR_lights_punctual: smooth between the inner and outer half angles.
    Smooth {
        axis: Vec3,
        cos_inner: f32,
        cos_outer: f32,
    },
}

/// A light in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    pub position: Vec3,
    pub intensity: [f32; 3],
    pub cone: Cone,
}

/// Why a light is unusable.
#[derive(Debug, thiserror::Error)]
#[error("invalid light: {0}")]
pub struct LightError(pub String);

impl Light {
    /// A point light.
    pub fn point(position: Vec3, intensity: [f32; 3]) -> Result<Light, LightError> {
        Light::new(position, intensity, Cone::None)
    }

    /// A spot light with full cone angle `cone_deg` along `direction`.
    pub fn spot(
        position: Vec3,
        intensity: [f32; 3],
        direction: Vec3,
        cone_deg: f32,
        smooth: bool,
    ) -> Result<Light, LightError> {
        let axis = direction.normalize_or_zero();
        if axis == Vec3::ZERO || !axis.is_finite() {
            return Err(LightError(format!(
                "spot direction {direction} has no length"
            )));
        }
        if !(cone_deg > 0.0 && cone_deg < 180.0) {
            return Err(LightError(format!(
                "spot cone {cone_deg} degrees is not in (0, 180)"
            )));
        }
        let outer = (cone_deg * 0.5).to_radians();
        let cone = if smooth {
            // The manifest's convention: the inner cone is half the outer one.
            Cone::Smooth {
                axis,
                cos_inner: (outer * 0.5).cos(),
                cos_outer: outer.cos(),
            }
        } else {
            Cone::Hard {
                axis,
                cos_half: outer.cos(),
            }
        };
        Light::new(position, intensity, cone)
    }

    fn new(position: Vec3, intensity: [f32; 3], cone: Cone) -> Result<Light, LightError> {
        if !position.is_finite() {
            return Err(LightError(format!("position {position} is not finite")));
        }
        if intensity.iter().any(|c| !c.is_finite() || *c < 0.0) {
            return Err(LightError(format!(
                "intensity {intensity:?} must be finite and non-negative"
            )));
        }
        Ok(Light {
            position,
            intensity,
            cone,
        })
    }

    /// The light a description gives (a spot without an axis points down; without a cone
    /// it is refused).
    pub fn from_desc(l: &LightDesc) -> Result<Light, LightError> {
        match l.kind {
            LightKind::Point => Light::point(l.position.into(), l.intensity),
            LightKind::Spot => Light::spot(
                l.position.into(),
                l.intensity,
                l.direction.unwrap_or([0.0, -1.0, 0.0]).into(),
                l.cone_deg.unwrap_or(0.0),
                l.falloff == SpotFalloff::Smooth,
            ),
        }
    }

    /// The light stored in a baked file; an unknown kind or falloff is an error naming it.
    pub fn from_info(info: &LightInfo) -> Result<Light, LightError> {
        let desc = LightDesc::try_from(info).map_err(|e| LightError(e.to_string()))?;
        Light::from_desc(&desc)
    }

    /// Unoccluded direct irradiance at the surface point `(x, n)`, per colour channel.
    pub fn irradiance(&self, x: Vec3, n: Vec3) -> [f32; 3] {
        let d = self.position - x;
        let d2 = d.length_squared();
        if d2.is_nan() || d2 <= 0.0 {
            // A point on the light itself: no defined direction; no light.
            return [0.0; 3];
        }
        let l = d / d2.sqrt();
        let cos = n.dot(l).max(0.0);
        let spot = self.cone_factor(-l);
        let k = cos * spot / d2;
        [
            self.intensity[0] * k,
            self.intensity[1] * k,
            self.intensity[2] * k,
        ]
    }

    /// The fraction of the intensity emitted along the unit direction `dir` (from the light):
    /// 1 for a point light, the cone's falloff for a spot.
    pub fn cone_factor(&self, dir: Vec3) -> f32 {
        match self.cone {
            Cone::None => 1.0,
            Cone::Hard { axis, cos_half } => {
                if axis.dot(dir) >= cos_half {
                    1.0
                } else {
                    0.0
                }
            }
            Cone::Smooth {
                axis,
                cos_inner,
                cos_outer,
            } => {
                let scale = 1.0 / (cos_inner - cos_outer).max(1e-3);
                let t = ((axis.dot(dir) - cos_outer) * scale).clamp(0.0, 1.0);
                t * t
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_square_and_cosine() {
        let l = Light::point(Vec3::new(0.0, 2.0, 0.0), [4.0, 8.0, 0.0]).unwrap();
        let e = l.irradiance(Vec3::ZERO, Vec3::Y);
        assert_eq!(e, [1.0, 2.0, 0.0]);
        let tilted = Vec3::new(1.0, 1.0, 0.0).normalize();
        let e2 = l.irradiance(Vec3::ZERO, tilted);
        assert!((e2[0] - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-6);
        assert_eq!(l.irradiance(Vec3::ZERO, -Vec3::Y), [0.0; 3]);
        assert_eq!(l.irradiance(Vec3::new(0.0, 2.0, 0.0), Vec3::Y), [0.0; 3]);
    }

    #[test]
    fn spot_cones() {
        let hard = Light::spot(Vec3::Y, [1.0; 3], -Vec3::Y, 60.0, false).unwrap();
        assert!(hard.irradiance(Vec3::ZERO, Vec3::Y)[0] > 0.0);
        // 45 degrees off the axis is outside a 60-degree cone.
        assert_eq!(hard.irradiance(Vec3::new(1.0, 0.0, 0.0), Vec3::Y)[0], 0.0);
        let smooth = Light::spot(Vec3::Y, [1.0; 3], -Vec3::Y, 60.0, true).unwrap();
        // On the axis: full; between inner (15) and outer (30 degrees): partial.
        assert!((smooth.irradiance(Vec3::ZERO, Vec3::Y)[0] - 1.0).abs() < 1e-6);
        let x = (22.5f32).to_radians().tan();
        let partial = smooth.irradiance(Vec3::new(x, 0.0, 0.0), Vec3::Y)[0];
        let full = hard.irradiance(Vec3::new(x, 0.0, 0.0), Vec3::Y)[0];
        assert!(partial > 0.0 && partial < full);
        assert!(Light::spot(Vec3::Y, [1.0; 3], Vec3::ZERO, 60.0, false).is_err());
        assert!(Light::spot(Vec3::Y, [1.0; 3], Vec3::Y, 180.0, false).is_err());
        assert!(Light::point(Vec3::new(f32::NAN, 0.0, 0.0), [1.0; 3]).is_err());
        assert!(Light::point(Vec3::ZERO, [1.0, f32::INFINITY, 0.0]).is_err());
    }

    #[test]
    fn a_stored_light_evaluates_like_its_description() {
        let desc = LightDesc {
            kind: LightKind::Spot,
            position: [0.0, 1.0, 0.0],
            intensity: [1.0, 2.0, 3.0],
            direction: Some([0.0, -2.0, 0.0]),
            cone_deg: Some(60.0),
            falloff: SpotFalloff::Smooth,
        };
        let stored = Light::from_info(&LightInfo::from(&desc)).unwrap();
        assert_eq!(stored, Light::from_desc(&desc).unwrap());
        assert!(matches!(stored.cone, Cone::Smooth { .. }));
        let mut info = LightInfo::from(&desc);
        info.kind = "area".into();
        let e = Light::from_info(&info).unwrap_err().to_string();
        assert!(e.contains("'area'"), "{e}");
    }
}
