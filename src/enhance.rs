//! Enhancing a whole DEM with the TEM ladder (`terrain enhance`): the DEM becomes the input
//! grid of the first refined level and is refined patch by patch through the same
//! [`PatchStore`] the world's quadtree uses, level by level, down to the output spacing.

use crate::dem::Heightfield;
use crate::grid::TileCoord;
use crate::models::tem::{LEVEL_SPACING_M, LEVELS, PATCH, TemSet};
use crate::world::pins::Pins;
use crate::world::refine::{PatchKey, PatchStore, RefineInput, run_blocking};

/// Why a DEM cannot be enhanced; the message names the option or the input at fault.
#[derive(Debug, thiserror::Error)]
pub enum EnhanceError {
    /// The input spacing is not one the ladder starts from.
    #[error("--input-res must be one of 32, 16, 8, 4, 2 (m per pixel), got {0}")]
    InputRes(f64),
    /// The output spacing is not one the ladder makes.
    #[error("--output-res must be one of 16, 8, 4, 2, 1 (m per pixel), got {0}")]
    OutputRes(f64),
    /// The output spacing is not finer than the input's.
    #[error("--output-res {output_m} must be finer than --input-res {input_m}")]
    NotFiner {
        /// Input spacing (m per pixel).
        input_m: f64,
        /// Output spacing (m per pixel).
        output_m: f64,
    },
    /// The output would exceed [`MAX_OUTPUT_SAMPLES`].
    #[error("the output would be {width} × {height} samples, more than the {MAX_OUTPUT_SAMPLES} this command makes at once: crop the input or choose a coarser --output-res")]
    TooLarge {
        /// Output width (samples).
        width: u64,
        /// Output height (samples).
        height: u64,
    },
    /// The input has no samples.
    #[error("the input DEM is empty")]
    Empty,
    /// Every input sample is no-data.
    #[error("the input DEM has no valid sample (all no-data)")]
    AllNoData,
    /// Refinement failed (a patch could not be started or a model failed).
    #[error("refining level {level}: {reason}")]
    Refine {
        /// The ladder level.
        level: usize,
        /// What went wrong.
        reason: String,
    },
}

/// A DEM as refinement input: pixel (x, y) of the grid is DEM sample (x, y); outside the DEM
/// the edge is replicated, so edge patches see a plausible context.
pub struct DemInput {
    hf: Heightfield,
}

impl DemInput {
    /// Wraps a DEM without no-data (fill it first).
    pub fn new(hf: Heightfield) -> Self {
        Self { hf }
    }
}

impl RefineInput for DemInput {
    fn window(&self, x0: i64, y0: i64, side: usize) -> Option<Vec<f32>> {
        let (w, h) = (self.hf.width as i64, self.hf.height as i64);
        let mut out = Vec::with_capacity(side * side);
        for y in y0..y0 + side as i64 {
            let yy = y.clamp(0, h - 1) as usize;
            for x in x0..x0 + side as i64 {
                out.push(self.hf.at(x.clamp(0, w - 1) as usize, yy));
            }
        }
        Some(out)
    }
}

/// The ladder levels (first, last) that take `input_res_m` to `output_res_m`: the input must
/// be one of 32/16/8/4/2 m and the output one of 16/8/4/2/1 m below it.
pub fn levels_for(input_res_m: f64, output_res_m: f64) -> Result<(usize, usize), EnhanceError> {
    let first = (0..LEVELS).find(|&k| (2.0 * LEVEL_SPACING_M[k] - input_res_m).abs() < 1e-9).ok_or(EnhanceError::InputRes(input_res_m))?;
    let last = (0..LEVELS).find(|&k| (LEVEL_SPACING_M[k] - output_res_m).abs() < 1e-9).ok_or(EnhanceError::OutputRes(output_res_m))?;
    if last < first {
        return Err(EnhanceError::NotFiner { input_m: input_res_m, output_m: output_res_m });
    }
    Ok((first, last))
}

/// Largest output `enhance` makes (samples): 2²⁷ = 134,217,728 (a square of up to 11,585²). The output, the
/// stored patches of the last level (≈ 1.6× the output) and the level above them take about
/// 1.5 GiB at this size.
pub const MAX_OUTPUT_SAMPLES: u64 = 1 << 27;

/// The size (width, height) of the output for an input of `width × height` refined over
/// `levels` levels, or an error if it exceeds [`MAX_OUTPUT_SAMPLES`].
pub fn output_size(width: usize, height: usize, levels: usize) -> Result<(usize, usize), EnhanceError> {
    let f = 1u64 << levels;
    let (w, h) = ((width as u64).saturating_mul(f), (height as u64).saturating_mul(f));
    if w.saturating_mul(h) > MAX_OUTPUT_SAMPLES {
        return Err(EnhanceError::TooLarge { width: w, height: h });
    }
    Ok((w as usize, h as usize))
}

