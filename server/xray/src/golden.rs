//! Golden-image comparison: how far a render is from a stored reference image, and the
//! tolerance the golden tests hold renders to (the CPU and GPU renderers, the engine's
//! stack scenes).

/// Largest mean absolute difference a render may have from its golden image (grey levels).
pub const MAX_MEAN_DIFFERENCE: f64 = 0.5;
/// Largest fraction of pixels more than 2 grey levels from the golden image.
pub const MAX_FAR_FRACTION: f64 = 1e-3;

/// Mean absolute difference (grey levels) and the fraction of pixels more than 2 levels
/// apart, of two 8-bit images of the same size.
pub fn difference(a: &[u8], b: &[u8]) -> (f64, f64) {
    assert_eq!(a.len(), b.len(), "images of different sizes");
    let n = a.len().max(1) as f64;
    let mean = a
        .iter()
        .zip(b)
        .map(|(x, y)| f64::from(x.abs_diff(*y)))
        .sum::<f64>()
        / n;
    let far = a.iter().zip(b).filter(|(x, y)| x.abs_diff(**y) > 2).count() as f64 / n;
    (mean, far)
}

/// Whether a difference is within the golden tolerance.
pub fn within_tolerance((mean, far): (f64, f64)) -> bool {
    mean <= MAX_MEAN_DIFFERENCE && far <= MAX_FAR_FRACTION
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn differences_are_counted_against_the_tolerance() {
        let a = vec![10u8; 1000];
        let mut b = a.clone();
        assert_eq!(difference(&a, &b), (0.0, 0.0));
        b[0] = 13; // one pixel 3 levels off: 0.1 % beyond 2
        let d = difference(&a, &b);
        assert!((d.0 - 0.003).abs() < 1e-12 && (d.1 - 0.001).abs() < 1e-12);
        assert!(within_tolerance(d));
        b[1] = 13;
        assert!(!within_tolerance(difference(&a, &b)));
    }
}
