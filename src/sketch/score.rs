//! Scores on the sketch format's 0–255 height scale and agreement between two sketches.

use super::distance::distance_to;
use super::{SKETCH_PX, Sketch};

/// Root-mean-square difference of two height fields (same scale, same length).
pub fn rmse(a: &[f32], b: &[f32]) -> f64 {
    let sum: f64 = a.iter().zip(b).map(|(&x, &y)| ((x - y) as f64).powi(2)).sum();
    (sum / a.len().max(1) as f64).sqrt()
}

/// The scales (Gaussian standard deviations, pixels) [`rmse_at_scale`] is reported at by
/// `terrain eval-sketch`: 0 (the plain RMSE) to 32 px (an eighth of a tile).
pub const ERROR_SCALES_PX: [f32; 5] = [0.0, 4.0, 8.0, 16.0, 32.0];

/// Root-mean-square of the difference of two [`SKETCH_PX`]² height fields after smoothing it
/// with a Gaussian of `sigma_px` pixels (0: [`rmse`]): how much of the error lies at scales
/// above about σ. Edges clamp.
pub fn rmse_at_scale(a: &[f32], b: &[f32], sigma_px: f32) -> f64 {
    let d: Vec<f32> = a.iter().zip(b).map(|(x, y)| x - y).collect();
    let d = if sigma_px > 0.0 { super::extract::gaussian(&d, SKETCH_PX, sigma_px) } else { d };
    (d.iter().map(|&v| (v as f64).powi(2)).sum::<f64>() / d.len().max(1) as f64).sqrt()
}

/// Root-mean-square difference of two height fields over the pixels of each band of `bands`
/// (0..=3; `None` for a band with no pixel).
pub fn rmse_by_band(a: &[f32], b: &[f32], bands: &[u8]) -> [Option<f64>; super::BANDS] {
    let mut sum = [0f64; super::BANDS];
    let mut count = [0usize; super::BANDS];
    for ((&x, &y), &k) in a.iter().zip(b).zip(bands) {
        let k = (k as usize).min(super::BANDS - 1);
        sum[k] += ((x - y) as f64).powi(2);
        count[k] += 1;
    }
    std::array::from_fn(|k| (count[k] > 0).then(|| (sum[k] / count[k] as f64).sqrt()))
}

/// Peak signal-to-noise ratio (dB) for an RMSE on the 0–255 scale (peak 255).
pub fn psnr(rmse: f64) -> f64 {
    20.0 * (255.0 / rmse.max(1e-9)).log10()
}

/// The largest and the 99th-percentile step between 4-neighbouring samples of an `n`×`n`
/// height field (its units; on the format's 0–255 scale the authors' targets reach ~7).
pub fn neighbour_steps(h: &[f32], n: usize) -> (f32, f32) {
    let mut steps: Vec<f32> = Vec::with_capacity(2 * n * n);
    for y in 0..n {
        for x in 0..n {
            let p = y * n + x;
            if x + 1 < n {
                steps.push((h[p + 1] - h[p]).abs());
            }
            if y + 1 < n {
                steps.push((h[p + n] - h[p]).abs());
            }
        }
    }
    if steps.is_empty() {
        return (0.0, 0.0);
    }
    let k = ((steps.len() - 1) as f64 * 0.99).round() as usize;
    let (_, p99, _) = steps.select_nth_unstable_by(k, f32::total_cmp);
    let p99 = *p99;
    (steps.iter().copied().fold(0.0, f32::max), p99)
}

/// How closely one sketch follows another (e.g. extracted vs drawn by the authors).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Agreement {
    /// Fraction of pixels with the same band.
    pub band: f64,
    /// Ridges: fraction of `ours` ridge pixels within [`STROKE_TOLERANCE_PX`] of a `theirs`
    /// ridge pixel (precision) and the converse (recall).
    pub ridge_precision: f64,
    /// See `ridge_precision`.
    pub ridge_recall: f64,
    /// Valleys: as for ridges.
    pub valley_precision: f64,
    /// See `valley_precision`.
    pub valley_recall: f64,
}

/// Distance (pixels) within which a stroke pixel counts as matching the other sketch's stroke.
pub const STROKE_TOLERANCE_PX: f32 = 3.0;

impl Agreement {
    /// Compares `ours` with `theirs`.
    pub fn between(ours: &Sketch, theirs: &Sketch) -> Self {
        let n = ours.band.len();
        let band = (0..n).filter(|&p| ours.band[p] == theirs.band[p]).count() as f64 / n as f64;
        let (rp, rr) = overlap(&ours.ridge, &theirs.ridge);
        let (vp, vr) = overlap(&ours.valley, &theirs.valley);
        Self { band, ridge_precision: rp, ridge_recall: rr, valley_precision: vp, valley_recall: vr }
    }

