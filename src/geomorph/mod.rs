//! Geomorphometric statistics of heightfield windows, and a distance between the statistics'
//! distributions over two sets of windows: how the learned world is compared with real terrain
//! (and with the procedural world) without a neural feature extractor.
//!
//! Per window (square, side a power of two, spacing in metres):
//! - slope (degrees, central differences): mean and the ratio p90 / p50,
//! - the Laplacian's skewness and excess kurtosis (ridges are sharp and valleys round, or the
//!   other way round; noise is symmetric),
//! - the spectral slope β of the radially averaged power spectrum between wavelengths of 4 and
//!   16 samples (P ∝ k^β, after removing the best-fitting plane and a Hann taper),
//! - the fraction of the area in closed depressions deeper than [`DEPRESSION_DEPTH_M`] (real
//!   terrain drains; noise is full of pits),
//! - the local relief: mean over 16×16-sample blocks of max − min (metres).
//!
//! The distance between two sets is the mean over the statistics of the 1-D Wasserstein
//! distance between their empirical distributions, each divided by the reference set's
//! spread of that statistic: its interquartile range / 1.349 (the standard deviation of a
//! normal distribution, robust to the few flat or extreme real windows), else its standard
//! deviation when the quartiles coincide.

pub mod drainage;

/// Names of the statistics, in the order of [`Stats::values`].
pub const STAT_NAMES: [&str; 7] =
    ["slope_mean_deg", "slope_p90_over_p50", "laplacian_skewness", "laplacian_kurtosis", "spectral_slope_4_16px", "depression_area_fraction", "local_relief_m"];

/// Depth (metres) below which a filled pit does not count as a closed depression.
pub const DEPRESSION_DEPTH_M: f32 = 0.5;

/// Floor (degrees) of the median slope in the ratio p90 / p50.
pub const MIN_MEDIAN_SLOPE_DEG: f64 = 0.5;

/// Side (samples) of the blocks over which local relief is measured.
pub const RELIEF_BLOCK: usize = 16;

/// The statistics of one window.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Stats {
    /// Mean slope (degrees).
    pub slope_mean_deg: f64,
    /// 90th over 50th percentile of the slope.
    pub slope_p90_over_p50: f64,
    /// Skewness of the Laplacian.
    pub laplacian_skewness: f64,
    /// Excess kurtosis of the Laplacian.
    pub laplacian_kurtosis: f64,
    /// Power-spectrum slope β between wavelengths of 4 and 16 samples.
    pub spectral_slope: f64,
    /// Fraction of the area in closed depressions.
    pub depression_fraction: f64,
    /// Mean local relief over 16×16 blocks (metres).
    pub local_relief_m: f64,
}

impl Stats {
    /// The values in the order of [`STAT_NAMES`].
    pub fn values(&self) -> [f64; 7] {
        [self.slope_mean_deg, self.slope_p90_over_p50, self.laplacian_skewness, self.laplacian_kurtosis, self.spectral_slope, self.depression_fraction, self.local_relief_m]
    }
}

/// Why a window cannot be measured.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum StatsError {
    /// The window is not square with a power-of-two side of at least 32.
    #[error("a window must be square with a power-of-two side ≥ 32 (got {0} samples for side {1})")]
    Shape(usize, usize),
    /// A sample is NaN or infinite.
    #[error("the window has no-data samples")]
    NoData,
}

