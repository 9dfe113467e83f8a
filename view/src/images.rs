//! Image outputs: linear HDR radiance as OpenEXR (float RGB) and a tone-mapped PNG for people
//! (Reinhard et al. 2002, global operator). Files are written atomically.

use std::io::Cursor;
use std::path::Path;

/// Errors writing or reading images.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("{path}: {msg}")]
    Encode { path: String, msg: String },
    #[error(transparent)]
    Format(#[from] mlt_format::FormatError),
}

/// A linear RGB float image, rows from the top.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbImage {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<[f32; 3]>,
}

/// Rec. 709 luminance of linear RGB.
pub fn luminance(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

impl RgbImage {
    pub fn new(width: u32, height: u32) -> RgbImage {
        RgbImage {
            width,
            height,
            pixels: vec![[0.0; 3]; width as usize * height as usize],
        }
    }

    pub fn get(&self, x: u32, y: u32) -> [f32; 3] {
        self.pixels[y as usize * self.width as usize + x as usize]
    }

    /// True when every channel of every pixel is finite.
    pub fn all_finite(&self) -> bool {
        self.pixels.iter().flatten().all(|v| v.is_finite())
    }

    /// Pixel-wise sum.
    pub fn add(&self, other: &RgbImage) -> RgbImage {
        let pixels = self
            .pixels
            .iter()
            .zip(&other.pixels)
            .map(|(a, b)| [a[0] + b[0], a[1] + b[1], a[2] + b[2]])
            .collect();
        RgbImage {
            width: self.width,
            height: self.height,
            pixels,
        }
    }

    /// Writes a float RGB OpenEXR file (linear radiance).
    pub fn write_exr(&self, path: &Path) -> Result<(), ImageError> {
        let err = |msg: String| ImageError::Encode {
            path: path.display().to_string(),
            msg,
        };
        let data: Vec<f32> = self.pixels.iter().flatten().copied().collect();
        let img = image::Rgb32FImage::from_raw(self.width, self.height, data)
            .ok_or_else(|| err("pixel count does not match the size".into()))?;
        let mut bytes = Cursor::new(Vec::new());
        image::DynamicImage::ImageRgb32F(img)
            .write_to(&mut bytes, image::ImageFormat::OpenExr)
            .map_err(|e| err(e.to_string()))?;
        mlt_format::file::write_atomic(path, bytes.get_ref())?;
        Ok(())
    }

    /// Reads a float RGB OpenEXR file.
    pub fn read_exr(path: &Path) -> Result<RgbImage, ImageError> {
        let err = |msg: String| ImageError::Encode {
            path: path.display().to_string(),
            msg,
        };
        let img = image::ImageReader::open(path)
            .map_err(|e| err(e.to_string()))?
            .with_guessed_format()
            .map_err(|e| err(e.to_string()))?
            .decode()
            .map_err(|e| err(e.to_string()))?
            .to_rgb32f();
        let (width, height) = img.dimensions();
        let pixels = img
            .into_raw()
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        Ok(RgbImage {
            width,
            height,
            pixels,
        })
    }

    /// Writes the image tone-mapped with [`reinhard`] and sRGB-encoded as an 8-bit PNG.
    pub fn write_png(&self, path: &Path) -> Result<(), ImageError> {
        let err = |msg: String| ImageError::Encode {
            path: path.display().to_string(),
            msg,
        };
        let mapped = reinhard(self);
        let bytes: Vec<u8> = mapped
            .pixels
            .iter()
            .flatten()
            .map(|&v| (linear_to_srgb(v) * 255.0 + 0.5).clamp(0.0, 255.0) as u8)
            .collect();
        let img = image::RgbImage::from_raw(self.width, self.height, bytes)
            .ok_or_else(|| err("pixel count does not match the size".into()))?;
        let mut out = Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Png)
            .map_err(|e| err(e.to_string()))?;
        mlt_format::file::write_atomic(path, out.get_ref())?;
        Ok(())
    }
}

/// The parameters of the global operator for an image: key 0.18, the log-average luminance
/// and the white point (the largest luminance), Reinhard et al. 2002 Eqs. 1-4.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ToneMap {
    pub key: f32,
    pub log_average: f32,
    pub white: f32,
}

impl ToneMap {
    /// Measures the image (pixels with zero luminance are ignored, so a black background does
    /// not darken the key).
    pub fn measure(img: &RgbImage) -> ToneMap {
        let (mut sum, mut n, mut white) = (0.0f64, 0usize, 0.0f32);
        for &p in &img.pixels {
            let l = luminance(p);
            if l.is_finite() && l > 0.0 {
                sum += (1e-6 + l as f64).ln();
                n += 1;
                white = white.max(l);
            }
        }
        let log_average = if n == 0 {
            1.0
        } else {
            (sum / n as f64).exp() as f32
        };
        ToneMap {
            key: 0.18,
            log_average,
            white,
        }
    }

    /// Display luminance scale for a pixel of luminance `l` (Eq. 4: `Ld = L (1 + L/Lw^2) /
    /// (1 + L)` with `L = key / log_average * l`).
    pub fn scale(&self, l: f32) -> f32 {
        if l.is_nan() || l <= 0.0 || !l.is_finite() {
            return 0.0;
        }
        let k = self.key / self.log_average.max(f32::MIN_POSITIVE);
        let lm = k * l;
        let lw = (k * self.white).max(f32::MIN_POSITIVE);
        let ld = lm * (1.0 + lm / (lw * lw)) / (1.0 + lm);
        ld / l
    }
}

/// Reinhard 2002 global tone mapping applied to luminance, colours kept in proportion.
pub fn reinhard(img: &RgbImage) -> RgbImage {
    let tm = ToneMap::measure(img);
    let pixels = img
        .pixels
        .iter()
        .map(|&p| {
            let s = tm.scale(luminance(p));
            [
                (p[0] * s).clamp(0.0, 1.0),
                (p[1] * s).clamp(0.0, 1.0),
                (p[2] * s).clamp(0.0, 1.0),
            ]
        })
        .collect();
    RgbImage {
        width: img.width,
        height: img.height,
        pixels,
    }
}

/// The sRGB transfer function.
pub fn linear_to_srgb(v: f32) -> f32 {
    if v.is_nan() || v <= 0.0 {
        0.0
    } else if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn white_point_maps_to_one_and_order_is_kept() {
        let mut img = RgbImage::new(3, 1);
        img.pixels = vec![[0.1; 3], [1.0; 3], [10.0; 3]];
        let tm = ToneMap::measure(&img);
        // Eq. 4 maps the white point to exactly 1.
        assert!((10.0 * tm.scale(10.0) - 1.0).abs() < 1e-5);
        let out = reinhard(&img);
        assert!(out.pixels[0][0] < out.pixels[1][0] && out.pixels[1][0] < out.pixels[2][0]);
        assert_eq!(tm.scale(0.0), 0.0);
        assert_eq!(tm.scale(f32::NAN), 0.0);
    }

    #[test]
    fn exr_round_trips_exactly() {
        let dir = mlt_test_support::TempDir::new("images");
        let mut img = RgbImage::new(4, 3);
        for (k, p) in img.pixels.iter_mut().enumerate() {
            *p = [k as f32 * 0.125, 1e-3 * k as f32, 1e3 + k as f32];
        }
        let path = dir.join("a.exr");
        img.write_exr(&path).unwrap();
        assert_eq!(RgbImage::read_exr(&path).unwrap(), img);
        img.write_png(&dir.join("a.png")).unwrap();
        assert!(std::fs::metadata(dir.join("a.png")).unwrap().len() > 0);
    }
}
