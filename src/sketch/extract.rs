//! Sketches from real terrain: the extractor that makes the generator's training pairs and the
//! page's example sketches.
//!
//! From a [`SKETCH_PX`]² height field: the heights are stretched to the format's 0–255 scale
//! (the target), the bands are its equal-interval quarters (band = ⌊h/64⌋), valleys are the
//! drainage network (D8 flow accumulation on the lightly smoothed terrain, kept where the
//! broadly smoothed terrain is concave) and ridges the same on the inverted terrain (where it
//! is convex). Stroke amounts follow the authors' sketches: the accumulation threshold is the
//! larger of a fixed catchment and the one that leaves a target share of centre-line pixels;
//! fragments shorter than a few pixels are dropped and the centre lines are drawn
//! [`STROKE_PX`] wide.

use super::baseline::stretch;
use super::{SKETCH_PX, STROKE_PX, Sketch};

/// Standard deviation (pixels) of the smoothing before flow routing.
pub const ROUTING_SIGMA_PX: f32 = 2.0;
/// Standard deviation (pixels) of the smoothing whose Laplacian tells concave from convex.
pub const SHAPE_SIGMA_PX: f32 = 8.0;
/// Smallest catchment (pixels) of a valley or ridge centre line.
pub const MIN_CATCHMENT_PX: f32 = 150.0;
/// Share of pixels on a valley centre line the threshold aims at (the authors' valley strokes
/// cover 0.9–2.5 % of a tile at 3 px wide).
pub const VALLEY_LINE_SHARE: f64 = 0.0055;
/// Share of pixels on a ridge centre line (the authors' ridges cover 1.0–3.5 %).
pub const RIDGE_LINE_SHARE: f64 = 0.0070;
/// Shortest centre-line fragment kept (pixels).
pub const MIN_FRAGMENT_PX: usize = 4;

/// A sketch and its target heights.
#[derive(Clone, Debug)]
pub struct Extracted {
    /// The sketch.
    pub sketch: Sketch,
    /// Heights on the format's 0–255 scale ([`SKETCH_PX`]², row-major; min 0, max 255).
    pub target: Vec<f32>,
}

/// Extracts the sketch of a [`SKETCH_PX`]² height field (any units, row-major); `None` if it
/// is flat or not finite.
pub fn extract(heights: &[f32]) -> Option<Extracted> {
    let n = SKETCH_PX * SKETCH_PX;
    if heights.len() != n || heights.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let mut target = heights.to_vec();
    let (lo, hi) = target.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    if hi - lo <= 0.0 {
        return None;
    }
    stretch(&mut target);
    let mut sketch = Sketch::filled(0);
    for p in 0..n {
        sketch.band[p] = ((target[p] / 64.0) as u8).min(3);
    }
    let routed = gaussian(&target, SKETCH_PX, ROUTING_SIGMA_PX);
    let shape = gaussian(&target, SKETCH_PX, SHAPE_SIGMA_PX);
    let lap = laplacian(&shape, SKETCH_PX);
    let valley_acc = accumulation(&routed, SKETCH_PX);
    let inverted: Vec<f32> = routed.iter().map(|v| -v).collect();
    let ridge_acc = accumulation(&inverted, SKETCH_PX);
    let valley_line = lines(&valley_acc, |p| lap[p] > 0.0, VALLEY_LINE_SHARE);
    let ridge_line = lines(&ridge_acc, |p| lap[p] < 0.0, RIDGE_LINE_SHARE);
    sketch.valley = dilate(&valley_line, SKETCH_PX, STROKE_PX / 2);
    sketch.ridge = dilate(&ridge_line, SKETCH_PX, STROKE_PX / 2);
    Some(Extracted { sketch, target })
}

