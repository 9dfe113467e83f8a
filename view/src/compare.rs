//! Error of a rendering against the brute-force reference of [`crate::reference`].
//!
//! All measures are on Rec. 709 luminance `L` of linear radiance (images) or irradiance
//! (probes), over the `N` pixels (probes) of the reference `r` and the test `t`:
//!
//! - relative RMSE: `sqrt(mean (L_t − L_r)²) / mean L_r`;
//! - mean relative error over lit pixels: `mean_{lit} |L_t − L_r| / L_r`, where a pixel is *lit*
//!   when `L_r > LIT_FRACTION · mean L_r` ([`LIT_FRACTION`] = 1 %: black background and deep
//!   shadow, where a relative error means nothing, are left out);
//! - ratio of means: `mean L_t / mean L_r` (1 when the energy is right).
//!
//! - by blocks of [`BLOCK`] x [`BLOCK`] pixels (images only, [`Blocks`]): the relative RMSE
//!   of the block means, `sqrt(mean_b (m_t,b − m_r,b)²) / mean L_r`, and the smallest and the
//!   largest ratio `m_t,b / m_r,b` over the lit blocks (`m_r,b > LIT_FRACTION · mean L_r`): a
//!   seam or a leak a few pixels wide shows there while the image's means hide it, and the
//!   reference's noise mostly averages out.
//!
//! The reference's own noise gives a floor under the first two: with `ν` its per-pixel noise
//! (the signed `(A − B)/2` of `reference_noise.exr`, or a probe's standard error `σ`), an exact
//! test image would still show a relative RMSE of `sqrt(mean ν²) / mean L_r` and a mean
//! relative error of `mean_{lit} |ν| / L_r` (for probes `sqrt(2/π) σ / L_r`, the mean absolute
//! value of a normal deviate). Errors well above the floor are the test's.

use std::path::{Path, PathBuf};

use crate::images::{luminance, ImageError, RgbImage};

/// Pixels whose reference luminance is below this fraction of the mean are not *lit*.
pub const LIT_FRACTION: f64 = 0.01;

/// Side of the blocks of [`Blocks`], in pixels.
pub const BLOCK: u32 = 16;

/// The error by blocks of [`BLOCK`] x [`BLOCK`] pixels (module docs); the last row and column
/// of blocks may be narrower.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Blocks {
    pub relative_rmse: f64,
    pub ratio_min: f64,
    pub ratio_max: f64,
    pub blocks: usize,
    pub lit: usize,
    /// The largest pixel of the test and of the reference (a sealed room's leak shows in the
    /// first where the second is black).
    pub test_max: f64,
    pub reference_max: f64,
}

/// [`Blocks`] of the luminances `reference` and `test` of a `width` x `height` image.
pub fn blocks(reference: &[f64], test: &[f64], width: u32, height: u32) -> Blocks {
    let (w, h) = (width as usize, height as usize);
    let n = (w * h).min(reference.len()).min(test.len());
    let mean = reference[..n].iter().sum::<f64>() / n.max(1) as f64;
    let b = BLOCK as usize;
    let (bw, bh) = (w.div_ceil(b), h.div_ceil(b));
    let mut out = Blocks {
        relative_rmse: 0.0,
        ratio_min: f64::INFINITY,
        ratio_max: 0.0,
        blocks: bw * bh,
        lit: 0,
        test_max: test[..n].iter().fold(0.0f64, |m, &v| m.max(v)),
        reference_max: reference[..n].iter().fold(0.0f64, |m, &v| m.max(v)),
    };
    let mut se = 0.0;
    for by in 0..bh {
        for bx in 0..bw {
            let (mut r, mut t, mut count) = (0.0, 0.0, 0usize);
            for y in by * b..((by + 1) * b).min(h) {
                for x in bx * b..((bx + 1) * b).min(w) {
                    let k = y * w + x;
                    if k < n {
                        r += reference[k];
                        t += test[k];
                        count += 1;
                    }
                }
            }
            if count == 0 {
                continue;
            }
            let (r, t) = (r / count as f64, t / count as f64);
            se += (t - r) * (t - r);
            if r > LIT_FRACTION * mean && r > 0.0 {
                out.lit += 1;
                out.ratio_min = out.ratio_min.min(t / r);
                out.ratio_max = out.ratio_max.max(t / r);
            }
        }
    }
    if out.lit == 0 {
        out.ratio_min = 0.0;
    }
    if mean > 0.0 && out.blocks > 0 {
        out.relative_rmse = (se / out.blocks as f64).sqrt() / mean;
    }
    out
}

