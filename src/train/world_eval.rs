//! Evaluating a world against real terrain: geomorphometric statistics ([`crate::geomorph`])
//! of windows cut from the validation split of real DEMs at 32 m and from generated regions,
//! the distance between their distributions, and the seam, crease and edge-strip figures.

use crate::dem::Heightfield;
use crate::geomorph::{self, Stats};
use crate::grid::coord::{BASE_SPACING_M, TILE_SAMPLES, TileCoord};
use crate::world::tile::{Neighbourhood, TileSource, paste};

use super::pairs::{Dem, Split, split_columns};

/// Window sides (samples at 32 m) the statistics are measured on.
pub const WINDOW_SIDES: [usize; 2] = [128, 256];

/// Real windows of side `side` at 32 m from the validation split (east third) of every DEM
/// with spacing ≤ 32 m, area-averaged to 32 m, on a grid of stride `side / 2`.
pub fn real_windows(dems: &[Dem], side: usize) -> Vec<Vec<f32>> {
    let mut out = Vec::new();
    for d in dems.iter().filter(|d| d.hf.spacing_m <= BASE_SPACING_M + 1e-9) {
        let Ok(hf) = d.hf.resample_area(BASE_SPACING_M) else { continue };
        let columns = split_columns(hf.width, Split::Validation);
        push_valid_windows(&hf, columns, side, &mut out);
    }
    out
}

/// Pushes onto `out` every `side`² window of `hf` with all samples valid, on a grid of stride
/// `side / 2` over the columns `columns` (first, end) and all rows.
fn push_valid_windows(hf: &Heightfield, (c0, c1): (usize, usize), side: usize, out: &mut Vec<Vec<f32>>) {
    let stride = side / 2;
    let mut y = 0;
    while y + side <= hf.height {
        let mut x = c0;
        while x + side <= c1 {
            let w = hf.window(x, y, side, side);
            if w.data.iter().all(|v| v.is_finite()) {
                out.push(w.data);
            }
            x += stride;
        }
        y += stride;
    }
}

/// A `w`×`h`-tile region of `source`'s world `seed` with top-left tile `origin` (metres,
/// row-major, `w`·128 samples wide).
pub fn region(source: &dyn TileSource, seed: u64, origin: TileCoord, w: usize, h: usize) -> Heightfield {
    let n = TILE_SAMPLES;
    let mut data = vec![0f32; w * n * h * n];
    for tj in 0..h {
        for ti in 0..w {
            let t = source.generate(seed, origin.offset(ti as i32, tj as i32), &Neighbourhood::default());
            paste(&mut data, w * n, &t.heights, n, ti * n, tj * n);
        }
    }
    Heightfield::new(w * n, h * n, BASE_SPACING_M, data)
}

/// The drainage statistics ([`crate::geomorph::drainage`]) of 32 m windows of side `side`.
pub fn drainage_of(windows: &[Vec<f32>], side: usize) -> Vec<crate::geomorph::drainage::Drainage> {
    windows.iter().map(|w| crate::geomorph::drainage::measure(w, side, BASE_SPACING_M)).collect()
}

/// Windows of side `side` on a grid of stride `side / 2` over `hf` (offset by a quarter
/// window so that tile edges fall inside windows, not only on their borders).
pub fn windows_of(hf: &Heightfield, side: usize) -> Vec<Vec<f32>> {
    let mut out = Vec::new();
    let mut y = side / 4;
    while y + side <= hf.height {
        let mut x = side / 4;
        while x + side <= hf.width {
            out.push(hf.window(x, y, side, side).data);
            x += side / 2;
        }
        y += side / 2;
    }
    out
}

/// The statistics of every window (windows that cannot be measured are skipped).
pub fn stats_of(windows: &[Vec<f32>], side: usize) -> Vec<Stats> {
    windows.iter().filter_map(|w| geomorph::measure(w, side, BASE_SPACING_M).ok()).collect()
}