/// Progress of [`enhance`]: (level, patches done at that level, patches at that level).
pub type Progress<'a> = &'a mut dyn FnMut(usize, usize, usize);

/// Enhances `input` (metres at `input_res_m` per pixel, NaN = no data) to `output_res_m`:
/// the output covers the same extent with 2^levels times the pixels per side; no-data input
/// pixels stay no-data (their area in the output is NaN). Returns the result and the
/// refinement counters.
pub fn enhance(
    input: &Heightfield,
    input_res_m: f64,
    output_res_m: f64,
    tem: &TemSet,
    batch: usize,
    progress: Progress,
) -> Result<(Heightfield, crate::world::RefineStats), EnhanceError> {
    enhance_pinned(input, input_res_m, output_res_m, tem, batch, &Pins::new(), TileCoord::new(0, 0), progress)
}

/// [`enhance`] of a region of the 32 m world whose north-west sample is that of tile
/// `origin`, where `pins` keep their own detail ([`PatchStore::with_pins`]): the refined
/// region is the pinned terrain's own heights at every level it has them for.
#[allow(clippy::too_many_arguments)]
pub fn enhance_pinned(
    input: &Heightfield,
    input_res_m: f64,
    output_res_m: f64,
    tem: &TemSet,
    batch: usize,
    pins: &Pins,
    origin: TileCoord,
    progress: Progress,
) -> Result<(Heightfield, crate::world::RefineStats), EnhanceError> {
    let (first, last) = levels_for(input_res_m, output_res_m)?;
    if input.width == 0 || input.height == 0 {
        return Err(EnhanceError::Empty);
    }
    let (w, h) = output_size(input.width, input.height, last - first + 1)?;
    let filled = input.fill_nodata().ok_or(EnhanceError::AllNoData)?;
    let source = DemInput::new(filled);
    let mut store = PatchStore::new(first, 0).with_pins(pins.clone(), origin);
    for level in first..=last {
        let scale = 2usize << (level - first);
        let (lw, lh) = (input.width * scale, input.height * scale);
        let (nx, ny) = (lw.div_ceil(PATCH) as i64, lh.div_ceil(PATCH) as i64);
        let total = (nx * ny) as usize;
        let mut done = 0;
        // Every patch of the level, in row order, in batches: each parent is stored already.
        let keys: Vec<PatchKey> = (0..ny).flat_map(|y| (0..nx).map(move |x| PatchKey { level: level as u8, x, y })).collect();
        for chunk in keys.chunks(batch.max(1)) {
            let jobs = store.jobs_for(chunk, &source);
            if jobs.len() != chunk.len() {
                return Err(EnhanceError::Refine { level, reason: format!("{} patches could not be started", chunk.len() - jobs.len()) });
            }
            done += run_blocking(&mut store, tem, jobs, |_| true).map_err(|reason| EnhanceError::Refine { level, reason })?;
            progress(level, done, total);
        }
        if level > first {
            store.drop_level(level - 1);
        }
    }
    let f = w / input.width;
    let mut data = Vec::with_capacity(w * h);
    for py in 0..h {
        for px in 0..w {
            let v = if input.at(px / f, py / f).is_nan() {
                f32::NAN
            } else {
                store.pixel(last, px as i64, py as i64).ok_or_else(|| EnhanceError::Refine { level: last, reason: format!("pixel ({px}, {py}) is missing") })?
            };
            data.push(v);
        }
    }
    // Same extent: the north-west corner stays where it was.
    Ok((Heightfield::new(w, h, LEVEL_SPACING_M[last], data).with_geo(input.geo), store.stats()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::models::tem::Exec;

    #[test]
    fn levels_follow_the_resolutions() {
        assert_eq!(levels_for(32.0, 1.0).unwrap(), (0, 4));
        assert_eq!(levels_for(16.0, 8.0).unwrap(), (1, 1));
        assert_eq!(levels_for(4.0, 1.0).unwrap(), (3, 4));
        assert!(matches!(levels_for(30.0, 1.0), Err(EnhanceError::InputRes(r)) if r == 30.0));
        assert!(matches!(levels_for(32.0, 3.0), Err(EnhanceError::OutputRes(r)) if r == 3.0));
        assert!(matches!(levels_for(8.0, 16.0), Err(EnhanceError::NotFiner { .. })));
        assert!(levels_for(30.0, 1.0).unwrap_err().to_string().contains("--input-res"));
    }

    /// A 10,000² input at ×32 would be 10¹¹ samples: refused before any work, with the
    /// limit in the message; the largest allowed size passes the check.
    #[test]
    fn outputs_beyond_the_limit_are_refused_up_front() {
        let e = output_size(10_000, 10_000, 5).unwrap_err().to_string();
        assert!(e.contains("320000 × 320000") && e.contains(&MAX_OUTPUT_SAMPLES.to_string()), "{e}");
        assert_eq!(output_size(362, 362, 5).unwrap(), (11_584, 11_584));
        assert!(output_size(363, 363, 5).is_err(), "11,616² > 2²⁷");
        assert!(output_size(usize::MAX / 2, 3, 5).is_err(), "no overflow");
        let tem = TemSet::untrained(&Exec::cpu());
        let big = Heightfield::new(400, 400, 32.0, vec![100.0; 400 * 400]);
        let mut calls = 0;
        let err = enhance(&big, 32.0, 1.0, &tem, 4, &mut |_, _, _| calls += 1).unwrap_err().to_string();
        assert!(err.contains("crop the input"), "{err}");
        assert_eq!(calls, 0, "refused before any patch was made");
    }

    /// Untrained models are bicubic at every level: the enhanced DEM keeps the input's extent,
    /// size × 2^levels, its area means and its no-data.
    #[test]
    fn enhance_keeps_extent_means_and_nodata() {
        let (w, h) = (37, 21);
        let mut data: Vec<f32> = (0..w * h).map(|k| ((k % w) as f32 * 0.4).sin() * 30.0 + (k / w) as f32 * 2.0 + 500.0).collect();
        data[3 * w + 5] = f32::NAN;
        let hf = Heightfield::new(w, h, 32.0, data);
        let tem = TemSet::untrained(&Exec::cpu());
        let mut calls = 0;
        let (out, stats) = enhance(&hf, 32.0, 8.0, &tem, 4, &mut |_, _, _| calls += 1).unwrap();
        assert_eq!((out.width, out.height, out.spacing_m), (w * 4, h * 4, 8.0));
        assert!(out.at(5 * 4 + 1, 3 * 4 + 2).is_nan());
        assert_eq!(out.data.iter().filter(|v| v.is_nan()).count(), 16);
        assert!(calls > 0 && stats.quads_made > 0);
        // Away from the edges, 4×4 means of the output are close to the input.
        let mut worst = 0f32;
        for y in 4..h - 4 {
            for x in 8..w - 4 {
                let m: f32 = (0..16).map(|k| out.at(x * 4 + k % 4, y * 4 + k / 4)).sum::<f32>() / 16.0;
                worst = worst.max((m - hf.at(x, y)).abs());
            }
        }
        assert!(worst < 2.0, "{worst}");
        assert!(matches!(enhance(&Heightfield::new(2, 2, 32.0, vec![f32::NAN; 4]), 32.0, 16.0, &tem, 4, &mut |_, _, _| ()), Err(EnhanceError::AllNoData)));
    }

    /// A rough 8 m DEM (520² samples) pinned on tile (5, −3), keeping its 8 m detail: the
    /// tile and the pins.
    fn rough_8m_pin() -> (TileCoord, Pins) {
        let n = 520;
        let rough = |x: usize, y: usize| 1200.0 + x as f32 * 0.3 + (x as f32 * 0.9).sin() * 6.0 + (y as f32 * 1.3).cos() * 4.0;
        let dem = Heightfield::new(n, n, 8.0, (0..n * n).map(|k| rough(k % n, k / n)).collect());
        let origin = TileCoord::new(5, -3);
        let mut pins = Pins::new();
        assert_eq!(pins.add(&dem, origin).unwrap().detail_m, Some(8.0));
        (origin, pins)
    }

    /// The same pinned 8 m tile with a soft edge (a square of 256 × 256 m pixels, 128–383, in
    /// its middle, fading over 256 m; a small sketch set into the world's own tile): refined to
    /// 8 m (random TEM weights), the square is the pin's 8 m heights bit for bit, and pixels
    /// over 512 m from it are what the region makes without the pin, bit for bit; within 200 m
    /// of it, where the two differ by over 1 m, under 5 % of the pixels are either (a blend).
    #[test]
    fn a_soft_edged_pin_holds_its_square_and_gives_way_to_the_tems_refinement_outside_it() {
        let (origin, pins) = rough_8m_pin();
        // 8 m pixel p of the origin tile has its centre at 8p + 4 − 16 m from the tile's corner.
        let world = |p: f64, o: i32| o as f64 * crate::grid::TILE_SIZE_M + 8.0 * p - 16.0;
        let soft = crate::world::pins::SoftEdge { min_m: [world(128.0, origin.i), world(128.0, origin.j)], max_m: [world(384.0, origin.i), world(384.0, origin.j)], fade_m: 256.0 };
        let pin = pins.get(origin).unwrap().clone().with_soft_edge(soft);
        let mut soft_pins = Pins::new();
        soft_pins.insert_tile(origin, pin.clone()).unwrap();
        let t = crate::grid::TILE_SAMPLES;
        let input = Heightfield::new(t, t, 32.0, pin.fine.to_vec());
        let random = crate::world::refine::tests::scrambled();
        let (pinned, _) = enhance_pinned(&input, 32.0, 8.0, &random, 4, &soft_pins, origin, &mut |_, _, _| ()).unwrap();
        let (free, _) = enhance(&input, 32.0, 8.0, &random, 4, &mut |_, _, _| ()).unwrap();
        let d8 = pin.detail(1).unwrap();
        let (mut far, mut fade, mut either) = (0, 0, 0);
        for y in 0..512 {
            for x in 0..512 {
                let (p, f, d) = (pinned.data[y * 512 + x], free.data[y * 512 + x], d8[y * 512 + x]);
                let out = |v: usize| if v < 128 { 128 - v } else { v.saturating_sub(383) };
                let dist = 8.0 * ((out(x) as f64).powi(2) + (out(y) as f64).powi(2)).sqrt();
                if dist == 0.0 {
                    assert_eq!(p.to_bits(), d.to_bits(), "in the square ({x}, {y})");
                } else if dist > 512.0 {
                    assert_eq!(p.to_bits(), f.to_bits(), "far from the square ({x}, {y})");
                    far += 1;
                } else if dist < 200.0 && (d - f).abs() > 1.0 {
                    fade += 1;
                    either += (p == d || p == f) as usize;
                }
            }
        }
        assert!(far > 10_000 && fade > 1000, "{far} pixels far, {fade} in the fade checked");
        // Near the square (weight ≈ 1) the blend may round to the pin's height.
        assert!(either * 20 < fade, "{either} of {fade} pixels in the fade are the pin's or the free TEM's");
    }

    /// A pinned tile of 8 m terrain in a 2 × 1-tile region: refined to 8 m (random TEM
    /// weights, so the TEM's own output is far from it), the pinned tile is the pin's 8 m
    /// heights bit for bit, and the tile beside it from 80 px (640 m) on is what the region
    /// makes without the pin, bit for bit. Refined on to 4 m (bicubic TEM), the pinned tile's
    /// 2 × 2 means follow the pin's 8 m heights (largest difference < 4 m: bicubic overshoots
    /// on its 7 m waves; 3.0 m measured), more than 5 times closer than the TEM's guess from
    /// 32 m without the pin (25.3 m).
    #[test]
    fn a_pins_own_detail_is_the_refined_terrain_at_its_levels_and_the_level_below_refines_it() {
        let (origin, pins) = rough_8m_pin();
        let pin = pins.get(origin).unwrap().clone();
        let t = crate::grid::TILE_SAMPLES;
        let input = Heightfield::new(
            2 * t,
            t,
            32.0,
            (0..2 * t * t).map(|k| if k % (2 * t) < t { pin.fine[(k / (2 * t)) * t + k % (2 * t)] } else { 1250.0 + (k % (2 * t)) as f32 * 0.5 }).collect(),
        );
        let random = crate::world::refine::tests::scrambled();
        let (pinned, _) = enhance_pinned(&input, 32.0, 8.0, &random, 4, &pins, origin, &mut |_, _, _| ()).unwrap();
        let (free, _) = enhance(&input, 32.0, 8.0, &random, 4, &mut |_, _, _| ()).unwrap();
        assert_eq!((pinned.width, pinned.height), (1024, 512));
        let d8 = pin.detail(1).unwrap();
        let mut off = 0f32;
        for y in 0..512 {
            for x in 0..1024 {
                let (p, f) = (pinned.data[y * 1024 + x], free.data[y * 1024 + x]);
                if x < 512 {
                    assert_eq!(p.to_bits(), d8[y * 512 + x].to_bits(), "pinned ({x}, {y})");
                    off = off.max((f - p).abs());
                } else if x >= 512 + 80 {
                    assert_eq!(p.to_bits(), f.to_bits(), "beside ({x}, {y})");
                }
            }
        }
        assert!(off > 1.0, "the TEM's own 8 m output differs from the pin's by {off} m at most");
        let bicubic = TemSet::untrained(&Exec::cpu());
        let means = |hf: &Heightfield| {
            let left = hf.window(0, 0, 1024, 1024).downsample2();
            left.data.iter().zip(d8).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max)
        };
        let (p4, _) = enhance_pinned(&input, 32.0, 4.0, &bicubic, 4, &pins, origin, &mut |_, _, _| ()).unwrap();
        let (f4, _) = enhance(&input, 32.0, 4.0, &bicubic, 4, &mut |_, _, _| ()).unwrap();
        let (mp, mf) = (means(&p4), means(&f4));
        eprintln!("4 m 2×2 means vs the pin's 8 m: pinned {mp:.3} m, without the pin {mf:.3} m (largest)");
        assert!(mp < 4.0 && mf > 5.0 * mp, "pinned {mp}, free {mf}");
    }
}