/// What can go wrong comparing.
#[derive(Debug, thiserror::Error)]
pub enum CompareError {
    #[error("{path}: missing (expected {what})")]
    Missing { path: PathBuf, what: String },
    #[error("{test}: size {tw}x{th} differs from the reference {reference} ({rw}x{rh})")]
    Size {
        test: PathBuf,
        reference: PathBuf,
        tw: u32,
        th: u32,
        rw: u32,
        rh: u32,
    },
    #[error("{path}: pixel ({x}, {y}) is not finite ({value:?})")]
    NotFinite {
        path: PathBuf,
        x: u32,
        y: u32,
        value: [f32; 3],
    },
    #[error("{path}: {msg}")]
    Csv { path: PathBuf, msg: String },
    #[error(transparent)]
    Image(#[from] ImageError),
}

/// Error measures of one test image (or probe set) against the reference (module docs).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Metrics {
    pub relative_rmse: f64,
    pub mean_relative_error_lit: f64,
    pub ratio_of_means: f64,
    pub reference_mean: f64,
    pub test_mean: f64,
    pub samples: usize,
    pub lit: usize,
    /// The floor the reference's own noise puts under `relative_rmse` and
    /// `mean_relative_error_lit` (None when the noise is not known).
    pub noise_relative_rmse: Option<f64>,
    pub noise_mean_relative_error_lit: Option<f64>,
}

/// Compares luminances `test` against `reference`, with the reference's per-sample noise
/// magnitude `noise` (`|ν|` or `sqrt(2/π) σ`, and `ν²` for the RMS as `noise_sq`) if known.
pub fn metrics(
    reference: &[f64],
    test: &[f64],
    noise_abs: Option<&[f64]>,
    noise_sq: Option<&[f64]>,
) -> Metrics {
    let n = reference.len().min(test.len());
    let nf = n.max(1) as f64;
    let ref_mean = reference[..n].iter().sum::<f64>() / nf;
    let test_mean = test[..n].iter().sum::<f64>() / nf;
    let se = reference[..n]
        .iter()
        .zip(&test[..n])
        .map(|(r, t)| (t - r) * (t - r))
        .sum::<f64>()
        / nf;
    let threshold = LIT_FRACTION * ref_mean;
    let lit: Vec<usize> = (0..n)
        .filter(|&k| reference[k] > threshold && reference[k] > 0.0)
        .collect();
    let div = |a: f64, b: f64| if b > 0.0 { a / b } else { 0.0 };
    let mrel = div(
        lit.iter()
            .map(|&k| (test[k] - reference[k]).abs() / reference[k])
            .sum::<f64>(),
        lit.len() as f64,
    );
    Metrics {
        relative_rmse: div(se.sqrt(), ref_mean),
        mean_relative_error_lit: mrel,
        ratio_of_means: div(test_mean, ref_mean),
        reference_mean: ref_mean,
        test_mean,
        samples: n,
        lit: lit.len(),
        noise_relative_rmse: noise_sq
            .map(|q| div((q[..n].iter().sum::<f64>() / nf).sqrt(), ref_mean)),
        noise_mean_relative_error_lit: noise_abs.map(|a| {
            div(
                lit.iter().map(|&k| a[k] / reference[k]).sum::<f64>(),
                lit.len() as f64,
            )
        }),
    }
}

fn lum(img: &RgbImage) -> Vec<f64> {
    img.pixels.iter().map(|p| luminance(*p) as f64).collect()
}

fn check_finite(path: &Path, img: &RgbImage) -> Result<(), CompareError> {
    if let Some(k) = img
        .pixels
        .iter()
        .position(|p| !p.iter().all(|v| v.is_finite()))
    {
        return Err(CompareError::NotFinite {
            path: path.to_path_buf(),
            x: (k % img.width.max(1) as usize) as u32,
            y: (k / img.width.max(1) as usize) as u32,
            value: img.pixels[k],
        });
    }
    Ok(())
}