/// Centre-line pixels: accumulation above the larger of [`MIN_CATCHMENT_PX`] and the threshold
/// that leaves `share` of the pixels (among those where `keep` holds), without fragments
/// shorter than [`MIN_FRAGMENT_PX`].
fn lines(acc: &[f32], keep: impl Fn(usize) -> bool, share: f64) -> Vec<bool> {
    let mut cand: Vec<f32> = (0..acc.len()).filter(|&p| keep(p)).map(|p| acc[p]).collect();
    let want = ((acc.len() as f64 * share) as usize).max(1);
    let threshold = if cand.len() > want {
        let k = cand.len() - want;
        *cand.select_nth_unstable_by(k, f32::total_cmp).1
    } else {
        0.0
    }
    .max(MIN_CATCHMENT_PX);
    let mask: Vec<bool> = (0..acc.len()).map(|p| keep(p) && acc[p] >= threshold).collect();
    drop_small(&mask, MIN_FRAGMENT_PX)
}

/// D8 flow accumulation (pixels, each counting itself): every pixel drains to its steepest
/// lower neighbour; pits and edges keep their water.
pub fn accumulation(h: &[f32], side: usize) -> Vec<f32> {
    let n = side * side;
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_unstable_by(|&a, &b| h[b].total_cmp(&h[a]));
    let mut acc = vec![1f32; n];
    for &p in &order {
        let (x, y) = ((p % side) as i64, (p / side) as i64);
        let mut best = None;
        let mut best_slope = 0f32;
        for dy in -1..=1i64 {
            for dx in -1..=1i64 {
                let (u, v) = (x + dx, y + dy);
                if (dx, dy) == (0, 0) || u < 0 || v < 0 || u >= side as i64 || v >= side as i64 {
                    continue;
                }
                let q = v as usize * side + u as usize;
                let dist = if dx != 0 && dy != 0 { std::f32::consts::SQRT_2 } else { 1.0 };
                let slope = (h[p] - h[q]) / dist;
                if slope > best_slope {
                    best_slope = slope;
                    best = Some(q);
                }
            }
        }
        if let Some(q) = best {
            acc[q] += acc[p];
        }
    }
    acc
}

/// Separable Gaussian blur of a `side`² grid (edges clamp), standard deviation `sigma` pixels.
pub fn gaussian(src: &[f32], side: usize, sigma: f32) -> Vec<f32> {
    let r = (3.0 * sigma).ceil() as i64;
    let k: Vec<f32> = (-r..=r).map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp()).collect();
    let sum: f32 = k.iter().sum();
    let k: Vec<f32> = k.iter().map(|v| v / sum).collect();
    let clamp = |i: i64| i.clamp(0, side as i64 - 1) as usize;
    let mut tmp = vec![0f32; side * side];
    for y in 0..side {
        for x in 0..side {
            tmp[y * side + x] = (-r..=r).map(|i| k[(i + r) as usize] * src[y * side + clamp(x as i64 + i)]).sum();
        }
    }
    let mut out = vec![0f32; side * side];
    for y in 0..side {
        for x in 0..side {
            out[y * side + x] = (-r..=r).map(|i| k[(i + r) as usize] * tmp[clamp(y as i64 + i) * side + x]).sum();
        }
    }
    out
}

/// 5-point Laplacian of a `side`² grid (edges clamp).
pub fn laplacian(h: &[f32], side: usize) -> Vec<f32> {
    let at = |x: i64, y: i64| h[y.clamp(0, side as i64 - 1) as usize * side + x.clamp(0, side as i64 - 1) as usize];
    (0..side * side)
        .map(|p| {
            let (x, y) = ((p % side) as i64, (p / side) as i64);
            at(x - 1, y) + at(x + 1, y) + at(x, y - 1) + at(x, y + 1) - 4.0 * at(x, y)
        })
        .collect()
}

/// Square dilation by `r` pixels.
pub fn dilate(mask: &[bool], side: usize, r: usize) -> Vec<bool> {
    let mut out = vec![false; mask.len()];
    let r = r as i64;
    for (p, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        let (x, y) = ((p % side) as i64, (p / side) as i64);
        for v in (y - r).max(0)..=(y + r).min(side as i64 - 1) {
            for u in (x - r).max(0)..=(x + r).min(side as i64 - 1) {
                out[v as usize * side + u as usize] = true;
            }
        }
    }
    out
}