/// The grid alignment of a `side`² window at 32 m (metres, row-major): the size of the 8-fold
/// harmonic of its gradient directions, each weighted by its slope (|Σ g·e^{8iθ}| / Σ g over
/// the samples steeper than 2 %, centred differences). Flow cut along the grid's eight
/// directions (D8 rills, straight channels) raises it; real terrain's valleys run every way:
/// `terrain eval-tcm`'s held-out real windows (256² at 32 m) average 0.015.
pub fn grid_alignment(window: &[f32], side: usize) -> f64 {
    let (mut re, mut im, mut sum) = (0f64, 0f64, 0f64);
    let at = |x: usize, y: usize| window[y * side + x] as f64;
    for y in 1..side.saturating_sub(1) {
        for x in 1..side.saturating_sub(1) {
            let (gx, gy) = ((at(x + 1, y) - at(x - 1, y)) / (2.0 * BASE_SPACING_M), (at(x, y + 1) - at(x, y - 1)) / (2.0 * BASE_SPACING_M));
            let g = gx.hypot(gy);
            if g > 0.02 {
                let theta = gy.atan2(gx);
                re += g * (8.0 * theta).cos();
                im += g * (8.0 * theta).sin();
                sum += g;
            }
        }
    }
    if sum > 0.0 { re.hypot(im) / sum } else { 0.0 }
}

/// Factor by which [`orientation_coherence`] area-averages a window at 32 m: to 128 m, the
/// TCM's spacing.
pub const COHERENCE_AVERAGE: usize = 4;

/// Side (samples at 128 m) of the boxes [`orientation_coherence`] averages the structure
/// tensor over: 1152 m.
pub const COHERENCE_BOX_PX: usize = 9;

/// How elongated the forms of a `side`² window at 32 m (metres, row-major) are: the window
/// area-averaged to 128 m ([`COHERENCE_AVERAGE`]), its gradients (forward differences) and
/// their structure tensor `J` averaged over every [`COHERENCE_BOX_PX`]² box; per box the
/// coherence `√((Jxx − Jyy)² + 4·Jxy²) / (Jxx + Jyy)` (0: gradients every way, round bumps;
/// 1: all parallel, the sides of one ridge or valley); the mean over the boxes. Parallel
/// ridges score 1.0 and an egg-crate of 2 km bumps 0.12 (tests); seed 42's learned world
/// ~0.35 and the real Mont Blanc massif ~0.53. The same measure as the TCM trainer's
/// coherence term ([`crate::train::tcm::coherence_gap`]).
pub fn orientation_coherence(window: &[f32], side: usize) -> f64 {
    coherence_averaged(window, side, COHERENCE_AVERAGE)
}

/// [`orientation_coherence`] with the window area-averaged by `f` (e.g. 16: to 512 m, boxes of
/// 4.6 km: [`large_scale`]).
pub fn coherence_averaged(window: &[f32], side: usize, f: usize) -> f64 {
    let n = side / f;
    let mut a = vec![0f64; n * n];
    for y in 0..n * f {
        for x in 0..n * f {
            a[(y / f) * n + x / f] += window[y * side + x] as f64 / (f * f) as f64;
        }
    }
    let m = n - 1;
    // The structure tensor's three parts over the (n − 1)² samples with both differences.
    let mut j = [vec![0f64; m * m], vec![0f64; m * m], vec![0f64; m * m]];
    for y in 0..m {
        for x in 0..m {
            let (dx, dy) = (a[y * n + x + 1] - a[y * n + x], a[(y + 1) * n + x] - a[y * n + x]);
            j[0][y * m + x] = dx * dx;
            j[1][y * m + x] = dy * dy;
            j[2][y * m + x] = dx * dy;
        }
    }
    let b = COHERENCE_BOX_PX;
    if m < b {
        return 0.0;
    }
    let box_sum = |v: &[f64], x0: usize, y0: usize| -> f64 { (y0..y0 + b).map(|y| v[y * m + x0..y * m + x0 + b].iter().sum::<f64>()).sum() };
    let (mut sum, mut count) = (0f64, 0usize);
    for y0 in 0..=m - b {
        for x0 in 0..=m - b {
            let (xx, yy, xy) = (box_sum(&j[0], x0, y0), box_sum(&j[1], x0, y0), box_sum(&j[2], x0, y0));
            let trace = xx + yy;
            if trace > 0.0 {
                sum += ((xx - yy).powi(2) + 4.0 * xy * xy).sqrt() / trace;
            }
            count += 1;
        }
    }
    sum / count.max(1) as f64
}