/// Reads an EXR, naming the file when it is missing or not finite.
fn read(path: &Path, what: &str) -> Result<RgbImage, CompareError> {
    if !path.is_file() {
        return Err(CompareError::Missing {
            path: path.to_path_buf(),
            what: what.to_string(),
        });
    }
    let img = RgbImage::read_exr(path)?;
    check_finite(path, &img)?;
    Ok(img)
}

/// The first of `names` that exists in `dir` (or the first name, for the error message).
fn pick(dir: &Path, names: &[&str]) -> PathBuf {
    names
        .iter()
        .map(|n| dir.join(n))
        .find(|p| p.is_file())
        .unwrap_or_else(|| dir.join(names[0]))
}

/// Compares a test image with the reference image and, if given, the reference's signed
/// noise image (same size as the reference).
pub fn compare_images(reference: &RgbImage, test: &RgbImage, noise: Option<&RgbImage>) -> Metrics {
    let nl = noise.map(lum);
    let abs: Option<Vec<f64>> = nl.as_ref().map(|v| v.iter().map(|x| x.abs()).collect());
    let sq: Option<Vec<f64>> = nl.as_ref().map(|v| v.iter().map(|x| x * x).collect());
    metrics(&lum(reference), &lum(test), abs.as_deref(), sq.as_deref())
}

/// Comparison of a test directory against a reference directory.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DirComparison {
    pub reference_dir: PathBuf,
    pub test_dir: PathBuf,
    pub indirect: Metrics,
    pub final_image: Metrics,
    /// The indirect and final images' error by blocks.
    pub indirect_blocks: Blocks,
    pub final_blocks: Blocks,
    /// `reference.json`'s noise block, if present.
    pub reference_noise: Option<serde_json::Value>,
}

/// Compares `TEST_DIR/{indirect,final}.exr` (or, failing those, the `reference_*.exr` there:
/// two references can be compared) with `REF_DIR/reference_{indirect,final}.exr` (or
/// `{indirect,final}.exr`), using `REF_DIR/reference_noise.exr` for the noise floor if present.
pub fn compare_dirs(reference_dir: &Path, test_dir: &Path) -> Result<DirComparison, CompareError> {
    let mut out = Vec::new();
    let mut by_blocks = Vec::new();
    let noise_path = reference_dir.join("reference_noise.exr");
    let noise = if noise_path.is_file() {
        Some(read(&noise_path, "the reference's noise image")?)
    } else {
        None
    };
    for name in ["indirect", "final"] {
        let rp = pick(
            reference_dir,
            &[&format!("reference_{name}.exr"), &format!("{name}.exr")],
        );
        let tp = pick(
            test_dir,
            &[&format!("{name}.exr"), &format!("reference_{name}.exr")],
        );
        let r = read(&rp, &format!("the reference's {name} radiance"))?;
        let t = read(&tp, &format!("the {name} radiance to test"))?;
        let size_err = |path: &Path, w: u32, h: u32| CompareError::Size {
            test: path.to_path_buf(),
            reference: rp.clone(),
            tw: w,
            th: h,
            rw: r.width,
            rh: r.height,
        };
        if (t.width, t.height) != (r.width, r.height) {
            return Err(size_err(&tp, t.width, t.height));
        }
        if let Some(nz) = &noise {
            if (nz.width, nz.height) != (r.width, r.height) {
                return Err(size_err(&noise_path, nz.width, nz.height));
            }
        }
        out.push(compare_images(&r, &t, noise.as_ref()));
        by_blocks.push(blocks(&lum(&r), &lum(&t), r.width, r.height));
    }
    let reference_noise = std::fs::read_to_string(reference_dir.join("reference.json"))
        .ok()
        .and_then(|s| serde_json::from_str::<serde_json::Value>(&s).ok())
        .and_then(|v| v.get("noise").cloned());
    Ok(DirComparison {
        reference_dir: reference_dir.to_path_buf(),
        test_dir: test_dir.to_path_buf(),
        indirect: out[0],
        final_image: out[1],
        indirect_blocks: by_blocks[0],
        final_blocks: by_blocks[1],
        reference_noise,
    })
}

/// A probe CSV as columns by name.
struct Csv {
    header: Vec<String>,
    rows: Vec<Vec<f64>>,
}