/// Measures a `side`² window `h` (metres, row-major) of spacing `spacing_m`.
pub fn measure(h: &[f32], side: usize, spacing_m: f64) -> Result<Stats, StatsError> {
    if !side.is_power_of_two() || side < 32 || h.len() != side * side {
        return Err(StatsError::Shape(h.len(), side));
    }
    if h.iter().any(|v| !v.is_finite()) {
        return Err(StatsError::NoData);
    }
    let n = side;
    let at = |x: usize, y: usize| h[y * n + x] as f64;
    let mut slopes = Vec::with_capacity((n - 2) * (n - 2));
    let mut lap = Vec::with_capacity((n - 2) * (n - 2));
    for y in 1..n - 1 {
        for x in 1..n - 1 {
            let gx = (at(x + 1, y) - at(x - 1, y)) / (2.0 * spacing_m);
            let gy = (at(x, y + 1) - at(x, y - 1)) / (2.0 * spacing_m);
            slopes.push(gx.hypot(gy).atan().to_degrees());
            lap.push((at(x + 1, y) + at(x - 1, y) + at(x, y + 1) + at(x, y - 1) - 4.0 * at(x, y)) / (spacing_m * spacing_m));
        }
    }
    let slope_mean_deg = mean(&slopes);
    slopes.sort_by(f64::total_cmp);
    let q = |p: f64| slopes[((slopes.len() - 1) as f64 * p).round() as usize];
    // The median slope is floored so that flat windows (lakes, ice) do not divide by ~0.
    let slope_p90_over_p50 = q(0.9) / q(0.5).max(MIN_MEDIAN_SLOPE_DEG);
    let (laplacian_skewness, laplacian_kurtosis) = skew_kurt(&lap);
    let mut relief = 0.0;
    let blocks = n / RELIEF_BLOCK;
    for by in 0..blocks {
        for bx in 0..blocks {
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for y in by * RELIEF_BLOCK..(by + 1) * RELIEF_BLOCK {
                for x in bx * RELIEF_BLOCK..(bx + 1) * RELIEF_BLOCK {
                    lo = lo.min(at(x, y));
                    hi = hi.max(at(x, y));
                }
            }
            relief += hi - lo;
        }
    }
    Ok(Stats {
        slope_mean_deg,
        slope_p90_over_p50,
        laplacian_skewness,
        laplacian_kurtosis,
        spectral_slope: spectral_slope(h, n),
        depression_fraction: crate::world::drainage::depression_fraction(h, n, DEPRESSION_DEPTH_M),
        local_relief_m: relief / (blocks * blocks) as f64,
    })
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Skewness and excess kurtosis of `v` (0 and 0 for a constant).
fn skew_kurt(v: &[f64]) -> (f64, f64) {
    let m = mean(v);
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64;
    if var <= 1e-18 {
        return (0.0, 0.0);
    }
    let s3 = v.iter().map(|x| (x - m).powi(3)).sum::<f64>() / v.len() as f64;
    let s4 = v.iter().map(|x| (x - m).powi(4)).sum::<f64>() / v.len() as f64;
    (s3 / var.powf(1.5), s4 / (var * var) - 3.0)
}

/// In-place radix-2 FFT of (re, im), length a power of two.
fn fft(re: &mut [f64], im: &mut [f64]) {
    let n = re.len();
    let mut j = 0;
    for i in 1..n {
        let mut bit = n >> 1;
        while j & bit != 0 {
            j ^= bit;
            bit >>= 1;
        }
        j |= bit;
        if i < j {
            re.swap(i, j);
            im.swap(i, j);
        }
    }
    let mut len = 2;
    while len <= n {
        let ang = -2.0 * std::f64::consts::PI / len as f64;
        for start in (0..n).step_by(len) {
            for k in 0..len / 2 {
                let (s, c) = (ang * k as f64).sin_cos();
                let (a, b) = (start + k, start + k + len / 2);
                let (tr, ti) = (re[b] * c - im[b] * s, re[b] * s + im[b] * c);
                re[b] = re[a] - tr;
                im[b] = im[a] - ti;
                re[a] += tr;
                im[a] += ti;
            }
        }
        len <<= 1;
    }
}

/// The slope β of log power against log wavenumber between wavelengths 4 and 16 samples.
fn spectral_slope(h: &[f32], n: usize) -> f64 {
    // Remove the least-squares plane, then taper with a 2-D Hann window.
    let c = (n as f64 - 1.0) / 2.0;
    let (mut sz, mut sxz, mut syz, mut sxx) = (0.0, 0.0, 0.0, 0.0);
    for y in 0..n {
        for x in 0..n {
            let (dx, dy, z) = (x as f64 - c, y as f64 - c, h[y * n + x] as f64);
            sz += z;
            sxz += dx * z;
            syz += dy * z;
            sxx += dx * dx;
        }
    }
    let (m, ax, ay) = (sz / (n * n) as f64, sxz / sxx, syz / sxx);
    let hann: Vec<f64> = (0..n).map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / (n - 1) as f64).cos()).collect();
    let mut re = vec![0.0; n * n];
    let mut im = vec![0.0; n * n];
    for y in 0..n {
        for x in 0..n {
            re[y * n + x] = (h[y * n + x] as f64 - m - ax * (x as f64 - c) - ay * (y as f64 - c)) * hann[x] * hann[y];
        }
    }
    for y in 0..n {
        fft(&mut re[y * n..(y + 1) * n], &mut im[y * n..(y + 1) * n]);
    }
    let (mut cr, mut ci) = (vec![0.0; n], vec![0.0; n]);
    for x in 0..n {
        for y in 0..n {
            cr[y] = re[y * n + x];
            ci[y] = im[y * n + x];
        }
        fft(&mut cr, &mut ci);
        for y in 0..n {
            re[y * n + x] = cr[y];
            im[y * n + x] = ci[y];
        }
    }
    // Radial bins of one wavenumber (cycles per window) each, from n/16 to n/4.
    let (k0, k1) = (n / 16, n / 4);
    let mut bins = vec![(0.0f64, 0usize); k1 + 1];
    for y in 0..n {
        for x in 0..n {
            let fx = if x <= n / 2 { x as f64 } else { x as f64 - n as f64 };
            let fy = if y <= n / 2 { y as f64 } else { y as f64 - n as f64 };
            let k = fx.hypot(fy).round() as usize;
            if (k0..=k1).contains(&k) {
                bins[k].0 += re[y * n + x].powi(2) + im[y * n + x].powi(2);
                bins[k].1 += 1;
            }
        }
    }
    let pts: Vec<(f64, f64)> = (k0..=k1).filter(|&k| bins[k].1 > 0 && bins[k].0 > 0.0).map(|k| ((k as f64).ln(), (bins[k].0 / bins[k].1 as f64).ln())).collect();
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / pts.len() as f64;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / pts.len() as f64;
    let num: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let den: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    if den > 0.0 { num / den } else { 0.0 }
}