/// Side of the squares [`large_scale`] measures (metres): 24,576 m, a 6×6-tile region.
pub const LARGE_SQUARE_M: f64 = 6.0 * crate::grid::TILE_SIZE_M;

/// Spacing (metres) [`large_scale`] measures flow paths at: the TCM's.
pub const LARGE_SPACING_M: f64 = 128.0;

/// The large-scale figures of a square of side [`LARGE_SQUARE_M`] (`h`, row-major, `n`² samples
/// at [`LARGE_SPACING_M`]): (the longest flow path over the square in km
/// ([`crate::geomorph::drainage::longest_flow_path_m`]), the orientation coherence of the
/// square area-averaged to 512 m ([`coherence_averaged`]: how far main ridges and valleys run
/// side by side rather than every way)).
pub fn large_scale(h: &[f32], n: usize) -> (f64, f64) {
    (crate::geomorph::drainage::longest_flow_path_m(h, n, LARGE_SPACING_M) / 1e3, coherence_averaged(h, n, 4))
}

/// Squares of side [`LARGE_SQUARE_M`] at [`LARGE_SPACING_M`] from every real DEM of spacing
/// ≤ [`LARGE_SPACING_M`] with room for one, on a grid of stride half a square, all samples
/// valid. Both splits: too few DEMs have a held-out third 24 km wide (the TCM sees 12 km at a
/// time, so it cannot have learned a square's layout).
pub fn real_squares(dems: &[Dem]) -> Vec<Vec<f32>> {
    let side = (LARGE_SQUARE_M / LARGE_SPACING_M) as usize;
    let mut out = Vec::new();
    for d in dems.iter().filter(|d| d.hf.spacing_m <= LARGE_SPACING_M + 1e-9) {
        let Ok(hf) = d.hf.resample_area(LARGE_SPACING_M) else { continue };
        push_valid_windows(&hf, (0, hf.width), side, &mut out);
    }
    out
}

/// The seam figure of a region made of whole tiles, for each interior tile edge (128 samples
/// long): the mean |height step| across the edge divided by the mean |step| between the
/// neighbouring rows (or columns) inside the two tiles (the 4 on either side). Real terrain,
/// which has no seams, scores about 1 on average but spreads widely from edge to edge: over
/// the validation DEMs cut into 128-sample tiles the 95th percentile is about 1.4. Summed up
/// over edges by [`mean_p95`].
pub fn seam_ratios(hf: &Heightfield) -> Vec<f64> {
    edge_ratios(hf, |get, c| (get(c) - get(c - 1)).abs(), 1..=4)
}

/// The crease figure of a region made of whole tiles, for each interior tile edge: as
/// [`seam_ratios`] with the change of slope (|second difference|, centred between two
/// samples) instead of the step, so a tile edge whose heights meet but whose slopes do not (a
/// fold, a ridge or a gully along the edge) counts too. The second differences straddling
/// each edge against those 2–5 samples inside the two tiles; 1 for a field without seams.
pub fn crease_ratios(hf: &Heightfield) -> Vec<f64> {
    edge_ratios(hf, |get, c| (get(c + 1) - get(c) - get(c - 1) + get(c - 2)).abs(), 2..=5)
}

/// (mean, 95th percentile) of `v`; NaN for none.
pub fn mean_p95(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    (v.iter().sum::<f64>() / v.len() as f64, v[((v.len() - 1) as f64 * 0.95).round() as usize])
}

