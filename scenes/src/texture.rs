//! Diffuse textures in linear RGB with bilinear, tiling lookup.
//!
//! # UV convention
//! [`Texture::sample`] uses the image-row convention of glTF: `(0, 0)` is the top-left corner
//! of the image (the first row stored in the file), `v` grows downwards. OBJ's convention is
//! the opposite (`v = 0` at the bottom), so the OBJ loader stores `(u, 1 - v)` in
//! [`crate::Mesh::uvs`]; the glTF loader stores UVs unchanged. UVs outside `[0, 1]` tile.
//!
//! # Storage
//! 8-bit sRGB images keep their bytes (3 per texel) and are decoded through a 256-entry table
//! when read: the same linear values as decoding them on load, from a quarter of the memory
//! of `[f32; 3]` texels (Sponza's 12 textures: 7.7 MB instead of 31). Other inputs (16-bit,
//! float, already linear) keep `f32`.

use std::path::Path;
use std::sync::LazyLock;

use glam::Vec2;

use crate::error::SceneError;

/// An RGB texture in linear colour space (8-bit sRGB input is decoded when read, see the
/// module docs). Built only through its constructors, so the texel count always matches
/// the size.
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    width: u32,
    height: u32,
    /// Row-major texels, first row at the top of the image (`v = 0`).
    texels: Texels,
}

/// How a texture's texels are stored.
#[derive(Clone, Debug, PartialEq)]
enum Texels {
    /// 8-bit sRGB-encoded, decoded by [`SRGB8`].
    Srgb8(Vec<[u8; 3]>),
    /// Linear.
    Linear(Vec<[f32; 3]>),
}

/// sRGB transfer function, decoded: encoded value in `[0, 1]` to linear.
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.040_45 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Linear values of the 256 8-bit sRGB codes.
static SRGB8: LazyLock<[f32; 256]> = LazyLock::new(|| {
    let mut table = [0.0; 256];
    for (i, t) in table.iter_mut().enumerate() {
        *t = srgb_to_linear(i as f32 / 255.0);
    }
    table
});

impl Texture {
    /// Builds a texture from already-linear texels; `None` if the size does not match or is 0.
    pub fn from_linear(width: u32, height: u32, texels: Vec<[f32; 3]>) -> Option<Texture> {
        let n = (width as usize).checked_mul(height as usize)?;
        if n == 0 || texels.len() != n || texels.iter().flatten().any(|c| !c.is_finite()) {
            return None;
        }
        Some(Texture {
            width,
            height,
            texels: Texels::Linear(texels),
        })
    }

    /// Builds a texture from 8-bit sRGB-encoded RGB triples (row-major, top row first);
    /// `None` if `rgb.len() != 3 * width * height` or the size is 0.
    pub fn from_rgb8(width: u32, height: u32, rgb: &[u8]) -> Option<Texture> {
        Self::from_srgb8_channels(width, height, rgb, 3)
    }

    /// Builds a texture from 8-bit sRGB-encoded pixels with `channels` interleaved channels
    /// (1 = grey, 2 = grey + alpha, 3 = RGB, 4 = RGBA; alpha is ignored).
    pub fn from_srgb8_channels(
        width: u32,
        height: u32,
        pixels: &[u8],
        channels: usize,
    ) -> Option<Texture> {
        let n = (width as usize).checked_mul(height as usize)?;
        if n == 0 || !(1..=4).contains(&channels) || pixels.len() != n.checked_mul(channels)? {
            return None;
        }
        let texels = pixels
            .chunks_exact(channels)
            .map(|p| {
                if channels < 3 {
                    [p[0]; 3]
                } else {
                    [p[0], p[1], p[2]]
                }
            })
            .collect();
        Some(Texture {
            width,
            height,
            texels: Texels::Srgb8(texels),
        })
    }

    /// Width in texels (at least 1).
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in texels (at least 1).
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Texel `i` (row-major from the top row) in linear RGB; panics past the last texel.
    #[inline]
    pub fn texel(&self, i: usize) -> [f32; 3] {
        match &self.texels {
            Texels::Srgb8(t) => {
                let table = &*SRGB8;
                t[i].map(|c| table[c as usize])
            }
            Texels::Linear(t) => t[i],
        }
    }