/// The interquartile range / 1.349 of `v`, else its standard deviation if that is 0 (else 1).
pub fn spread(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let q = |p: f64| s[((s.len() - 1) as f64 * p).round() as usize];
    let iqr = (q(0.75) - q(0.25)) / 1.349;
    if iqr > 1e-12 {
        return iqr;
    }
    let m = mean(v);
    let sd = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
    if sd > 1e-12 { sd } else { 1.0 }
}

/// 1-D Wasserstein-1 distance between the empirical distributions `a` and `b` (through their
/// quantile functions at 256 levels).
pub fn wasserstein1(a: &[f64], b: &[f64]) -> f64 {
    let sorted = |v: &[f64]| {
        let mut s = v.to_vec();
        s.sort_by(f64::total_cmp);
        s
    };
    let (a, b) = (sorted(a), sorted(b));
    let q = |s: &[f64], p: f64| s[((s.len() - 1) as f64 * p).round() as usize];
    (0..256).map(|k| (k as f64 + 0.5) / 256.0).map(|p| (q(&a, p) - q(&b, p)).abs()).sum::<f64>() / 256.0
}

/// Per statistic (order of [`STAT_NAMES`]), the Wasserstein-1 distance between `set` and
/// `reference`, divided by the reference's [`spread`]; and their mean as the last element.
/// Both sets must be non-empty.
pub fn distance(set: &[Stats], reference: &[Stats]) -> Vec<f64> {
    distance_by(set, reference, Stats::values)
}

