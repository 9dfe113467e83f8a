//! The albedo check before any work: an albedo of 1 or more in a channel loses no energy, so
//! the bounce series `S = T + T^2 + ...` cannot converge and the level-0 paths never end by
//! themselves; such a scene is refused before the basis is placed, naming the material.
//!
//! A material's albedo is its colour (MTL `Kd`, glTF's base colour factor) times, when it is
//! textured, the mean of its texture per channel: what the surface reflects on average. A
//! texture whose brightest texels reach 1 under the colour while its mean stays below is
//! accepted (a white label on a wall loses energy around it) with a warning.

use mlt_scenes::{Geometry, Scene};

use crate::error::BakeError;

/// Whether an albedo loses energy in every channel: each below 1 (a NaN does not).
fn below_one(rgb: &[f32; 3]) -> bool {
    rgb.iter()
        .all(|a| a.partial_cmp(&1.0) == Some(std::cmp::Ordering::Less))
}

/// Refuses `scene` when a material that a triangle uses (or the analytic sphere) has an albedo
/// of 1 or more in a channel; returns warnings for textures whose brightest texels reach 1.
pub fn check_albedo(scene: &Scene) -> Result<Vec<String>, BakeError> {
    let refuse = |what: String, rgb: [f32; 3]| BakeError::AlbedoNotBelowOne {
        scene: scene.source.clone(),
        what,
        albedo: rgb,
    };
    let mesh = match &scene.geometry {
        Geometry::Sphere { albedo, .. } => {
            return if !below_one(albedo) {
                Err(refuse("the sphere".into(), *albedo))
            } else {
                Ok(Vec::new())
            };
        }
        Geometry::Mesh(m) => m,
    };
    let mut used = vec![false; mesh.materials.len()];
    for &m in &mesh.triangle_material {
        if let Some(u) = used.get_mut(m as usize) {
            *u = true;
        }
    }
    let mut warnings = Vec::new();
    for (material, _) in mesh.materials.iter().zip(&used).filter(|(_, u)| **u) {
        let texture = material.texture.and_then(|t| mesh.textures.get(t as usize));
        let (mean, brightest) = match texture {
            Some(t) => texture_mean_and_max(t.texels()),
            None => ([1.0; 3], [1.0; 3]),
        };
        let albedo: [f32; 3] = std::array::from_fn(|c| material.albedo[c] * mean[c]);
        if !below_one(&albedo) {
            let what = match texture {
                Some(_) => format!(
                    "material '{}' (colour times its texture's mean)",
                    material.name
                ),
                None => format!("material '{}'", material.name),
            };
            return Err(refuse(what, albedo));
        }
        let peak: [f32; 3] = std::array::from_fn(|c| material.albedo[c] * brightest[c]);
        if texture.is_some() && peak.iter().any(|a| *a >= 1.0) {
            warnings.push(format!(
                "{}: material '{}': its brightest texels reflect {peak:?} (1 or more; its mean {albedo:?} is below 1, so the bake goes on)",
                scene.source, material.name
            ));
        }
    }
    Ok(warnings)
}

/// The mean and the largest value per channel of `texels` (zero for an empty texture).
fn texture_mean_and_max(texels: impl ExactSizeIterator<Item = [f32; 3]>) -> ([f32; 3], [f32; 3]) {
    let n = texels.len().max(1) as f64;
    let (mut sum, mut max) = ([0.0f64; 3], [0.0f32; 3]);
    for t in texels {
        for c in 0..3 {
            sum[c] += f64::from(t[c]);
            max[c] = max[c].max(t[c]);
        }
    }
    (sum.map(|s| (s / n) as f32), max)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn builtin(spec: &str) -> Scene {
        mlt_scenes::load_scene(spec).unwrap()
    }

    #[test]
    fn an_albedo_of_one_is_refused_naming_it_and_one_below_is_not() {
        for spec in [
            "builtin:sphere?albedo=1.0",
            "builtin:sphere?albedo=0.5,1.2,0.5",
        ] {
            let e = check_albedo(&builtin(spec)).unwrap_err().to_string();
            assert!(e.contains("the sphere") && e.contains("albedo"), "{e}");
            assert!(e.starts_with(spec), "{e}");
        }
        assert!(check_albedo(&builtin("builtin:sphere?albedo=0.999")).is_ok());
        assert!(check_albedo(&builtin("builtin:cornell"))
            .unwrap()
            .is_empty());
        let e = check_albedo(&builtin("builtin:box?albedo=1"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("material"), "{e}");
    }

    #[test]
    fn a_texture_is_judged_by_its_mean_and_warned_of_by_its_brightest_texels() {
        let texels = [[1.0, 1.0, 1.0], [0.2, 0.4, 0.0]];
        let (mean, max) = texture_mean_and_max(texels.into_iter());
        assert_eq!(mean, [0.6, 0.7, 0.5]);
        assert_eq!(max, [1.0, 1.0, 1.0]);
        assert_eq!(
            texture_mean_and_max(std::iter::empty()),
            ([0.0; 3], [0.0; 3])
        );
    }
}
