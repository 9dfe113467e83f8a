//! Where an image's error lies: the measures of [`crate::compare`] per part of the image,
//! either a grid of tiles (where on the screen) or classes of the reference's brightness
//! (its quantiles: whether the dark parts are too bright and the bright ones too dark, the
//! signature of a solution that is too smooth).
//!
//! Per part, over its pixels of reference luminance `r` and test luminance `t`: the share of
//! the reference's light `sum r / sum_all r`, the ratio of means `sum t / sum r`, the relative
//! RMSE `sqrt(mean (t - r)^2) / mean r`, and the part's share of the whole image's error in
//! the mean, `(sum t - sum r) / sum_all r`: these shares add up to the whole image's ratio of
//! means less one, so they say which parts make an image too bright or too dark.

/// The measures of one part of the image (module docs).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Part {
    /// `"x0-x1,y0-y1"` (pixel ranges, end excluded) for a tile; `"q1/5"` for a brightness
    /// class, darkest first.
    pub label: String,
    pub pixels: usize,
    pub share_of_reference: f64,
    pub ratio_of_means: f64,
    pub relative_rmse: f64,
    /// `(sum t - sum r) / sum_all r`.
    pub excess_of_total: f64,
}

fn part(label: String, reference: &[f64], test: &[f64], ids: &[usize], total: f64) -> Part {
    let (mut sr, mut st, mut se) = (0.0, 0.0, 0.0);
    for &k in ids {
        sr += reference[k];
        st += test[k];
        se += (test[k] - reference[k]).powi(2);
    }
    let n = ids.len().max(1) as f64;
    let div = |a: f64, b: f64| if b > 0.0 { a / b } else { 0.0 };
    Part {
        label,
        pixels: ids.len(),
        share_of_reference: div(sr, total),
        ratio_of_means: div(st, sr),
        relative_rmse: div((se / n).sqrt(), sr / n),
        excess_of_total: div(st - sr, total),
    }
}

/// The parts of a `width` x `height` image (row-major luminances) on a grid of `cols` x
/// `rows` tiles, row by row from the top. Panics unless both images hold `width * height`
/// values and the grid is at least 1 x 1.
pub fn by_tiles(
    reference: &[f64],
    test: &[f64],
    width: usize,
    height: usize,
    cols: usize,
    rows: usize,
) -> Vec<Part> {
    assert!(reference.len() == width * height && test.len() == width * height);
    assert!(cols >= 1 && rows >= 1);
    let total: f64 = reference.iter().sum();
    let mut parts = Vec::with_capacity(cols * rows);
    for ty in 0..rows {
        let (y0, y1) = (ty * height / rows, (ty + 1) * height / rows);
        for tx in 0..cols {
            let (x0, x1) = (tx * width / cols, (tx + 1) * width / cols);
            let ids: Vec<usize> = (y0..y1)
                .flat_map(|y| (x0..x1).map(move |x| y * width + x))
                .collect();
            parts.push(part(
                format!("{x0}-{x1},{y0}-{y1}"),
                reference,
                test,
                &ids,
                total,
            ));
        }
    }
    parts
}

/// The parts of the image by the reference's brightness: `classes` classes of equal pixel
/// count (the last takes the remainder), darkest first; ties in brightness go by pixel index,
/// so the classes do not depend on a sort's stability. Panics unless both images have the
/// same length and `classes` is at least 1.
pub fn by_brightness(reference: &[f64], test: &[f64], classes: usize) -> Vec<Part> {
    assert_eq!(reference.len(), test.len());
    assert!(classes >= 1);
    let total: f64 = reference.iter().sum();
    let mut order: Vec<usize> = (0..reference.len()).collect();
    order.sort_by(|&a, &b| reference[a].total_cmp(&reference[b]).then(a.cmp(&b)));
    let n = order.len();
    (0..classes)
        .map(|c| {
            let ids = &order[c * n / classes..(c + 1) * n / classes];
            part(format!("q{}/{classes}", c + 1), reference, test, ids, total)
        })
        .collect()
}

/// A text table of `parts`, one line each.
pub fn format_parts(parts: &[Part]) -> String {
    let mut s = String::from(
        "part             pixels  share of ref.  ratio of means  rel. RMSE  excess of total\n",
    );
    for p in parts {
        s.push_str(&format!(
            "{:<15} {:>7}  {:>13.3}  {:>14.3}  {:>9.3}  {:>+15.4}\n",
            p.label,
            p.pixels,
            p.share_of_reference,
            p.ratio_of_means,
            p.relative_rmse,
            p.excess_of_total
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 4 x 2 image whose left half is twice as bright in the test.
    fn left_bright() -> (Vec<f64>, Vec<f64>) {
        let r: Vec<f64> = (0..8).map(|k| 1.0 + k as f64).collect();
        let t: Vec<f64> = (0..8)
            .map(|k| if k % 4 < 2 { 2.0 * r[k] } else { r[k] })
            .collect();
        (r, t)
    }

    #[test]
    fn tiles_find_the_half_that_is_too_bright_and_their_excesses_add_up() {
        let (r, t) = left_bright();
        let parts = by_tiles(&r, &t, 4, 2, 2, 1);
        assert_eq!(parts.len(), 2);
        assert_eq!(parts[0].label, "0-2,0-2");
        assert!((parts[0].ratio_of_means - 2.0).abs() < 1e-12);
        assert!((parts[1].ratio_of_means - 1.0).abs() < 1e-12 && parts[1].relative_rmse == 0.0);
        // Left: 1 + 2 + 5 + 6 = 14 of 36.
        assert!((parts[0].share_of_reference - 14.0 / 36.0).abs() < 1e-12);
        let whole: f64 = t.iter().sum::<f64>() / r.iter().sum::<f64>() - 1.0;
        let sum: f64 = parts.iter().map(|p| p.excess_of_total).sum();
        assert!((sum - whole).abs() < 1e-12);
        assert_eq!(parts.iter().map(|p| p.pixels).sum::<usize>(), 8);
    }

    #[test]
    fn brightness_classes_sort_by_the_reference_and_cover_every_pixel() {
        let (r, t) = left_bright();
        // Darkest half: values 1-4 (pixels 0-3: two of them doubled); brightest: 5-8.
        let parts = by_brightness(&r, &t, 2);
        assert_eq!(parts[0].label, "q1/2");
        assert!((parts[0].ratio_of_means - (2.0 + 4.0 + 3.0 + 4.0) / 10.0).abs() < 1e-12);
        assert!((parts[1].ratio_of_means - (10.0 + 12.0 + 7.0 + 8.0) / 26.0).abs() < 1e-12);
        let three = by_brightness(&r, &t, 3);
        assert_eq!(
            three.iter().map(|p| p.pixels).collect::<Vec<_>>(),
            vec![2, 3, 3]
        );
        let whole: f64 = t.iter().sum::<f64>() / r.iter().sum::<f64>() - 1.0;
        let sum: f64 = three.iter().map(|p| p.excess_of_total).sum();
        assert!((sum - whole).abs() < 1e-12);
        // An exact test image has no error anywhere.
        assert!(by_brightness(&r, &r, 4)
            .iter()
            .all(|p| p.ratio_of_means == 1.0 && p.excess_of_total == 0.0));
    }
}
