//! The generator's terrain put on the format's 0–255 scale by its own sketch's bands.
//!
//! The format's bands are equal quarters of each tile's height range, so in a target the
//! border between band k−1 and band k lies at height 64·k ([`border_height`]). The generator's
//! heights along a border scatter around some other value, and a plain min–max stretch leaves
//! them there. [`to_band_scale`] maps the heights by a smooth increasing function through the
//! lowest height (→ 0), the median height along each border (→ 64·k) and the highest (→ 255):
//! it uses only the sketch, so it runs the same on every sketch, in the CLI and in the page.

use super::BANDS;
use super::baseline::{border_height, stretch};

/// Fewest border pixels for a border's median to count; a shorter border sets no knot.
const MIN_BORDER_PX: usize = 5;

/// Puts `h` (heights in any unit, `side`² row-major, made for the bands `band`, 0–3 per
/// pixel) on the format's 0–255 scale by [`BandMap::fit`]; flat heights become 127.5, as
/// [`stretch`] makes them.
pub fn to_band_scale(h: &mut [f32], band: &[u8], side: usize) {
    match BandMap::fit(h, band, side) {
        Some(map) => h.iter_mut().for_each(|x| *x = map.apply(*x)),
        None => stretch(h),
    }
}

/// An increasing map from a generator's heights to the format's 0–255 scale: a monotone
/// cubic through knots (height, value on the scale).
#[derive(Clone, Debug, PartialEq)]
pub struct BandMap {
    knots: Vec<(f32, f32)>,
    slopes: Vec<f32>,
}

/// One piece of a [`BandMap`]: the cubic Hermite segment from knot (`x0`, `y0`) to
/// (`x0 + width`, `y1`) with slopes `m0` and `m1` at its ends.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Segment {
    /// Height where the segment starts.
    pub x0: f32,
    /// Height span of the segment (> 0).
    pub width: f32,
    /// Value (0–255) at its start.
    pub y0: f32,
    /// Value (0–255) at its end.
    pub y1: f32,
    /// Slope (value per height) at its start.
    pub m0: f32,
    /// Slope at its end.
    pub m1: f32,
}

impl Segment {
    /// The value of height `x` on this segment (extrapolated by the cubic outside it).
    pub fn apply(&self, x: f32) -> f32 {
        let t = (x - self.x0) / self.width;
        let (t2, t3) = (t * t, t * t * t);
        (2.0 * t3 - 3.0 * t2 + 1.0) * self.y0 + (t3 - 2.0 * t2 + t) * self.width * self.m0 + (-2.0 * t3 + 3.0 * t2) * self.y1 + (t3 - t2) * self.width * self.m1
    }
}

impl BandMap {
    /// The map for heights `h` (any unit, `side`² row-major) made for the bands `band` (0–3
    /// per pixel): the lowest height goes to 0, the highest to 255, and the median height along
    /// the border of each pair of neighbouring bands k−1, k (the pixels of either band with a
    /// 4-neighbour in the other) to 64·k, with a monotone cubic between ([`monotone_slopes`]).
    /// Where those medians do not increase from band to band it is the min–max stretch;
    /// `None` for flat heights.
    pub fn fit(h: &[f32], band: &[u8], side: usize) -> Option<Self> {
        assert!(h.len() == side * side && band.len() == h.len(), "heights and bands of a {side}² sketch");
        let (lo, hi) = h.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
        if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
            return None;
        }
        let mut knots = vec![(lo, 0.0)];
        for k in 1..BANDS {
            let mut along = border_heights(h, band, side, k as u8);
            if along.len() >= MIN_BORDER_PX {
                knots.push((median(&mut along), border_height(k)));
            }
        }
        knots.push((hi, 255.0));
        if knots.windows(2).any(|w| w[1].0 <= w[0].0) {
            knots = vec![(lo, 0.0), (hi, 255.0)];
        }
        let slopes = monotone_slopes(&knots);
        Some(Self { knots, slopes })
    }

    /// The segment that maps height `x` (the first or last one beyond the knots).
    pub fn segment(&self, x: f32) -> Segment {
        let k = &self.knots;
        let i = k.windows(2).position(|w| x <= w[1].0).unwrap_or(k.len() - 2);
        Segment { x0: k[i].0, width: k[i + 1].0 - k[i].0, y0: k[i].1, y1: k[i + 1].1, m0: self.slopes[i], m1: self.slopes[i + 1] }
    }

    /// Height `x` on the format's 0–255 scale.
    pub fn apply(&self, x: f32) -> f32 {
        self.segment(x).apply(x)
    }
}