/// The mask (a [`SKETCH_PX`]² grid) without its 8-connected components of fewer than `min`
/// pixels.
pub fn drop_small(mask: &[bool], min: usize) -> Vec<bool> {
    assert_eq!(mask.len(), SKETCH_PX * SKETCH_PX, "a sketch-sized mask");
    let mut out = vec![false; mask.len()];
    for comp in super::regions::Components::of_mask(mask).members().into_iter().filter(|c| c.len() >= min) {
        comp.into_iter().for_each(|p| out[p] = true);
    }
    out
}

/// How a person redraws an extracted sketch (the generator's training augmentation, so that
/// sketches drawn with the page's brushes make natural terrain too): people draw band borders
/// as smooth blobs, not as the wiggly contours of real terrain, and draw fewer, smoother
/// strokes than the drainage network has.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HandDrawn {
    /// Standard deviation (pixels) of the smoothing of the terrain whose quarters become the
    /// bands: the larger, the blobbier the borders and the fewer the small islands.
    pub band_sigma_px: f32,
    /// Standard deviation (pixels) of the smoothing of the stroke masks (0: as extracted).
    pub stroke_sigma_px: f32,
    /// Share (0–1) of the ridge and of the valley strokes (8-connected pieces) kept.
    pub keep_strokes: f32,
}