/// The seam figure as step distributions, pooled over all the interior tile edges of
/// `fields` (each made of whole tiles): (mean |step| across the edges / mean |step| between
/// the rows 1–4 inside the tiles, 95th percentile of the former / that of the latter). A
/// world with steps along its tile edges has more large steps there than inside its tiles;
/// a field without seams scores 1 on both, to within its own variation.
pub fn seam_steps(fields: &[Heightfield]) -> (f64, f64) {
    let n = TILE_SAMPLES;
    let (mut edge, mut inner) = (Vec::new(), Vec::new());
    for hf in fields {
        let at = |x: usize, y: usize| hf.data[y * hf.width + x] as f64;
        for vertical in [true, false] {
            let (along, across) = if vertical { (hf.height, hf.width) } else { (hf.width, hf.height) };
            for e in (n..across).step_by(n).filter(|&e| e + 4 < across) {
                for a in 0..along {
                    let get = |c: usize| if vertical { at(c, a) } else { at(a, c) };
                    edge.push((get(e) - get(e - 1)).abs());
                    for k in 1..=4 {
                        inner.push((get(e + k) - get(e + k - 1)).abs());
                        inner.push((get(e - k) - get(e - k - 1)).abs());
                    }
                }
            }
        }
    }
    let ((edge_mean, edge_p95), (inner_mean, inner_p95)) = (mean_p95(&edge), mean_p95(&inner));
    (edge_mean / inner_mean, edge_p95 / inner_p95)
}

/// Samples of 32 m per 128 m sample (the TCM's scale) for [`edge_strip_ratio`].
const STRIP_POOL: usize = 4;
/// The strip along each tile edge that [`edge_strip_ratio`] measures: 128 m samples 1 to 4
/// inside the edge (the edge sample itself is what [`crease_ratios`] sees).
const STRIP: std::ops::RangeInclusive<usize> = 1..=4;
/// Where [`edge_strip_ratio`]'s interior starts: 128 m samples from the tile edge.
const STRIP_INTERIOR_FROM: usize = 8;

/// The edge-strip figure of a region made of whole tiles: the region area-averaged to 128 m
/// (the scale the tiles are made at), then the mean |second difference| across the edges'
/// direction (x for the vertical edges, y for the horizontal ones) over the strips 1–4
/// samples inside every tile edge, divided by the same mean over the tiles' interiors
/// (≥ 8 samples from every edge). 1 for a field without tiles; a world whose tiles are
/// smooth inside and busy along their edges — a tile grid the eye sees although heights and
/// slopes meet at the edge itself — scores above 1.
pub fn edge_strip_ratio(hf: &Heightfield) -> f64 {
    let (p, t) = (STRIP_POOL, TILE_SAMPLES / STRIP_POOL);
    let (w, h) = (hf.width / p, hf.height / p);
    let coarse: Vec<f64> = (0..w * h)
        .map(|k| {
            let (x, y) = (k % w * p, k / w * p);
            (0..p * p).map(|q| hf.data[(y + q / p) * hf.width + x + q % p] as f64).sum::<f64>() / (p * p) as f64
        })
        .collect();
    let at = |x: usize, y: usize| coarse[y * w + x];
    let from_edge = |v: usize| (v % t).min(t - 1 - v % t);
    let (mut strip, mut ns, mut inner, mut ni) = (0.0, 0, 0.0, 0);
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let across_x = (at(x + 1, y) - 2.0 * at(x, y) + at(x - 1, y)).abs();
            let across_y = (at(x, y + 1) - 2.0 * at(x, y) + at(x, y - 1)).abs();
            // (samples from the edge the curvature crosses, from the other pair of edges).
            for (d, other, curvature) in [(from_edge(x), from_edge(y), across_x), (from_edge(y), from_edge(x), across_y)] {
                if STRIP.contains(&d) {
                    strip += curvature;
                    ns += 1;
                } else if d >= STRIP_INTERIOR_FROM && other >= STRIP_INTERIOR_FROM {
                    inner += curvature;
                    ni += 1;
                }
            }
        }
    }
    if ns == 0 || ni == 0 || inner <= 0.0 {
        return f64::NAN;
    }
    (strip / ns as f64) / (inner / ni as f64)
}

