//! A golden image: the built-in Cornell box baked small and rendered headless, compared with
//! the committed `tests/golden/cornell_final.exr`, so that a change to any stage of the bake,
//! the relighting or the renderer shows.
//!
//! The setup: `builtin:cornell` baked with the paper preset (4 bounces), 4 receiver levels,
//! about 60 level-0 points, 64 gather rays and seed 1; relit on the CPU (8 shadow rays per sender, flattening on the CPU)
//! with the scene's light; rendered at 96x72 with the file's camera and a 512-pixel shadow map
//! (`common::render`); the final (direct + indirect) buffer is compared.
//!
//! The comparison passes when both hold:
//! - relative RMSE `sqrt(sum (a - g)^2 / sum g^2)` over all channels of the linear images is
//!   at most [`MAX_RELATIVE_RMSE`] (1 %);
//! - after tone mapping both with the golden's own operator (Reinhard, as the PNGs) and
//!   8-bit sRGB encoding, at most [`MAX_OFF_PIXELS`] (1 %) of the pixels differ by more than
//!   [`OFF_LEVELS`] (8 levels) in some channel, and none by more than [`MAX_LEVELS`] (64).
//!
//! Software rasterisers and GPUs differ by rounding (16- or 32-bit float accumulation) and at
//! triangle edges, where a pixel may see another surface: the per-pixel bounds allow a few
//! such pixels, the RMSE bound allows the rounding. A brighter or moved light, a changed
//! kernel or a dropped bounce changes most pixels by far more (see the second test).
//!
//! On failure the new image and the difference `|new - golden|` are written to
//! `target/debug/golden/` (paths in the message). To regenerate the golden image on purpose:
//!
//! ```text
//! MLT_UPDATE_GOLDEN=1 cargo test -p mlt-view --test golden
//! ```

mod common;

use std::path::{Path, PathBuf};

use common::small;
use mlt_bake::{BakeOptions, Preset};
use mlt_view::images::{linear_to_srgb, luminance, ToneMap};
use mlt_view::{Light, RgbImage};

/// Largest relative RMSE of the linear final image.
const MAX_RELATIVE_RMSE: f64 = 0.01;
/// A pixel is "off" when a tone-mapped 8-bit channel differs by more than this.
const OFF_LEVELS: i32 = 8;
/// Largest fraction of off pixels.
const MAX_OFF_PIXELS: f64 = 0.01;
/// Largest difference of any tone-mapped 8-bit channel.
const MAX_LEVELS: i32 = 64;

const WIDTH: u32 = 96;
const HEIGHT: u32 = 72;

fn golden_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden/cornell_final.exr")
}

/// Where a failing run leaves its images: `golden/` in the profile directory of the target
/// dir (this test binary lives in its `deps/`).
fn failure_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("the test binary's path");
    let profile = exe
        .parent()
        .and_then(Path::parent)
        .expect("the test binary lies in target/PROFILE/deps");
    profile.join("golden")
}

/// The final image of the small Cornell box relit with the file's light as `light` changes it.
fn render(name: &str, light: impl Fn(Light) -> Light) -> RgbImage {
    let spec = "builtin:cornell";
    let scene_light = mlt_scenes::load_scene(spec).unwrap().light;
    let light = light(Light::from_desc(&scene_light).unwrap());
    let opts = BakeOptions {
        preset: Some(Preset::Paper),
        receiver_levels: Some(4),
        coarse_count: Some(60),
        gather_rays: Some(64),
        seed: Some(1),
        ..Default::default()
    };
    let (buffers, ..) = common::render(spec, opts, Some(light), small(WIDTH, HEIGHT), name);
    buffers.final_
}

/// How far an image is from the golden one.
#[derive(Debug)]
struct Difference {
    relative_rmse: f64,
    off_pixels: f64,
    max_levels: i32,
}

impl Difference {
    fn passes(&self) -> bool {
        self.relative_rmse <= MAX_RELATIVE_RMSE
            && self.off_pixels <= MAX_OFF_PIXELS
            && self.max_levels <= MAX_LEVELS
    }
}

/// 8-bit sRGB channels of `img` tone-mapped with `tm`.
fn tone_mapped(img: &RgbImage, tm: &ToneMap) -> Vec<[i32; 3]> {
    img.pixels
        .iter()
        .map(|&p| {
            let s = tm.scale(luminance(p));
            p.map(|c| ((linear_to_srgb((c * s).clamp(0.0, 1.0)) * 255.0 + 0.5) as i32).min(255))
        })
        .collect()
}