/// Slopes at `knots` (x and y both increasing) for a monotone cubic through them
/// (Fritsch–Carlson, as SciPy's `PchipInterpolator`): the map has no kink at a border height,
/// so the terrain shows no crease along the contours 64, 128 and 192.
fn monotone_slopes(knots: &[(f32, f32)]) -> Vec<f32> {
    let n = knots.len();
    let h: Vec<f32> = knots.windows(2).map(|w| w[1].0 - w[0].0).collect();
    let d: Vec<f32> = knots.windows(2).map(|w| (w[1].1 - w[0].1) / (w[1].0 - w[0].0)).collect();
    if n == 2 {
        return vec![d[0]; 2];
    }
    let mut m = vec![0f32; n];
    for i in 1..n - 1 {
        let (w1, w2) = (2.0 * h[i] + h[i - 1], h[i] + 2.0 * h[i - 1]);
        m[i] = (w1 + w2) / (w1 / d[i - 1] + w2 / d[i]);
    }
    // The end slopes: a three-point estimate, kept between 0 and three times the end secant.
    let end = |h0: f32, h1: f32, d0: f32, d1: f32| (((2.0 * h0 + h1) * d0 - h0 * d1) / (h0 + h1)).clamp(0.0, 3.0 * d0);
    m[0] = end(h[0], h[1], d[0], d[1]);
    m[n - 1] = end(h[n - 2], h[n - 3], d[n - 2], d[n - 3]);
    m
}

/// Heights of the pixels of band `k − 1` or `k` that have a 4-neighbour in the other one.
fn border_heights(h: &[f32], band: &[u8], side: usize, k: u8) -> Vec<f32> {
    let mut along = Vec::new();
    for y in 0..side {
        for x in 0..side {
            let p = y * side + x;
            let other = match band[p] {
                b if b == k => k - 1,
                b if b + 1 == k => k,
                _ => continue,
            };
            let touches =
                (x > 0 && band[p - 1] == other) || (x + 1 < side && band[p + 1] == other) || (y > 0 && band[p - side] == other) || (y + 1 < side && band[p + side] == other);
            if touches {
                along.push(h[p]);
            }
        }
    }
    along
}

/// The median of `v` (not empty; the mean of the two middle values for an even count).
fn median(v: &mut [f32]) -> f32 {
    v.sort_by(f32::total_cmp);
    let m = v.len() / 2;
    if v.len() % 2 == 1 { v[m] } else { (v[m - 1] + v[m]) / 2.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ramp of true heights 0–255 along x and its bands (equal quarters).
    fn ramp(side: usize) -> (Vec<f32>, Vec<u8>) {
        let t: Vec<f32> = (0..side * side).map(|p| (p % side) as f32 / (side - 1) as f32 * 255.0).collect();
        let band = t.iter().map(|&v| ((v / 64.0) as u8).min(3)).collect();
        (t, band)
    }

    fn rmse(a: &[f32], b: &[f32]) -> f32 {
        (a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f32>() / a.len() as f32).sqrt()
    }

    /// Terrain of the right shape whose bands are spread unevenly (the true heights t through
    /// exp(t / 60), as steep as a glacial valley's walls above a flat floor): the min–max
    /// stretch leaves it 78 off the truth, the band scale within 3, with the borders at 64,
    /// 128 and 192 within 2 (a border's two middle pixels straddle its knot) and the range
    /// exactly 0–255.
    #[test]
    fn exponentially_spread_bands_come_back_to_the_true_ramp_within_3() {
        let side = 64;
        let (t, band) = ramp(side);
        let mut h: Vec<f32> = t.iter().map(|&v| (v / 60.0).exp()).collect();
        let mut stretched = h.clone();
        stretch(&mut stretched);
        to_band_scale(&mut h, &band, side);
        let (e_stretch, e_band) = (rmse(&stretched, &t), rmse(&h, &t));
        assert!(e_stretch > 70.0, "stretch only {e_stretch} off");
        assert!(e_band < 3.0, "band scale {e_band} off");
        for k in 1..4u8 {
            let mut along = border_heights(&h, &band, side, k);
            let m = median(&mut along);
            assert!((m - border_height(k as usize)).abs() < 2.0, "border {k} at {m}");
        }
        assert!(h.windows(2).take(side - 1).all(|p| p[1] > p[0]), "not increasing along the ramp");
        assert_eq!(h.iter().copied().fold(f32::INFINITY, f32::min), 0.0);
        assert!((h.iter().copied().fold(f32::NEG_INFINITY, f32::max) - 255.0).abs() < 1e-3);
    }

    /// Terrain that falls where its bands rise (border medians decreasing) is only stretched
    /// (within 1e-3 of 255), and flat terrain becomes 127.5.
    #[test]
    fn falling_or_flat_terrain_is_only_stretched() {
        let side = 32;
        let (t, band) = ramp(side);
        let mut falling: Vec<f32> = t.iter().map(|v| 300.0 - v).collect();
        let mut stretched = falling.clone();
        stretch(&mut stretched);
        to_band_scale(&mut falling, &band, side);
        let worst = falling.iter().zip(&stretched).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-3, "differs from the stretch by {worst}");
        let mut flat = vec![5.0; side * side];
        to_band_scale(&mut flat, &band, side);
        assert!(flat.iter().all(|&v| v == 127.5));
    }
}