/// Per tile edge (128 samples, or what the field has of it): the mean of `diff` at the edge
/// (position `e`) over its mean at `e ± k` for `k` in `inside`.
fn edge_ratios(hf: &Heightfield, diff: impl Fn(&dyn Fn(usize) -> f64, usize) -> f64, inside: std::ops::RangeInclusive<usize>) -> Vec<f64> {
    let n = TILE_SAMPLES;
    let at = |x: usize, y: usize| hf.data[y * hf.width + x] as f64;
    let mut ratios = Vec::new();
    // Vertical edges (between tile columns) per tile row, then horizontal ones.
    for vertical in [true, false] {
        let (along, across) = if vertical { (hf.height, hf.width) } else { (hf.width, hf.height) };
        for e in (n..across).step_by(n).filter(|&e| e + *inside.end() < across) {
            for seg in (0..along).step_by(n) {
                let (mut edge, mut inner, mut count_inner) = (0.0, 0.0, 0);
                for a in seg..(seg + n).min(along) {
                    let get = |c: usize| if vertical { at(c, a) } else { at(a, c) };
                    edge += diff(&get, e);
                    for k in inside.clone() {
                        inner += diff(&get, e + k) + diff(&get, e - k);
                        count_inner += 2;
                    }
                }
                let edge = edge / ((seg + n).min(along) - seg) as f64;
                let inner = inner / count_inner as f64;
                if inner > 1e-6 {
                    ratios.push(edge / inner);
                }
            }
        }
    }
    ratios
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A cone (slopes facing every way alike) has a grid alignment under 0.01; a square
    /// pyramid (four faces along the grid's axes) and one turned by 22.5° (faces between the
    /// eight directions, which the 8-fold harmonic counts alike) over 0.9.
    #[test]
    fn grid_alignment_is_low_for_a_cone_and_high_for_pyramids() {
        let side = 128;
        let c = (side as f64 - 1.0) / 2.0;
        let field = |f: &dyn Fn(f64, f64) -> f64| -> Vec<f32> { (0..side * side).map(|p| f((p % side) as f64 - c, (p / side) as f64 - c) as f32).collect() };
        // The cone ends in a plain 60 samples out, so the square window adds no corners.
        let cone = grid_alignment(&field(&|x, y| 2000.0 - 10.0 * x.hypot(y).min(60.0)), side);
        let pyramid = grid_alignment(&field(&|x, y| 2000.0 - 10.0 * x.abs().max(y.abs())), side);
        let (s, k) = (22.5f64.to_radians().sin(), 22.5f64.to_radians().cos());
        let turned = grid_alignment(&field(&|x, y| 2000.0 - 10.0 * (k * x + s * y).abs().max((k * y - s * x).abs())), side);
        assert!(cone < 0.01, "cone {cone}");
        assert!(pyramid > 0.9 && turned > 0.9, "pyramid {pyramid}, turned {turned}");
    }

    /// Parallel ridges 3 km apart (turned off the grid) have an orientation coherence over
    /// 0.95, with 50 m of noise on them still over 0.85; an egg-crate of 2 km bumps under 0.2.
    #[test]
    fn orientation_coherence_is_high_for_ridges_and_low_for_an_egg_crate() {
        let side = 256;
        let field = |f: &dyn Fn(f64, f64) -> f64| -> Vec<f32> { (0..side * side).map(|p| f((p % side) as f64 * 32.0, (p / side) as f64 * 32.0) as f32).collect() };
        let tau = std::f64::consts::TAU;
        let ridges = orientation_coherence(&field(&|x, y| 300.0 * (tau * (0.8 * x + 0.6 * y) / 3000.0).sin()), side);
        let noisy = orientation_coherence(
            &field(&|x, y| 300.0 * (tau * (0.8 * x + 0.6 * y) / 3000.0).sin() + 50.0 * crate::models::tcm::gauss(crate::grid::mix64((x * 7.0 + y * 1e5) as u64)) as f64),
            side,
        );
        let egg = orientation_coherence(&field(&|x, y| 300.0 * (tau * x / 2000.0).sin() * (tau * y / 2000.0).sin()), side);
        assert!(ridges > 0.95, "ridges {ridges}");
        assert!(noisy > 0.85, "noisy ridges {noisy}");
        assert!(egg < 0.2, "egg-crate {egg}");
    }

    /// A region whose tiles are offset by 10 m each has a seam ratio far above 1 along the
    /// shifted edges; a smooth continuous field has a ratio of 1.
    #[test]
    fn seam_ratio_is_one_for_continuous_fields_and_large_for_steps() {
        let n = TILE_SAMPLES;
        let smooth = Heightfield::new(2 * n, 2 * n, 32.0, (0..4 * n * n).map(|p| ((p % (2 * n)) as f32 * 0.1).sin() * 5.0 + (p / (2 * n)) as f32 * 0.7).collect());
        let (mean, _) = mean_p95(&seam_ratios(&smooth));
        assert!((mean - 1.0).abs() < 0.1, "{mean}");
        let stepped = Heightfield::new(2 * n, 2 * n, 32.0, smooth.data.iter().enumerate().map(|(p, v)| v + if p % (2 * n) >= n { 10.0 } else { 0.0 }).collect());
        let (_, p95) = mean_p95(&seam_ratios(&stepped));
        assert!(p95 > 5.0, "{p95}");
    }

    /// The pooled step figure of a continuous field is within 10 % of 1 on both mean and
    /// 95th percentile; with every second tile raised 10 m both exceed 5.
    #[test]
    fn seam_steps_are_one_for_continuous_fields_and_large_for_steps() {
        let n = TILE_SAMPLES;
        let smooth = Heightfield::new(2 * n, 2 * n, 32.0, (0..4 * n * n).map(|p| ((p % (2 * n)) as f32 * 0.1).sin() * 5.0 + (p / (2 * n)) as f32 * 0.7).collect());
        let (mean, p95) = seam_steps(std::slice::from_ref(&smooth));
        assert!((mean - 1.0).abs() < 0.1 && (p95 - 1.0).abs() < 0.1, "{mean} {p95}");
        let stepped = Heightfield::new(2 * n, 2 * n, 32.0, smooth.data.iter().enumerate().map(|(p, v)| v + if p % (2 * n) >= n { 10.0 } else { 0.0 }).collect());
        let (mean, p95) = seam_steps(&[smooth, stepped]);
        assert!(mean > 5.0 && p95 > 5.0, "{mean} {p95}");
    }

    /// A field of the same ripples everywhere has an edge-strip figure within 5 % of 1; the
    /// same ripples 3× stronger within 4 × 128 m of every tile edge score above 2.
    #[test]
    fn edge_strip_ratio_is_one_without_tiles_and_large_for_busy_edges() {
        let n = TILE_SAMPLES;
        let side = 4 * n;
        let ripple = |p: usize| (((p % side) as f32) * 0.21).sin() * 20.0 + (((p / side) as f32) * 0.17).sin() * 20.0;
        let plain = Heightfield::new(side, side, 32.0, (0..side * side).map(ripple).collect());
        let r = edge_strip_ratio(&plain);
        assert!((r - 1.0).abs() < 0.05, "{r}");
        let near = |v: usize| (v % n).min(n - 1 - v % n) < 5 * STRIP_POOL;
        let busy = Heightfield::new(side, side, 32.0, (0..side * side).map(|p| ripple(p) * if near(p % side) || near(p / side) { 3.0 } else { 1.0 }).collect());
        let r = edge_strip_ratio(&busy);
        assert!(r > 2.0, "{r}");
    }

    /// A bowl (constant curvature) has a crease figure of 1; the same bowl folded along a
    /// tile edge (a V of ±3 m per sample) keeps its seam figure below 1.1 — the heights meet —
    /// while its crease figure exceeds 100.
    #[test]
    fn crease_ratio_is_one_for_a_bowl_and_large_for_a_fold_the_seam_ratio_misses() {
        let n = TILE_SAMPLES;
        let bowl = |p: usize| 0.002 * ((p % (2 * n)) as f32).powi(2) + 0.003 * ((p / (2 * n)) as f32).powi(2);
        let smooth = Heightfield::new(2 * n, 2 * n, 32.0, (0..4 * n * n).map(bowl).collect());
        let (mean, p95) = mean_p95(&crease_ratios(&smooth));
        assert!((mean - 1.0).abs() < 0.01 && (p95 - 1.0).abs() < 0.01, "{mean} {p95}");
        let folded = Heightfield::new(2 * n, 2 * n, 32.0, (0..4 * n * n).map(|p| bowl(p) + 3.0 * ((p % (2 * n)) as f32 - n as f32 + 0.5).abs()).collect());
        let (seam, _) = mean_p95(&seam_ratios(&folded));
        assert!(seam < 1.1, "seam {seam}");
        let (_, p95) = mean_p95(&crease_ratios(&folded));
        assert!(p95 > 100.0, "crease {p95}");
    }
}