/// The sketch a person might draw of `e`'s terrain ([`HandDrawn`]): bands are the quarters of
/// the target smoothed by `style.band_sigma_px`, with regions smaller than a brush dot
/// ([`super::tidy::MIN_REGION_PX`]) taken into the band around them; each ridge and valley piece is kept where `keep(piece
/// index)` is below `style.keep_strokes` (`keep` returns a number in 0–1), then smoothed by
/// `style.stroke_sigma_px` and drawn at least [`STROKE_PX`] wide. The target is unchanged:
/// the generator learns the terrain, not the drawing.
pub fn hand_drawn(e: &Extracted, style: &HandDrawn, mut keep: impl FnMut(usize) -> f32) -> Sketch {
    let n = SKETCH_PX * SKETCH_PX;
    let smooth = if style.band_sigma_px > 0.0 { gaussian(&e.target, SKETCH_PX, style.band_sigma_px) } else { e.target.clone() };
    let mut sketch = Sketch::filled(0);
    for p in 0..n {
        sketch.band[p] = ((smooth[p] / 64.0).max(0.0) as u8).min(3);
    }
    super::tidy::merge_islands(&mut sketch, &[], &[]);
    let mut piece = 0;
    for (from, to) in [(&e.sketch.ridge, &mut sketch.ridge), (&e.sketch.valley, &mut sketch.valley)] {
        let mut kept = vec![false; n];
        for comp in super::regions::Components::of_mask(from).members() {
            if keep(piece) < style.keep_strokes {
                comp.into_iter().for_each(|p| kept[p] = true);
            }
            piece += 1;
        }
        if style.stroke_sigma_px > 0.0 {
            let soft = gaussian(&kept.iter().map(|&k| if k { 1.0 } else { 0.0 }).collect::<Vec<f32>>(), SKETCH_PX, style.stroke_sigma_px);
            // A 3 px line blurred keeps about 3 / (2.5 σ) of its height at its centre: half of
            // that is its edge.
            let edge = (STROKE_PX as f32 / (2.5 * style.stroke_sigma_px)).min(1.0) * 0.5;
            kept = soft.iter().map(|&v| v >= edge).collect();
        }
        *to = kept;
    }
    sketch
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A valley running north–south down the middle of a tilted plane.
    fn v_valley() -> Vec<f32> {
        (0..SKETCH_PX * SKETCH_PX)
            .map(|p| {
                let (x, y) = ((p % SKETCH_PX) as f32, (p / SKETCH_PX) as f32);
                (x - 127.5).abs() * 2.0 + y * 0.5
            })
            .collect()
    }

    #[test]
    fn a_v_shaped_valley_is_found_on_its_axis_and_bands_are_height_quarters() {
        let e = extract(&v_valley()).unwrap();
        let valley_cols: Vec<usize> = (0..SKETCH_PX * SKETCH_PX).filter(|&p| e.sketch.valley[p]).map(|p| p % SKETCH_PX).collect();
        assert!(valley_cols.len() > 100, "{} valley pixels", valley_cols.len());
        assert!(valley_cols.iter().all(|&x| (126..=129).contains(&x)), "valley off the axis: {:?}", &valley_cols[..10]);
        // No ridge on the valley floor.
        assert!((0..SKETCH_PX * SKETCH_PX).filter(|&p| e.sketch.ridge[p]).all(|p| !(120..136).contains(&(p % SKETCH_PX))));
        for p in 0..SKETCH_PX * SKETCH_PX {
            assert_eq!(e.sketch.band[p], ((e.target[p] / 64.0) as u8).min(3));
        }
        let (lo, hi) = e.target.iter().fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        assert_eq!((lo, hi), (0.0, 255.0));
    }

    /// Rugged terrain: a tilted plane with bumps of several sizes, so its quarters have
    /// ragged borders and small islands.
    fn rugged() -> Vec<f32> {
        (0..SKETCH_PX * SKETCH_PX)
            .map(|p| {
                let (x, y) = ((p % SKETCH_PX) as f32, (p / SKETCH_PX) as f32);
                y + 20.0 * (x * 0.11).sin() * (y * 0.07).cos() + 6.0 * (x * 0.53 + y * 0.31).sin() + (x - 127.5).abs() * 0.6
            })
            .collect()
    }

    /// Redrawn with smoothed bands, a sketch has no band region under a brush dot (the
    /// extracted one of the same terrain has some), keeps every stroke pixel with all pieces
    /// kept and no smoothing, and has no stroke with none kept; the bands still follow the
    /// terrain (≥ 85 % of pixels in the same band).
    #[test]
    fn a_redrawn_sketch_has_no_region_under_a_brush_dot_and_keeps_or_drops_whole_strokes() {
        let e = extract(&rugged()).unwrap();
        let small = crate::sketch::tidy::MIN_REGION_PX;
        assert!(crate::sketch::tidy::band_islands(&e.sketch, small) > 0, "the test terrain has small islands");
        let style = HandDrawn { band_sigma_px: 8.0, stroke_sigma_px: 0.0, keep_strokes: 1.0 };
        let all = hand_drawn(&e, &style, |_| 0.5);
        assert_eq!(crate::sketch::tidy::band_islands(&all, small), 0);
        assert_eq!((all.ridge.clone(), all.valley.clone()), (e.sketch.ridge.clone(), e.sketch.valley.clone()));
        let same = (0..SKETCH_PX * SKETCH_PX).filter(|&p| all.band[p] == e.sketch.band[p]).count();
        assert!(same * 100 >= SKETCH_PX * SKETCH_PX * 85, "{same} pixels keep their band");
        let none = hand_drawn(&e, &HandDrawn { keep_strokes: 0.0, ..style }, |_| 0.5);
        assert!(!none.ridge.iter().chain(&none.valley).any(|&s| s));
        assert!(e.sketch.valley.iter().any(|&v| v), "the test terrain has valleys");
        let smooth = hand_drawn(&e, &HandDrawn { stroke_sigma_px: 2.0, ..style }, |_| 0.5);
        let count = |m: &[bool]| m.iter().filter(|&&v| v).count();
        let (before, after) = (count(&e.sketch.valley), count(&smooth.valley));
        assert!(after * 10 >= before * 8, "smoothed valleys keep most of their pixels: {before} → {after}");
    }

    #[test]
    fn accumulation_on_a_plane_tilted_east_adds_up_each_row() {
        let side = 16;
        let h: Vec<f32> = (0..side * side).map(|p| -((p % side) as f32)).collect();
        let acc = accumulation(&h, side);
        // Every row drains east along itself (straight east is the steepest descent).
        for y in 0..side {
            assert_eq!(acc[y * side + side - 1], side as f32, "row {y}");
        }
        assert!(extract(&vec![3.0; SKETCH_PX * SKETCH_PX]).is_none());
    }
}
