//! Probes: irradiance at given surface points for the current light, as CSV.
//!
//! Input rows are `x,y,z,nx,ny,nz` (a header line and `#` comments are skipped). Output rows
//! add, per colour channel: `direct` (exact: the light model with one shadow ray),
//! `direct_basis` (the direct light as the sender expansion `e` reconstructs it) and
//! `indirect` (`n . ` the indirect vector irradiance reconstructed from the receivers' `i`).

use std::path::Path;

use glam::Vec3;
use mlt_format::links::LINK_DIM;
use mlt_format::IndexedBasis;
use mlt_relight::{Frame, Light};
use mlt_scenes::RayCaster;

/// A probe point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Probe {
    pub position: Vec3,
    pub normal: Vec3,
}

/// What went wrong reading probes.
#[derive(Debug, thiserror::Error)]
pub enum ProbeError {
    #[error("{path}:{line}: {message}")]
    Row {
        path: std::path::PathBuf,
        line: usize,
        message: String,
    },
}

/// Parses probe rows; the normal is normalised.
pub fn parse_probes(path: &Path, text: &str) -> Result<Vec<Probe>, ProbeError> {
    let mut out = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let row = |message: String| ProbeError::Row {
            path: path.to_path_buf(),
            line: k + 1,
            message,
        };
        let nums: Result<Vec<f32>, _> = fields.iter().map(|f| f.parse::<f32>()).collect();
        let nums = match nums {
            Ok(v) => v,
            // A header (any non-numeric first row) is skipped.
            Err(_) if out.is_empty() && k == 0 => continue,
            Err(e) => return Err(row(format!("not a number: {e}"))),
        };
        if nums.len() != 6 {
            return Err(row(format!(
                "expected 6 values x,y,z,nx,ny,nz, found {}",
                nums.len()
            )));
        }
        if nums.iter().any(|v| !v.is_finite()) {
            return Err(row("a value is not finite".into()));
        }
        let normal = Vec3::new(nums[3], nums[4], nums[5]);
        if normal.length_squared() < 1e-12 {
            return Err(row("the normal has no length".into()));
        }
        out.push(Probe {
            position: Vec3::new(nums[0], nums[1], nums[2]),
            normal: normal.normalize(),
        });
    }
    Ok(out)
}

/// Irradiance at one probe: (direct, direct from the basis, indirect), RGB each.
pub fn evaluate(
    ib: &IndexedBasis,
    caster: &dyn RayCaster,
    light: &Light,
    frame: &Frame,
    sender_levels: usize,
    p: &Probe,
) -> [[f32; 3]; 3] {
    let (x, n) = (p.position.to_array(), p.normal.to_array());
    let mut direct = light.irradiance(p.position, p.normal);
    if direct != [0.0; 3]
        && caster.occluded(p.position + p.normal * caster.ray_epsilon(), light.position)
    {
        direct = [0.0; 3];
    }
    let mut db = [0.0f32; 3];
    ib.reconstruct(&frame.e, 3, 0..sender_levels, x, n, &mut db);
    let mut v = [0.0f32; LINK_DIM];
    ib.reconstruct(&frame.i, LINK_DIM, 0..ib.levels(), x, n, &mut v);
    let ind = std::array::from_fn(|c| n[0] * v[3 * c] + n[1] * v[3 * c + 1] + n[2] * v[3 * c + 2]);
    [direct, db, ind]
}

/// The output CSV.
pub fn to_csv(probes: &[Probe], values: &[[[f32; 3]; 3]]) -> String {
    let mut o = String::from(
        "x,y,z,nx,ny,nz,direct_r,direct_g,direct_b,direct_basis_r,direct_basis_g,direct_basis_b,indirect_r,indirect_g,indirect_b\n",
    );
    for (p, v) in probes.iter().zip(values) {
        let mut fields: Vec<String> = Vec::with_capacity(15);
        for c in p
            .position
            .to_array()
            .iter()
            .chain(p.normal.to_array().iter())
        {
            fields.push(format!("{c}"));
        }
        for group in v {
            for c in group {
                fields.push(format!("{c}"));
            }
        }
        o.push_str(&fields.join(","));
        o.push('\n');
    }
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_rows_skips_header_and_comments_and_names_bad_lines() {
        let p = Path::new("in.csv");
        let v = parse_probes(
            p,
            "x,y,z,nx,ny,nz\n# a comment\n1,2,3,0,0,2\n\n4, 5, 6, 1, 0, 0\n",
        )
        .unwrap();
        assert_eq!(v.len(), 2);
        assert_eq!(v[0].normal, Vec3::Z);
        let e = parse_probes(p, "1,2,3,0,0,1\n1,2,nan,0,0,1\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("in.csv:2") && e.contains("finite"), "{e}");
        let e = parse_probes(p, "1,2,3,0,0\n").unwrap_err().to_string();
        assert!(e.contains("expected 6"), "{e}");
        let e = parse_probes(p, "1,2,3,0,0,0\n").unwrap_err().to_string();
        assert!(e.contains("no length"), "{e}");
        let e = parse_probes(p, "1,2,3,0,0,1\n1,x,3,0,0,1\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("in.csv:2") && e.contains("not a number"), "{e}");
    }
}
