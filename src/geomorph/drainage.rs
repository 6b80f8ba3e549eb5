//! Drainage statistics of a square window: how much of it is dead flat, how much lies in
//! closed depressions once area-averaged to ~100 m and ~400 m, and how far water runs in it.
//! Real mountain ranges drain through valleys that survive any averaging and carry water
//! across many kilometres; a field of round bumps with level lakes does neither.

use super::DEPRESSION_DEPTH_M;
use crate::dem::Heightfield;
use crate::world::drainage::{depression_fraction, fill_depressions};

/// Slope (degrees) below which a sample counts as dead flat.
pub const FLAT_SLOPE_DEG: f64 = 0.2;

/// Area-averaging factors of a 32 m window for the two coarser scales: 3 (96 m, "~100 m")
/// and 12 (384 m, "~400 m").
pub const COARSE_FACTORS: [usize; 2] = [3, 12];

/// Names of [`Drainage::values`], in order.
pub const DRAINAGE_NAMES: [&str; 4] = ["flat_fraction", "depression_fraction_96m", "depression_fraction_384m", "longest_flow_path_km"];

/// The drainage statistics of one window.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Drainage {
    /// Fraction of the interior samples with slope below [`FLAT_SLOPE_DEG`].
    pub flat_fraction: f64,
    /// Fraction of the window in closed depressions after area-averaging by 3 (96 m at 32 m).
    pub depression_fraction_96m: f64,
    /// The same after area-averaging by 12 (384 m at 32 m).
    pub depression_fraction_384m: f64,
    /// The longest path water takes over the window (D8, steepest descent on the window with
    /// its depressions filled), kilometres.
    pub longest_flow_path_km: f64,
}

impl Drainage {
    /// The values in the order of [`DRAINAGE_NAMES`].
    pub fn values(&self) -> [f64; 4] {
        [self.flat_fraction, self.depression_fraction_96m, self.depression_fraction_384m, self.longest_flow_path_km]
    }
}

/// The drainage statistics of the `n`×`n` window `h` (metres) with samples `spacing_m` apart.
/// The coarse scales are area averages ([`Heightfield::resample_area`]: blocks of 3² and 12²
/// samples, a remainder along the right and bottom edges dropped); a sample there is in a
/// closed depression when a level fill raises it by more than [`DEPRESSION_DEPTH_M`]
/// ([`depression_fraction`], the window's border the outlet).
pub fn measure(h: &[f32], n: usize, spacing_m: f64) -> Drainage {
    let field = Heightfield::new(n, n, spacing_m, h.to_vec());
    let coarse = COARSE_FACTORS.map(|f| {
        let c = field.resample_area(spacing_m * f as f64).expect("a coarser spacing");
        depression_fraction(&c.data, c.width, DEPRESSION_DEPTH_M)
    });
    Drainage {
        flat_fraction: flat_fraction(h, n, spacing_m),
        depression_fraction_96m: coarse[0],
        depression_fraction_384m: coarse[1],
        longest_flow_path_km: longest_flow_path_m(h, n, spacing_m) / 1000.0,
    }
}

/// Fraction of the interior samples of the `n`×`n` field whose slope (central differences)
/// is below [`FLAT_SLOPE_DEG`].
pub fn flat_fraction(h: &[f32], n: usize, spacing_m: f64) -> f64 {
    let limit = FLAT_SLOPE_DEG.to_radians().tan();
    let (mut flat, mut all) = (0usize, 0usize);
    for y in 1..n - 1 {
        for x in 1..n - 1 {
            let gx = (h[y * n + x + 1] - h[y * n + x - 1]) as f64 / (2.0 * spacing_m);
            let gy = (h[(y + 1) * n + x] - h[(y - 1) * n + x]) as f64 / (2.0 * spacing_m);
            flat += (gx.hypot(gy) < limit) as usize;
            all += 1;
        }
    }
    flat as f64 / all.max(1) as f64
}

