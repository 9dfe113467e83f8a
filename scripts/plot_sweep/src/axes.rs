//! Axis helpers shared by the plot binaries: log-axis ranges and short tick labels.

/// Log-axis range around positive values, padded by a factor.
pub fn range(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    for x in v.filter(|x| *x > 0.0) {
        lo = lo.min(x);
        hi = hi.max(x);
    }
    if !lo.is_finite() {
        return (1e-3, 1.0);
    }
    (lo / 1.6, hi * 1.6)
}

/// A tick label with at most three significant digits.
pub fn short(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let digits = (2 - v.abs().log10().floor() as i32).max(0) as usize;
    format!("{v:.digits$}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_pad_the_positive_values_and_labels_keep_three_digits() {
        let (lo, hi) = range([0.0, 2.0, 8.0].into_iter());
        assert!((lo - 2.0 / 1.6).abs() < 1e-12 && (hi - 8.0 * 1.6).abs() < 1e-12);
        assert_eq!(range(std::iter::empty()), (1e-3, 1.0));
        assert_eq!(short(123.456), "123");
        assert_eq!(short(1.23456), "1.23");
    }
}
