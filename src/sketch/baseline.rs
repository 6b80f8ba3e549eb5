//! The non-learned reference: heights interpolated linearly by distance between band borders.
//!
//! A pixel of band k lies between the border with the band below (height 64·k on the format's
//! 0–255 scale) and the border with the band above (64·(k+1)); its height is the linear blend
//! by its distances to the two. Where a band has no lower (or upper) neighbour — the floor of a
//! basin, the top of a summit — the height runs from the one border it has to the band's far
//! value over the band's widest extent. Strokes are ignored. The result is stretched to 0–255
//! like the format's targets. It is also the generator's starting point
//! ([`crate::models::sketch`] learns the difference).

use super::distance::distance_to;
use super::{BANDS, SKETCH_PX, Sketch};

/// Height of the border between band k−1 and band k on the 0–255 scale.
pub fn border_height(k: usize) -> f32 {
    64.0 * k as f32
}

/// The interpolated heights of `sketch` ([`SKETCH_PX`]², row-major), on the 0–255 scale.
pub fn interpolate(sketch: &Sketch) -> Vec<f32> {
    let (w, h) = (SKETCH_PX, SKETCH_PX);
    let n = w * h;
    let mut out = vec![0f32; n];
    for k in 0..BANDS {
        let members: Vec<usize> = (0..n).filter(|&p| sketch.band[p] as usize == k).collect();
        if members.is_empty() {
            continue;
        }
        let below: Vec<bool> = sketch.band.iter().map(|&b| (b as usize) < k).collect();
        let above: Vec<bool> = sketch.band.iter().map(|&b| (b as usize) > k).collect();
        // Distances from pixel centres to the border half a pixel away.
        let d_lo: Vec<f32> = distance_to(&below, w, h).into_iter().map(|d| (d - 0.5).max(0.0)).collect();
        let d_hi: Vec<f32> = distance_to(&above, w, h).into_iter().map(|d| (d - 0.5).max(0.0)).collect();
        let widest = |d: &[f32]| members.iter().map(|&p| d[p]).filter(|v| v.is_finite()).fold(1.0f32, f32::max);
        let (span_lo, span_hi) = (widest(&d_lo), widest(&d_hi));
        let (lo, hi) = (border_height(k), border_height(k + 1));
        for &p in &members {
            let t = match (d_lo[p].is_finite(), d_hi[p].is_finite()) {
                (true, true) => d_lo[p] / (d_lo[p] + d_hi[p]).max(1e-6),
                (true, false) => (d_lo[p] / span_lo).min(1.0),
                (false, true) => 1.0 - (d_hi[p] / span_hi).min(1.0),
                (false, false) => 0.5,
            };
            out[p] = lo + t * (hi - lo);
        }
    }
    stretch(&mut out);
    out
}

/// Stretches heights in place to span exactly 0–255, as every target of the format does (a flat
/// field becomes 127.5).
pub fn stretch(v: &mut [f32]) {
    let (lo, hi) = v.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    for x in v.iter_mut() {
        *x = if hi > lo { (*x - lo) / (hi - lo) * 255.0 } else { 127.5 };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_two_band_split_interpolates_linearly_across_the_border_and_spans_0_to_255() {
        // Left half band 1, right half band 2: heights rise monotonically from left to right.
        let mut s = Sketch::filled(1);
        for y in 0..SKETCH_PX {
            for x in SKETCH_PX / 2..SKETCH_PX {
                s.band[y * SKETCH_PX + x] = 2;
            }
        }
        let h = interpolate(&s);
        let row: Vec<f32> = (0..SKETCH_PX).map(|x| h[7 * SKETCH_PX + x]).collect();
        assert_eq!(row[0], 0.0);
        assert_eq!(row[SKETCH_PX - 1], 255.0);
        assert!(row.windows(2).all(|p| p[1] > p[0]), "not strictly increasing");
        // The border (between columns 127 and 128) sits at the middle of the range.
        assert!(((row[127] + row[128]) / 2.0 - 127.5).abs() < 1.0, "{} {}", row[127], row[128]);
    }
}
