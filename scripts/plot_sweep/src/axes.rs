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

/// Tick positions for a log axis over `[lo, hi]`: the values 1, 2 and 5 times a power of ten
/// inside it, or every digit times a power of ten when those are fewer than three (a range
/// within one decade would otherwise get no labelled tick at all).
pub fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    if !(lo > 0.0 && hi > lo && hi.is_finite()) {
        return Vec::new();
    }
    let decades = lo.log10().floor() as i32..=hi.log10().ceil() as i32;
    let pick = |mantissas: &[f64]| -> Vec<f64> {
        decades
            .clone()
            .flat_map(|e| mantissas.iter().map(move |m| m * 10f64.powi(e)))
            .filter(|v| *v >= lo && *v <= hi)
            .collect()
    };
    let ticks = pick(&[1.0, 2.0, 5.0]);
    if ticks.len() >= 3 {
        ticks
    } else {
        pick(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0])
    }
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

    #[test]
    fn log_ticks_label_every_range() {
        assert_eq!(log_ticks(0.3, 30.0), vec![0.5, 1.0, 2.0, 5.0, 10.0, 20.0]);
        // Within one decade: every digit.
        assert_eq!(log_ticks(11.0, 29.0), vec![20.0]);
        assert_eq!(log_ticks(11.0, 45.0), vec![20.0, 30.0, 40.0]);
        let t = log_ticks(0.062, 0.19);
        let want = [0.07, 0.08, 0.09, 0.1];
        assert_eq!(t.len(), want.len());
        assert!(t.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-12));
        assert!(log_ticks(0.0, 1.0).is_empty() && log_ticks(2.0, 1.0).is_empty());
    }
}