    /// The linear RGB texels, row-major from the top row.
    pub fn texels(&self) -> impl ExactSizeIterator<Item = [f32; 3]> + '_ {
        let n = (self.width as usize) * (self.height as usize);
        (0..n).map(move |i| self.texel(i))
    }

    /// Loads a PNG or JPEG file (sRGB-encoded) and converts it to linear RGB.
    pub fn load(path: &Path) -> Result<Texture, SceneError> {
        let bytes = std::fs::read(path).map_err(|e| SceneError::io(path, e))?;
        Self::decode(&bytes, path)
    }

    /// Decodes PNG or JPEG bytes (sRGB-encoded); `path` only names the source in errors.
    pub fn decode(bytes: &[u8], path: &Path) -> Result<Texture, SceneError> {
        let img = image::load_from_memory(bytes).map_err(|e| SceneError::Texture {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let (w, h) = (img.width(), img.height());
        let bad_size = || SceneError::Texture {
            path: path.to_path_buf(),
            message: format!("unusable image size {w}x{h}"),
        };
        let color = img.color();
        if color.bytes_per_pixel() / color.channel_count().max(1) >= 2 {
            // 16-bit (or float) input: decode sRGB at full precision.
            let rgb = img.to_rgb32f();
            let texels = rgb
                .pixels()
                .map(|p| [0, 1, 2].map(|c| srgb_to_linear(p.0[c].clamp(0.0, 1.0))))
                .collect();
            Self::from_linear(w, h, texels).ok_or_else(bad_size)
        } else {
            let rgb = img.to_rgb8();
            Self::from_rgb8(w, h, rgb.as_raw()).ok_or_else(bad_size)
        }
    }

    /// Bilinearly filtered linear RGB at `uv` (see the module docs for the convention);
    /// the texture repeats outside `[0, 1]`. Non-finite UVs sample the corner texel.
    pub fn sample(&self, uv: Vec2) -> [f32; 3] {
        let (w, h) = (self.width as usize, self.height as usize);
        let wrap01 = |x: f32| if x.is_finite() { x - x.floor() } else { 0.0 };
        // Texel centres sit at (i + 0.5) / size.
        let x = wrap01(uv.x) * w as f32 - 0.5;
        let y = wrap01(uv.y) * h as f32 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let wrap = |i: f32, n: usize| (i as i64).rem_euclid(n as i64) as usize;
        let (i0, i1) = (wrap(x0, w), wrap(x0 + 1.0, w));
        let (j0, j1) = (wrap(y0, h), wrap(y0 + 1.0, h));
        let [a, b, c, d] =
            [(i0, j0), (i1, j0), (i0, j1), (i1, j1)].map(|(i, j)| self.texel(j * w + i));
        let mut out = [0.0; 3];
        for k in 0..3 {
            let top = a[k] + (b[k] - a[k]) * fx;
            let bottom = c[k] + (d[k] - c[k]) * fx;
            out[k] = top + (bottom - top) * fy;
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_decoding_of_8bit_values() {
        let t = Texture::from_rgb8(1, 1, &[255, 128, 0]).expect("valid 1x1 texture");
        let c = t.sample(Vec2::new(0.3, 0.7));
        assert!((c[0] - 1.0).abs() < 1e-6, "{c:?}");
        assert!((c[1] - 0.2158).abs() < 1e-3, "{c:?}");
        assert_eq!(c[2], 0.0);
    }

    #[test]
    fn sampling_wraps_around() {
        // 2x1: left texel black, right texel white.
        let t = Texture::from_linear(2, 1, vec![[0.0; 3], [1.0; 3]]).expect("valid");
        // Texel centres: u = 0.25 (black) and 0.75 (white); tiled copies one period away.
        for k in [-3.0f32, -1.0, 0.0, 1.0, 5.0] {
            assert!(t.sample(Vec2::new(0.25 + k, 0.5))[0].abs() < 1e-5);
            assert!((t.sample(Vec2::new(0.75 + k, 0.5))[0] - 1.0).abs() < 1e-5);
        }
        // At u = 0 the filter straddles the seam: halfway between the last and first texel.
        assert!((t.sample(Vec2::new(0.0, 0.5))[0] - 0.5).abs() < 1e-5);
        assert!((t.sample(Vec2::new(1.0, 0.5))[0] - 0.5).abs() < 1e-5);
        // Halfway between the centres inside the image.
        assert!((t.sample(Vec2::new(0.5, 0.5))[0] - 0.5).abs() < 1e-5);
    }

    #[test]
    fn first_row_is_v_zero() {
        // 1x2: top row red, bottom row green.
        let t = Texture::from_rgb8(1, 2, &[255, 0, 0, 0, 255, 0]).expect("valid");
        assert_eq!(t.sample(Vec2::new(0.5, 0.25)), [1.0, 0.0, 0.0]);
        assert_eq!(t.sample(Vec2::new(0.5, 0.75)), [0.0, 1.0, 0.0]);
    }

    #[test]
    fn bad_sizes_are_rejected() {
        assert!(Texture::from_rgb8(2, 2, &[0; 11]).is_none());
        assert!(Texture::from_rgb8(0, 0, &[]).is_none());
        assert!(Texture::from_linear(1, 1, vec![[f32::NAN; 3]]).is_none());
    }

    #[test]
    fn decode_png_roundtrip_and_error_names_file() {
        let mut png = Vec::new();
        let img = image::RgbImage::from_raw(2, 1, vec![255, 255, 255, 128, 128, 128])
            .expect("buffer size matches");
        img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .expect("encode png");
        let t = Texture::decode(&png, Path::new("x.png")).expect("decodes");
        assert_eq!((t.width(), t.height()), (2, 1));
        assert!((t.texel(1)[0] - 0.2158).abs() < 1e-3);
        let err = Texture::decode(b"not an image", Path::new("broken.png")).unwrap_err();
        assert!(err.to_string().contains("broken.png"), "{err}");
    }
}