fn difference(new: &RgbImage, golden: &RgbImage) -> Difference {
    assert_eq!(
        (new.width, new.height),
        (golden.width, golden.height),
        "the golden image has another size"
    );
    let (mut err, mut norm) = (0.0f64, 0.0f64);
    for (a, g) in new.pixels.iter().zip(&golden.pixels) {
        for c in 0..3 {
            err += (a[c] as f64 - g[c] as f64).powi(2);
            norm += (g[c] as f64).powi(2);
        }
    }
    let tm = ToneMap::measure(golden);
    let (a, g) = (tone_mapped(new, &tm), tone_mapped(golden, &tm));
    let per_pixel: Vec<i32> = a
        .iter()
        .zip(&g)
        .map(|(a, g)| (0..3).map(|c| (a[c] - g[c]).abs()).max().unwrap_or(0))
        .collect();
    Difference {
        relative_rmse: (err / norm.max(f64::MIN_POSITIVE)).sqrt(),
        off_pixels: per_pixel.iter().filter(|&&d| d > OFF_LEVELS).count() as f64
            / per_pixel.len().max(1) as f64,
        max_levels: per_pixel.iter().copied().max().unwrap_or(0),
    }
}

/// Writes the new image and `|new - golden|` where a failing run leaves them; returns the
/// directory.
fn keep_failure(new: &RgbImage, golden: &RgbImage) -> PathBuf {
    let dir = failure_dir();
    std::fs::create_dir_all(&dir).unwrap();
    let mut diff = RgbImage::new(new.width, new.height);
    for ((d, a), g) in diff.pixels.iter_mut().zip(&new.pixels).zip(&golden.pixels) {
        *d = [0, 1, 2].map(|c| (a[c] - g[c]).abs());
    }
    new.write_exr(&dir.join("cornell_final.new.exr")).unwrap();
    new.write_png(&dir.join("cornell_final.new.png")).unwrap();
    diff.write_exr(&dir.join("cornell_final.diff.exr")).unwrap();
    diff.write_png(&dir.join("cornell_final.diff.png")).unwrap();
    dir
}

#[test]
fn the_cornell_box_renders_like_the_golden_image() {
    let new = render("golden", |l| l);
    assert!(new.all_finite());
    let path = golden_path();
    if std::env::var_os("MLT_UPDATE_GOLDEN").is_some() {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        new.write_exr(&path).unwrap();
        eprintln!("wrote the golden image {}", path.display());
    }
    let golden = RgbImage::read_exr(&path).unwrap_or_else(|e| {
        panic!("no golden image ({e}); make it with MLT_UPDATE_GOLDEN=1 cargo test -p mlt-view --test golden")
    });
    let d = difference(&new, &golden);
    eprintln!("against the golden image: {d:?}");
    if !d.passes() {
        let kept = keep_failure(&new, &golden);
        panic!(
            "the final image differs from {}: {d:?} (limits: relative RMSE {MAX_RELATIVE_RMSE}, \
             {MAX_OFF_PIXELS} of the pixels off by more than {OFF_LEVELS} levels, {MAX_LEVELS} \
             levels at most); the new image and the difference are in {}. If the change is \
             intended: MLT_UPDATE_GOLDEN=1 cargo test -p mlt-view --test golden",
            path.display(),
            kept.display()
        );
    }
}

#[test]
fn a_brighter_or_moved_light_fails_the_comparison() {
    let golden = RgbImage::read_exr(&golden_path()).expect("the golden image");
    let brighter = render("golden-brighter", |mut l| {
        l.intensity = l.intensity.map(|i| i * 1.05);
        l
    });
    let d = difference(&brighter, &golden);
    eprintln!("5 % brighter: {d:?}");
    assert!(!d.passes(), "5 % more light passes: {d:?}");
    let moved = render("golden-moved", |mut l| {
        l.position.x += 0.05;
        l
    });
    let d = difference(&moved, &golden);
    eprintln!("moved: {d:?}");
    assert!(!d.passes(), "a light moved by 5 cm passes: {d:?}");
    // The comparison itself accepts an image against itself.
    let same = difference(&golden, &golden);
    assert!(same.passes() && same.relative_rmse == 0.0 && same.max_levels == 0);
}