impl Csv {
    fn read(path: &Path) -> Result<Csv, CompareError> {
        let err = |msg: String| CompareError::Csv {
            path: path.to_path_buf(),
            msg,
        };
        if !path.is_file() {
            return Err(CompareError::Missing {
                path: path.to_path_buf(),
                what: "a probe CSV".into(),
            });
        }
        let text = std::fs::read_to_string(path).map_err(|e| err(e.to_string()))?;
        let mut lines = text.lines().filter(|l| !l.trim().is_empty());
        let header: Vec<String> = lines
            .next()
            .ok_or_else(|| err("empty file".into()))?
            .split(',')
            .map(|s| s.trim().to_string())
            .collect();
        let mut rows = Vec::new();
        for (k, line) in lines.enumerate() {
            let row: Vec<f64> = line
                .split(',')
                .map(|s| s.trim().parse::<f64>())
                .collect::<Result<_, _>>()
                .map_err(|e| err(format!("data row {}: {e}", k + 1)))?;
            if row.len() != header.len() {
                return Err(err(format!(
                    "data row {} has {} fields, the header {}",
                    k + 1,
                    row.len(),
                    header.len()
                )));
            }
            if let Some(c) = row.iter().position(|v| !v.is_finite()) {
                return Err(err(format!(
                    "data row {}: {} is not finite",
                    k + 1,
                    header[c]
                )));
            }
            rows.push(row);
        }
        Ok(Csv { header, rows })
    }

    fn col(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h == name)
    }

    /// Luminance of the RGB columns `prefix_{r,g,b}`.
    fn lum(&self, path: &Path, prefix: &str) -> Result<Vec<f64>, CompareError> {
        let idx: Vec<usize> = ["r", "g", "b"]
            .iter()
            .map(|c| {
                self.col(&format!("{prefix}_{c}"))
                    .ok_or_else(|| CompareError::Csv {
                        path: path.to_path_buf(),
                        msg: format!("no column {prefix}_{c}"),
                    })
            })
            .collect::<Result<_, _>>()?;
        Ok(self
            .rows
            .iter()
            .map(|r| luminance([r[idx[0]] as f32, r[idx[1]] as f32, r[idx[2]] as f32]) as f64)
            .collect())
    }
}

/// Comparison of probe irradiances (test: `view --probe-out`; reference: the `reference`
/// binary's probe CSV with standard errors).
#[derive(Clone, Debug, serde::Serialize)]
pub struct ProbeComparison {
    pub reference: PathBuf,
    pub test: PathBuf,
    /// Indirect irradiance.
    pub indirect: Metrics,
    /// Direct + indirect irradiance (the final image's irradiance; the direct part is the
    /// test's own `direct` column).
    pub final_image: Metrics,
}

/// Compares two probe CSVs row by row (the probe positions must agree).
pub fn compare_probe_csv(reference: &Path, test: &Path) -> Result<ProbeComparison, CompareError> {
    let r = Csv::read(reference)?;
    let t = Csv::read(test)?;
    if r.rows.len() != t.rows.len() {
        return Err(CompareError::Csv {
            path: test.to_path_buf(),
            msg: format!(
                "{} probes, the reference {} has {}",
                t.rows.len(),
                reference.display(),
                r.rows.len()
            ),
        });
    }
    for name in ["x", "y", "z"] {
        let (Some(a), Some(b)) = (r.col(name), t.col(name)) else {
            return Err(CompareError::Csv {
                path: test.to_path_buf(),
                msg: format!("no column {name} here or in the reference"),
            });
        };
        for (k, (rr, tr)) in r.rows.iter().zip(&t.rows).enumerate() {
            let tol = 1e-4 * rr[a].abs().max(1.0);
            if (rr[a] - tr[b]).abs() > tol {
                return Err(CompareError::Csv {
                    path: test.to_path_buf(),
                    msg: format!(
                        "probe {} is at {name} = {}, the reference's at {}",
                        k + 1,
                        tr[b],
                        rr[a]
                    ),
                });
            }
        }
    }
    let (ri, ti) = (r.lum(reference, "indirect")?, t.lum(test, "indirect")?);
    let (rd, td) = (r.lum(reference, "direct")?, t.lum(test, "direct")?);
    let se = r
        .col("indirect_se_lum")
        .map(|c| r.rows.iter().map(|row| row[c]).collect::<Vec<f64>>());
    let abs: Option<Vec<f64>> = se.as_ref().map(|s| {
        s.iter()
            .map(|v| v * (2.0 / std::f64::consts::PI).sqrt())
            .collect()
    });
    let sq: Option<Vec<f64>> = se.as_ref().map(|s| s.iter().map(|v| v * v).collect());
    let rf: Vec<f64> = ri.iter().zip(&rd).map(|(a, b)| a + b).collect();
    let tf: Vec<f64> = ti.iter().zip(&td).map(|(a, b)| a + b).collect();
    Ok(ProbeComparison {
        reference: reference.to_path_buf(),
        test: test.to_path_buf(),
        indirect: metrics(&ri, &ti, abs.as_deref(), sq.as_deref()),
        final_image: metrics(&rf, &tf, abs.as_deref(), sq.as_deref()),
    })
}

