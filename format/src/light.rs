//! The scene's light, described once from the manifest to the file: a point or spot light of
//! RGB radiant intensity `I` (W/sr). Its direct irradiance at a surface point at distance `d`
//! is `E = I max(0, cos) / d^2 V`, inside the spot's cone.
//!
//! [`LightDesc`] is the description a manifest or a built-in scene gives (TOML and JSON through
//! serde); the bake hashes its JSON into the input key. [`LightInfo`] is the form archived in a
//! file's `META` section, with its kind and falloff as strings; the two convert into each other
//! here and nowhere else.

use serde::{Deserialize, Serialize};

use crate::meta::LightInfo;

/// Whether the light radiates in every direction or within a cone.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LightKind {
    Point,
    Spot,
}

/// How a spot light's intensity falls off towards the edge of its cone.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SpotFalloff {
    /// Full intensity inside the cone, zero outside.
    #[default]
    Hard,
    /// glTF KHR_lights_punctual smooth falloff between the inner (`cone_deg / 2` by
    /// default) and outer cone angle.
    Smooth,
}

/// A point or spot light with RGB radiant intensity in W/sr.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightDesc {
    pub kind: LightKind,
    pub position: [f32; 3],
    pub intensity: [f32; 3],
    /// Spot axis (need not be unit length).
    #[serde(default)]
    pub direction: Option<[f32; 3]>,
    /// Spot full cone angle in degrees (outer cone).
    #[serde(default)]
    pub cone_deg: Option<f32>,
    #[serde(default)]
    pub falloff: SpotFalloff,
}

impl LightKind {
    /// The name stored in files and written in manifests.
    pub fn name(self) -> &'static str {
        match self {
            LightKind::Point => "point",
            LightKind::Spot => "spot",
        }
    }
}

impl SpotFalloff {
    /// The name stored in files and written in manifests.
    pub fn name(self) -> &'static str {
        match self {
            SpotFalloff::Hard => "hard",
            SpotFalloff::Smooth => "smooth",
        }
    }
}

/// A light stored in a file that this build cannot interpret.
#[derive(Debug, PartialEq, Eq, thiserror::Error)]
pub enum LightInfoError {
    #[error("unknown light kind '{0}' (expected 'point' or 'spot')")]
    Kind(String),
    #[error("unknown spot falloff '{0}' (expected 'hard' or 'smooth')")]
    Falloff(String),
}

impl From<&LightDesc> for LightInfo {
    /// The stored form: a spot's axis normalised, zero axis and cone for a point light.
    fn from(l: &LightDesc) -> LightInfo {
        let spot = l.kind == LightKind::Spot;
        LightInfo {
            kind: l.kind.name().into(),
            position: l.position,
            intensity: l.intensity,
            direction: match (spot, l.direction) {
                (true, Some(d)) => glam::Vec3::from(d).normalize_or_zero().to_array(),
                _ => [0.0; 3],
            },
            cone_deg: if spot { l.cone_deg.unwrap_or(0.0) } else { 0.0 },
            falloff: l.falloff.name().into(),
        }
    }
}

impl TryFrom<&LightInfo> for LightDesc {
    type Error = LightInfoError;

    /// The description of a stored light; a spot's axis and cone are `Some`, a point light's
    /// `None`.
    fn try_from(info: &LightInfo) -> Result<LightDesc, LightInfoError> {
        let kind = match info.kind.as_str() {
            "point" => LightKind::Point,
            "spot" => LightKind::Spot,
            other => return Err(LightInfoError::Kind(other.to_string())),
        };
        let falloff = match info.falloff.as_str() {
            "hard" => SpotFalloff::Hard,
            "smooth" => SpotFalloff::Smooth,
            other => return Err(LightInfoError::Falloff(other.to_string())),
        };
        let spot = kind == LightKind::Spot;
        Ok(LightDesc {
            kind,
            position: info.position,
            intensity: info.intensity,
            direction: spot.then_some(info.direction),
            cone_deg: spot.then_some(info.cone_deg),
            falloff,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spot() -> LightDesc {
        LightDesc {
            kind: LightKind::Spot,
            position: [0.5, 1.9, -0.25],
            intensity: [2.0, 1.5, 0.5],
            direction: Some([0.0, -1.0, 0.0]),
            cone_deg: Some(60.0),
            falloff: SpotFalloff::Smooth,
        }
    }

    fn point() -> LightDesc {
        LightDesc {
            kind: LightKind::Point,
            position: [0.0, 1.9, 0.0],
            intensity: [1.0; 3],
            direction: None,
            cone_deg: None,
            falloff: SpotFalloff::Hard,
        }
    }

    #[test]
    fn descriptions_round_trip_through_the_stored_form() {
        for l in [spot(), point()] {
            let info = LightInfo::from(&l);
            assert_eq!(LightDesc::try_from(&info), Ok(l));
        }
        let info = LightInfo::from(&spot());
        assert_eq!(info.kind, "spot");
        assert_eq!(info.falloff, "smooth");
        let info = LightInfo::from(&point());
        assert_eq!(
            (info.kind.as_str(), info.direction, info.cone_deg),
            ("point", [0.0; 3], 0.0)
        );
    }

    #[test]
    fn a_spot_axis_is_stored_normalised_and_a_point_light_ignores_one() {
        let mut l = spot();
        l.direction = Some([0.0, -3.0, 4.0]);
        assert_eq!(LightInfo::from(&l).direction, [0.0, -0.6, 0.8]);
        let mut p = point();
        p.direction = Some([1.0, 0.0, 0.0]);
        p.cone_deg = Some(30.0);
        let info = LightInfo::from(&p);
        assert_eq!((info.direction, info.cone_deg), ([0.0; 3], 0.0));
    }

    #[test]
    fn unknown_names_in_a_file_are_errors_naming_them() {
        let mut info = LightInfo::from(&spot());
        info.kind = "area".into();
        let e = LightDesc::try_from(&info).unwrap_err();
        assert_eq!(e, LightInfoError::Kind("area".into()));
        assert!(e.to_string().contains("'area'"), "{e}");
        let mut info = LightInfo::from(&spot());
        info.falloff = "linear".into();
        let e = LightDesc::try_from(&info).unwrap_err();
        assert!(e.to_string().contains("'linear'"), "{e}");
    }

    #[test]
    fn the_json_form_is_the_one_the_input_key_hashes() {
        let json = serde_json::to_string(&point()).unwrap();
        assert_eq!(
            json,
            r#"{"kind":"point","position":[0.0,1.9,0.0],"intensity":[1.0,1.0,1.0],"direction":null,"cone_deg":null,"falloff":"hard"}"#
        );
    }
}