/// The longest flow path over the `n`×`n` field (metres): its depressions are filled with a
/// small gradient so that every sample drains, each sample sends its water to its steepest
/// lower 8-neighbour, and the longest chain of such steps (diagonals √2 long) is measured.
pub fn longest_flow_path_m(h: &[f32], n: usize, spacing_m: f64) -> f64 {
    let mut z = h.to_vec();
    fill_depressions(&mut z, n, 1e-3);
    let mut order: Vec<usize> = (0..n * n).collect();
    order.sort_by(|&a, &b| z[b].total_cmp(&z[a]));
    let mut length = vec![0f64; n * n];
    let mut longest = 0f64;
    for p in order {
        let (x, y) = ((p % n) as i64, (p / n) as i64);
        let mut best: Option<(usize, f64, f64)> = None;
        for (dx, dy) in [(-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)] {
            let (qx, qy) = (x + dx, y + dy);
            if qx < 0 || qy < 0 || qx >= n as i64 || qy >= n as i64 {
                continue;
            }
            let q = qy as usize * n + qx as usize;
            let d = if dx != 0 && dy != 0 { std::f64::consts::SQRT_2 } else { 1.0 } * spacing_m;
            let drop = (z[p] - z[q]) as f64 / d;
            if drop > 0.0 && best.is_none_or(|b| drop > b.1) {
                best = Some((q, drop, d));
            }
        }
        longest = longest.max(length[p]);
        if let Some((q, _, d)) = best {
            length[q] = length[q].max(length[p] + d);
        }
    }
    longest
}

/// Per statistic (order of [`DRAINAGE_NAMES`]), the Wasserstein-1 distance between `set` and
/// `reference` divided by the reference's spread ([`super::distance_by`]); and their mean as
/// the last element.
pub fn distance(set: &[Drainage], reference: &[Drainage]) -> Vec<f64> {
    super::distance_by(set, reference, Drainage::values)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geomorph::tests::field;

    /// A plane tilted 1° along x is not flat, has no depressions at any scale, and water runs
    /// straight across it: the longest path is the window's width less one sample (63 × 32 m).
    /// Tilted 0.1° it is all flat.
    #[test]
    fn a_tilted_plane_drains_across_its_width_and_is_flat_only_below_the_limit() {
        let n = 64;
        let steep = field(n, |x, _| -x * 32.0 * 1f64.to_radians().tan());
        let d = measure(&steep, n, 32.0);
        assert_eq!((d.flat_fraction, d.depression_fraction_96m, d.depression_fraction_384m), (0.0, 0.0, 0.0), "{d:?}");
        assert!((d.longest_flow_path_km - 63.0 * 0.032).abs() < 1e-9, "{d:?}");
        let gentle = field(n, |x, _| -x * 32.0 * 0.1f64.to_radians().tan());
        assert_eq!(flat_fraction(&gentle, n, 32.0), 1.0);
    }

    /// A bowl 50 m deep fills the window's middle: at 96 m and 384 m its closed depression
    /// covers the disc inside the rim's lowest point (π/4 of the window; within 0.05 on the
    /// 64² grid at 96 m and 0.15 on the 16² grid at 384 m, whose border ring is the outlet),
    /// and the longest flow path is no longer than from a corner to the centre and on to the
    /// lowest rim point.
    #[test]
    fn a_bowl_is_a_closed_depression_at_every_scale() {
        let n = 192;
        let c = (n - 1) as f64 / 2.0;
        let bowl = field(n, |x, y| 50.0 * ((x - c).powi(2) + (y - c).powi(2)) / (c * c));
        let d = measure(&bowl, n, 32.0);
        for (f, tol) in [(d.depression_fraction_96m, 0.05), (d.depression_fraction_384m, 0.15)] {
            assert!((f - std::f64::consts::FRAC_PI_4).abs() < tol, "{d:?}");
        }
        assert!(d.longest_flow_path_km <= 2.0 * c * std::f64::consts::SQRT_2 * 0.032 + 1e-9, "{d:?}");
    }

    /// The distance of a set to itself is 0 for every statistic; a set of flatter windows is
    /// far from steeper ones in the flat fraction.
    #[test]
    fn the_distance_of_a_set_to_itself_is_zero() {
        let n = 32;
        let set: Vec<Drainage> = (1..8).map(|k| measure(&field(n, |x, y| (x * k as f64).sin() * 10.0 + y * k as f64), n, 32.0)).collect();
        assert!(distance(&set, &set).iter().all(|d| *d == 0.0));
        let flat: Vec<Drainage> = (1..8).map(|k| measure(&field(n, |x, _| x * 0.001 * k as f64), n, 32.0)).collect();
        // Every flat window has flat fraction 1, every steep one 0 (whose spread falls back to 1).
        assert_eq!(distance(&flat, &set)[0], 1.0);
    }
}