/// One line for the measures by blocks.
pub fn format_blocks(name: &str, b: &Blocks) -> String {
    format!(
        "{name:>8} by {BLOCK}x{BLOCK} blocks: relative RMSE {:.4}, block ratios {:.3}-{:.3} ({} of {} blocks lit); largest pixel {:.4e} (reference {:.4e})",
        b.relative_rmse, b.ratio_min, b.ratio_max, b.lit, b.blocks, b.test_max, b.reference_max
    )
}

/// One line of text per measure.
pub fn format_metrics(name: &str, m: &Metrics) -> String {
    let floor = match (m.noise_relative_rmse, m.noise_mean_relative_error_lit) {
        (Some(a), Some(b)) => {
            format!("; reference noise floor: rel. RMSE {a:.4}, mean rel. error {b:.4}")
        }
        _ => String::new(),
    };
    format!(
        "{name:>8}: relative RMSE {:.4}, mean relative error (lit, {} of {}) {:.4}, ratio of means {:.4}{floor}",
        m.relative_rmse, m.lit, m.samples, m.mean_relative_error_lit, m.ratio_of_means
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_see_a_seam_that_the_means_hide() {
        // A 32x32 image of 1s; the test is 3x too bright in one 16x16 block and 0.5x in
        // another, so that the means nearly agree.
        let r = vec![1.0f64; 32 * 32];
        let mut t = r.clone();
        for y in 0..16 {
            for x in 0..16 {
                t[y * 32 + x] = 3.0;
                t[(y + 16) * 32 + x + 16] = 0.5;
            }
        }
        let b = blocks(&r, &t, 32, 32);
        assert_eq!((b.blocks, b.lit), (4, 4));
        assert_eq!((b.ratio_min, b.ratio_max), (0.5, 3.0));
        let want = ((4.0 + 0.25) / 4.0f64).sqrt();
        assert!(
            (b.relative_rmse - want).abs() < 1e-12,
            "{}",
            b.relative_rmse
        );
        // Partial blocks at the edges count as blocks; a black reference has no lit block.
        let b = blocks(&vec![1.0; 20 * 17], &vec![1.0; 20 * 17], 20, 17);
        assert_eq!((b.blocks, b.lit, b.relative_rmse), (4, 4, 0.0));
        let b = blocks(&[0.0; 4], &[1.0, 2.0, 0.5, 0.0], 2, 2);
        assert_eq!((b.lit, b.ratio_min, b.relative_rmse), (0, 0.0, 0.0));
        assert_eq!((b.test_max, b.reference_max), (2.0, 0.0));
    }

    #[test]
    fn metrics_of_a_scaled_image() {
        let r = vec![1.0, 2.0, 0.0, 4.0];
        let t: Vec<f64> = r.iter().map(|v| v * 1.5).collect();
        let m = metrics(&r, &t, None, None);
        assert!((m.ratio_of_means - 1.5).abs() < 1e-12);
        assert!((m.mean_relative_error_lit - 0.5).abs() < 1e-12);
        assert_eq!(m.lit, 3);
        let same = metrics(&r, &r, None, None);
        assert_eq!(same.relative_rmse, 0.0);
        assert_eq!(same.mean_relative_error_lit, 0.0);
        assert_eq!(same.ratio_of_means, 1.0);
        // A black reference gives zeros, not NaN.
        let z = metrics(&[0.0; 3], &[1.0; 3], None, None);
        assert!(z.relative_rmse == 0.0 && z.ratio_of_means == 0.0);
    }
}
