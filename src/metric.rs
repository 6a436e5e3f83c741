//! The error metric of DESIGN.md §3: normalised RMSE of Rec. 709 luminance over the covered
//! texels (or pixels), `sqrt(sum (Y - Y_ref)^2 / sum Y_ref^2)`, reported per channel too, with
//! the mean bias, the largest error and counts of non-finite and negative values.

use glam::Vec3;
use serde::Serialize;

use crate::luminance;

/// The comparison of an image A against a reference B.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Comparison {
    /// Texels (pixels) compared.
    pub count: usize,
    /// Normalised luminance RMSE (a fraction: 0.05 is 5 %).
    pub error: f64,
    /// The same per channel (R, G, B), each normalised by its own reference.
    pub error_rgb: [f64; 3],
    /// Mean bias of luminance: sum(Y_a) / sum(Y_ref) - 1.
    pub bias: f64,
    /// Largest absolute luminance error.
    pub max_abs: f64,
    /// Largest luminance error relative to the reference's mean luminance.
    pub max_rel_to_mean: f64,
    /// Texels of A with a non-finite channel (counted as zero in the error).
    pub non_finite: usize,
    /// Texels of A with a negative channel.
    pub negative: usize,
    /// Texels of the reference with a non-finite channel: any makes the figures meaningless
    /// (an infinite one read 0.00 %), so a caller must refuse such a reference.
    pub reference_non_finite: usize,
}

/// Compare `a` against reference `b` where `mask` is true (all when `None`).
pub fn compare(a: &[Vec3], b: &[Vec3], mask: Option<&[bool]>) -> Comparison {
    assert_eq!(a.len(), b.len(), "images must have the same size");
    let mut c = Comparison::default();
    let (mut se, mut sref, mut sum_a, mut sum_b) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let (mut se_c, mut ref_c) = ([0.0f64; 3], [0.0f64; 3]);
    for k in 0..a.len() {
        if mask.is_some_and(|m| !m[k]) {
            continue;
        }
        c.count += 1;
        let mut va = a[k];
        if !va.is_finite() {
            c.non_finite += 1;
            va = Vec3::ZERO;
        }
        if va.min_element() < 0.0 {
            c.negative += 1;
        }
        let vb = b[k];
        if !vb.is_finite() {
            c.reference_non_finite += 1;
        }
        let (ya, yb) = (luminance(va) as f64, luminance(vb) as f64);
        se += (ya - yb) * (ya - yb);
        sref += yb * yb;
        sum_a += ya;
        sum_b += yb;
        c.max_abs = c.max_abs.max((ya - yb).abs());
        for ch in 0..3 {
            let d = (va[ch] - vb[ch]) as f64;
            se_c[ch] += d * d;
            ref_c[ch] += (vb[ch] as f64) * (vb[ch] as f64);
        }
    }
    let norm = |e: f64, r: f64| {
        if r > 0.0 {
            (e / r).sqrt()
        } else if e > 0.0 {
            f64::INFINITY
        } else {
            0.0
        }
    };
    c.error = norm(se, sref);
    c.error_rgb = [norm(se_c[0], ref_c[0]), norm(se_c[1], ref_c[1]), norm(se_c[2], ref_c[2])];
    c.bias = if sum_b > 0.0 { sum_a / sum_b - 1.0 } else { 0.0 };
    let mean_b = if c.count > 0 { sum_b / c.count as f64 } else { 0.0 };
    c.max_rel_to_mean = if mean_b > 0.0 { c.max_abs / mean_b } else { 0.0 };
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_computed_figures() {
        // Reference luminances 1 and 2 (grey), A reads 1.5 and 2: error sqrt(0.25 / 5).
        let b = [Vec3::splat(1.0), Vec3::splat(2.0), Vec3::splat(7.0)];
        let a = [Vec3::splat(1.5), Vec3::splat(2.0), Vec3::new(f32::NAN, 0.0, -1.0)];
        let mask = [true, true, false];
        let c = compare(&a, &b, Some(&mask));
        assert_eq!(c.count, 2);
        assert!((c.error - (0.25f64 / 5.0).sqrt()).abs() < 1e-6);
        assert!((c.bias - (3.5 / 3.0 - 1.0)).abs() < 1e-6);
        assert!((c.max_abs - 0.5).abs() < 1e-6);
        assert!((c.error_rgb[0] - c.error).abs() < 1e-6);
        assert_eq!((c.non_finite, c.negative, c.reference_non_finite), (0, 0, 0));
        // A reference texel that is not finite is counted where it is compared.
        let inf = [Vec3::splat(1.0), Vec3::splat(f32::INFINITY), Vec3::splat(f32::NAN)];
        assert_eq!(compare(&a, &inf, Some(&mask)).reference_non_finite, 1);
        assert_eq!(compare(&a, &inf, None).reference_non_finite, 2);
        // Unmasked, the third texel is non-finite (taken as 0) and negative.
        let c = compare(&a, &b, None);
        assert_eq!((c.non_finite, c.negative), (1, 0));
        let y3 = luminance(Vec3::splat(7.0)) as f64;
        assert!((c.error - ((0.25 + y3 * y3) / (5.0 + y3 * y3)).sqrt()).abs() < 1e-6);
        let neg = compare(&[Vec3::new(-1.0, 1.0, 1.0)], &[Vec3::ONE], None);
        assert_eq!(neg.negative, 1);
    }
}