    /// F1 score of the ridge overlap.
    pub fn ridge_f1(&self) -> f64 {
        f1(self.ridge_precision, self.ridge_recall)
    }

    /// F1 score of the valley overlap.
    pub fn valley_f1(&self) -> f64 {
        f1(self.valley_precision, self.valley_recall)
    }
}

fn f1(p: f64, r: f64) -> f64 {
    if p + r > 0.0 { 2.0 * p * r / (p + r) } else { 0.0 }
}

/// (precision, recall) of mask `a` against mask `b` within [`STROKE_TOLERANCE_PX`].
fn overlap(a: &[bool], b: &[bool]) -> (f64, f64) {
    let near = |from: &[bool], to: &[bool]| -> f64 {
        let d = distance_to(to, SKETCH_PX, SKETCH_PX);
        let total = from.iter().filter(|&&x| x).count();
        if total == 0 {
            return 0.0;
        }
        from.iter().zip(&d).filter(|&(&x, &dist)| x && dist <= STROKE_TOLERANCE_PX).count() as f64 / total as f64
    };
    (near(a, b), near(b, a))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn neighbour_steps_of_a_ramp_with_one_spike_are_the_spike_and_the_ramps_step() {
        // A 20 × 20 ramp rising 2 per column, one sample raised by 50: 760 steps, 4 touch it.
        let n = 20;
        let mut h: Vec<f32> = (0..n * n).map(|p| 2.0 * (p % n) as f32).collect();
        h[5 * n + 5] += 50.0;
        let (max, p99) = neighbour_steps(&h, n);
        assert_eq!(max, 52.0);
        assert_eq!(p99, 2.0);
    }

    /// A constant offset of 5 keeps its RMSE of 5 at every scale; a checkerboard of ±5 (the
    /// finest detail) has RMSE 5 unsmoothed and under 0.05 (1 %) at σ = 4 px. Per band: the error
    /// of each band's own pixels, none for a band without pixels.
    #[test]
    fn error_by_scale_keeps_an_offset_and_drops_a_checkerboard_and_by_band_splits_it() {
        let n = SKETCH_PX * SKETCH_PX;
        let zero = vec![0f32; n];
        let offset = vec![5f32; n];
        for s in ERROR_SCALES_PX {
            assert!((rmse_at_scale(&offset, &zero, s) - 5.0).abs() < 1e-4, "σ {s}");
        }
        let checker: Vec<f32> = (0..n).map(|p| if (p % SKETCH_PX + p / SKETCH_PX).is_multiple_of(2) { 5.0 } else { -5.0 }).collect();
        assert!((rmse_at_scale(&checker, &zero, 0.0) - 5.0).abs() < 1e-6);
        let smoothed = rmse_at_scale(&checker, &zero, 4.0);
        assert!(smoothed < 0.05, "{smoothed}");
        let bands: Vec<u8> = (0..n).map(|p| if p < n / 2 { 0 } else { 2 }).collect();
        let half: Vec<f32> = (0..n).map(|p| if p < n / 2 { 3.0 } else { 4.0 }).collect();
        assert_eq!(rmse_by_band(&half, &zero, &bands), [Some(3.0), None, Some(4.0), None]);
    }

    #[test]
    fn rmse_and_psnr_of_a_constant_offset_of_5_are_5_and_34_15_db() {
        let a = vec![10f32; 100];
        let b = vec![15f32; 100];
        assert!((rmse(&a, &b) - 5.0).abs() < 1e-9);
        assert!((psnr(5.0) - 34.151).abs() < 1e-3, "{}", psnr(5.0));
    }

    #[test]
    fn a_stroke_shifted_by_two_pixels_matches_fully_and_one_shifted_by_ten_not_at_all() {
        let mut a = Sketch::filled(0);
        let mut b = Sketch::filled(0);
        let mut c = Sketch::filled(0);
        for x in 20..200 {
            a.ridge[100 * SKETCH_PX + x] = true;
            b.ridge[102 * SKETCH_PX + x] = true;
            c.ridge[110 * SKETCH_PX + x] = true;
        }
        let ab = Agreement::between(&a, &b);
        assert_eq!((ab.ridge_precision, ab.ridge_recall, ab.band), (1.0, 1.0, 1.0));
        let ac = Agreement::between(&a, &c);
        assert_eq!((ac.ridge_precision, ac.ridge_recall), (0.0, 0.0));
        assert_eq!(ac.valley_f1(), 0.0);
    }
}