/// [`distance`] for any per-window statistics: `values` gives a window's `N` statistics.
pub fn distance_by<T, const N: usize>(set: &[T], reference: &[T], values: impl Fn(&T) -> [f64; N]) -> Vec<f64> {
    let mut per: Vec<f64> = (0..N)
        .map(|k| {
            let a: Vec<f64> = set.iter().map(|s| values(s)[k]).collect();
            let r: Vec<f64> = reference.iter().map(|s| values(s)[k]).collect();
            wasserstein1(&a, &r) / spread(&r)
        })
        .collect();
    per.push(mean(&per));
    per
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// An `n`×`n` field of heights `f(x, y)` (samples), row-major.
    pub(crate) fn field(n: usize, f: impl Fn(f64, f64) -> f64) -> Vec<f32> {
        (0..n * n).map(|p| f((p % n) as f64, (p / n) as f64) as f32).collect()
    }

    /// A plane rising 1 m per 10 m sample (gradient 0.1: 5.71°) has that slope everywhere,
    /// p90/p50 = 1, no depressions, a zero Laplacian and a local relief of 15 m per 16-sample
    /// block.
    #[test]
    fn a_plane_has_its_slope_and_no_depressions() {
        let h = field(64, |x, _| x);
        let s = measure(&h, 64, 10.0).unwrap();
        assert!((s.slope_mean_deg - 0.1f64.atan().to_degrees()).abs() < 1e-6, "{s:?}");
        assert!((s.slope_p90_over_p50 - 1.0).abs() < 1e-9);
        assert_eq!(s.depression_fraction, 0.0);
        assert_eq!((s.laplacian_skewness, s.laplacian_kurtosis), (0.0, 0.0));
        assert!((s.local_relief_m - 15.0).abs() < 1e-9);
    }

    /// A bowl (a paraboloid cut by the window's border) is a closed depression except at its
    /// rim: the filled area is the disc inside the lowest border height.
    #[test]
    fn a_bowl_is_a_closed_depression() {
        let n = 64;
        let h = field(n, |x, y| (x - 31.5).powi(2) + (y - 31.5).powi(2));
        let f = crate::world::drainage::depression_fraction(&h, n, 0.5);
        // The spill height is the border's minimum, 31.5² ≈ 992: the disc of radius ≈ 31.5
        // covers π·31.5² / 64² ≈ 0.76 of the window (minus the last half-metre ring).
        assert!((f - 0.76).abs() < 0.03, "{f}");
        let tilted = field(n, |x, y| (x - 31.5).powi(2) + (y - 31.5).powi(2) + 200.0 * x);
        assert!(crate::world::drainage::depression_fraction(&tilted, n, 0.5) < f, "tilting opens the bowl");
    }

    /// Fields synthesised with a power-law spectrum P ∝ k^β (random phases) measure β within
    /// 0.3 for β = −2, −3 and −4.
    #[test]
    fn spectral_slope_recovers_synthetic_power_laws() {
        let n = 128;
        for beta in [-2.0f64, -3.0, -4.0] {
            let mut h = vec![0f64; n * n];
            let mut seed = 1u64;
            for ky in -40i32..=40 {
                for kx in 0i32..=40 {
                    let k = ((kx * kx + ky * ky) as f64).sqrt();
                    if k < 1.0 {
                        continue;
                    }
                    seed = crate::grid::mix64(seed);
                    let phase = (seed >> 11) as f64 / (1u64 << 53) as f64 * std::f64::consts::TAU;
                    let amp = k.powf(beta / 2.0);
                    for y in 0..n {
                        for x in 0..n {
                            h[y * n + x] += amp * (std::f64::consts::TAU * (kx as f64 * x as f64 + ky as f64 * y as f64) / n as f64 + phase).cos();
                        }
                    }
                }
            }
            let hf: Vec<f32> = h.iter().map(|v| (*v * 100.0) as f32).collect();
            let b = spectral_slope(&hf, n);
            assert!((b - beta).abs() < 0.3, "β {beta}: measured {b}");
        }
    }

    /// Identical sets are at distance 0; shifting one statistic of every window by the
    /// reference's spread gives 1 for it.
    #[test]
    fn distance_is_zero_for_equal_sets_and_counts_standard_deviations() {
        let base = Stats {
            slope_mean_deg: 10.0,
            slope_p90_over_p50: 2.0,
            laplacian_skewness: 0.0,
            laplacian_kurtosis: 1.0,
            spectral_slope: -3.0,
            depression_fraction: 0.01,
            local_relief_m: 50.0,
        };
        let set: Vec<Stats> = (0..100).map(|k| Stats { slope_mean_deg: k as f64, ..base }).collect();
        assert!(distance(&set, &set).iter().all(|&d| d == 0.0));
        let sd = spread(&set.iter().map(|s| s.slope_mean_deg).collect::<Vec<_>>());
        assert!((sd - 49.0 / 1.349).abs() < 1e-9, "interquartile range of 0..100 by the rounded quantiles: 74 − 25 = 49");
        let shifted: Vec<Stats> = set.iter().map(|s| Stats { slope_mean_deg: s.slope_mean_deg + sd, ..*s }).collect();
        let d = distance(&shifted, &set);
        assert!((d[0] - 1.0).abs() < 1e-9, "{d:?}");
        assert!((d[7] - 1.0 / 7.0).abs() < 1e-9);
        assert_eq!(measure(&[0.0; 100], 10, 1.0), Err(StatsError::Shape(100, 10)));
        assert_eq!(measure(&[f32::NAN; 32 * 32], 32, 1.0), Err(StatsError::NoData));
    }
}
