//! The world of a sketch: the terrain made from the sketch canvas ([`crate::sketch`]) placed
//! on the 2 × 2 tiles around the origin (its 256² samples at the world's 32 m: 8,192 m
//! across), heights = the terrain's 0–255 scale × relief / 255 metres. Around it the ground
//! falls smoothly from the sketch's edge to 0 m over [`FADE_M`]; beyond that it is flat. The
//! falling ground follows the sketch's edge smoothed more the farther out it is (a box mean
//! of the sketch around the nearest edge sample, as wide as the distance), so the edge's
//! valleys and ridges do not run out as straight stripes across the plain.
//!
//! Where the learned world's models are at hand the sketch's tiles are pinned into it instead
//! ([`SketchSource::pins`]) and the learned world grows around them; this fading plain is the
//! world while they load, and the fallback when they fail.

use std::sync::Arc;

use super::pins::Pins;
use super::{BASE_SPACING_M, Neighbourhood, TILE_SAMPLES, Tile, TileCoord, TileSource};
use crate::sketch::SKETCH_PX;

/// Ground extent of the sketch's tile (metres): its [`SKETCH_PX`] samples at the world's
/// 32 m, 8,192 m (the generator is told it: [`crate::models::sketch::extent_value`]).
pub const SKETCH_EXTENT_M: f64 = SKETCH_PX as f64 * BASE_SPACING_M;

/// Distance over which the ground around the sketch falls to 0 m (metres).
pub const FADE_M: f64 = 4096.0;
/// Default relief of a sketch (metres between its lowest and highest point).
pub const DEFAULT_RELIEF_M: f64 = 1500.0;
/// Reliefs a sketch may be given (metres).
pub const RELIEF_M: std::ops::RangeInclusive<f64> = 10.0..=8000.0;
/// First world sample (x and z) covered by the sketch: it is centred on the origin.
pub const FIRST_SAMPLE: i64 = -(SKETCH_PX as i64) / 2;
/// The tiles the sketch covers, row-major.
pub const SKETCH_TILES: [TileCoord; 4] = [TileCoord { i: -1, j: -1 }, TileCoord { i: 0, j: -1 }, TileCoord { i: -1, j: 0 }, TileCoord { i: 0, j: 0 }];

/// Tile source of a sketch's terrain.
pub struct SketchSource {
    heights: Arc<Vec<f32>>,
    relief_m: f32,
    /// Summed-area table of the heights ((SKETCH_PX + 1)², row-major): box means in O(1).
    sums: Vec<f64>,
}

impl SketchSource {
    /// The world of `heights` ([`SKETCH_PX`]² on the 0–255 scale) with `relief_m` metres from
    /// 0 to 255 (clamped to [`RELIEF_M`]).
    pub fn new(heights: Arc<Vec<f32>>, relief_m: f64) -> Self {
        assert_eq!(heights.len(), SKETCH_PX * SKETCH_PX, "a sketch's terrain is {SKETCH_PX}² samples");
        let n = SKETCH_PX;
        let mut sums = vec![0f64; (n + 1) * (n + 1)];
        for y in 0..n {
            for x in 0..n {
                sums[(y + 1) * (n + 1) + x + 1] = heights[y * n + x] as f64 + sums[y * (n + 1) + x + 1] + sums[(y + 1) * (n + 1) + x] - sums[y * (n + 1) + x];
            }
        }
        Self { heights, relief_m: relief_m.clamp(*RELIEF_M.start(), *RELIEF_M.end()) as f32, sums }
    }

    /// Mean height (0–255 scale) of the sketch over the box of half-width `r` samples around
    /// (`cu`, `cv`), cut to the sketch.
    fn box_mean(&self, cu: i64, cv: i64, r: i64) -> f64 {
        let n = SKETCH_PX as i64;
        let (x0, x1, y0, y1) = ((cu - r).max(0), (cu + r).min(n - 1), (cv - r).max(0), (cv + r).min(n - 1));
        let at = |x: i64, y: i64| self.sums[(y * (n + 1) + x) as usize];
        let sum = at(x1 + 1, y1 + 1) - at(x0, y1 + 1) - at(x1 + 1, y0) + at(x0, y0);
        sum / ((x1 - x0 + 1) * (y1 - y0 + 1)) as f64
    }

    /// The 2 × 2 tiles the sketch covers ([`SKETCH_TILES`]) as pins of the learned world
    /// ([`super::learned::LearnedSource::with_pins`]): its terrain in metres, sample for
    /// sample, so the learned world grows around the sketch.
    pub fn pins(&self) -> Pins {
        let mut pins = Pins::new();
        for c in SKETCH_TILES {
            let tile = self.tile(c);
            pins.insert(c, tile.heights).expect("a sketch's terrain is finite (checked when it arrives)");
        }
        pins
    }

    /// Tile `coord` of this world.
    pub fn tile(&self, coord: TileCoord) -> Tile {
        let (x0, z0) = (coord.i as i64 * TILE_SAMPLES as i64, coord.j as i64 * TILE_SAMPLES as i64);
        let heights = (0..TILE_SAMPLES * TILE_SAMPLES).map(|p| self.height(x0 + (p % TILE_SAMPLES) as i64, z0 + (p / TILE_SAMPLES) as i64)).collect();
        Tile::new(coord, heights)
    }

    /// Height (metres) at world sample (`gx`, `gz`).
    pub fn height(&self, gx: i64, gz: i64) -> f32 {
        let n = SKETCH_PX as i64;
        let (u, v) = (gx - FIRST_SAMPLE, gz - FIRST_SAMPLE);
        let (cu, cv) = (u.clamp(0, n - 1), v.clamp(0, n - 1));
        if (cu, cv) == (u, v) {
            return self.heights[(cv * n + cu) as usize] / 255.0 * self.relief_m;
        }
        // The first sample out holds the edge sample's height (r = 0); farther out, the box
        // widens with the distance.
        let r = (u - cu).abs().max((v - cv).abs()) - 1;
        let h = self.box_mean(cu, cv, r) / 255.0 * self.relief_m as f64;
        let d = libm::hypot((u - cu) as f64, (v - cv) as f64) * BASE_SPACING_M;
        let t = (1.0 - d / FADE_M).max(0.0);
        (h * t * t) as f32
    }
}

impl TileSource for SketchSource {
    fn name(&self) -> String {
        format!("sketch ({:.0} m relief)", self.relief_m)
    }

    fn uses_neighbours(&self) -> bool {
        false
    }

    fn far_tile(&self, _seed: u64, coord: TileCoord) -> Option<Vec<f32>> {
        Some(super::stream::far_samples(coord, |gx, gz| self.height(gx, gz)))
    }

    fn generate(&self, _seed: u64, coord: TileCoord, _neighbours: &Neighbourhood<'_>) -> Tile {
        self.tile(coord)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sketch_covers_the_four_tiles_at_the_origin_and_fades_to_zero_4_km_out() {
        let h: Vec<f32> = (0..SKETCH_PX * SKETCH_PX).map(|p| (p % SKETCH_PX) as f32 / (SKETCH_PX - 1) as f32 * 255.0).collect();
        let src = SketchSource::new(Arc::new(h), 1000.0);
        let tile = src.generate(1, TileCoord::new(0, 0), &Neighbourhood::default());
        // Tile (0, 0) holds sketch columns 128..256: its last column is the sketch's top.
        assert_eq!(tile.heights[TILE_SAMPLES - 1], 1000.0);
        assert!((tile.heights[0] - 128.0 / 255.0 * 1000.0).abs() < 1e-3);
        let west = src.generate(1, TileCoord::new(-1, 0), &Neighbourhood::default());
        assert_eq!(west.heights[0], 0.0, "the sketch's lowest column");
        // East of the sketch: the edge height, falling to 0 at FADE_M.
        assert!((src.height(128, 0) - 1000.0 * (1.0 - 32.0 / 4096.0f32).powi(2)).abs() < 1e-2);
        assert_eq!(src.height(127 + 128, 0), 0.0);
        assert!(src.generate(1, TileCoord::new(3, 0), &Neighbourhood::default()).heights.iter().all(|&v| v == 0.0));
    }

    /// An edge striped across (a ridge every 21 samples along it) does not run out as stripes:
    /// 64 samples (2 km) out, the height varies along a line beside the edge by under 2 % of
    /// what the edge does (drawn straight out, faded, it would be 25 %); the first sample out
    /// holds the edge's height.
    #[test]
    fn the_ground_around_the_sketch_has_no_stripes() {
        let h: Vec<f32> = (0..SKETCH_PX * SKETCH_PX).map(|p| 127.5 + 127.5 * ((p / SKETCH_PX) as f32 * 0.3).sin()).collect();
        let src = SketchSource::new(Arc::new(h), 1000.0);
        let east = -FIRST_SAMPLE - 1;
        let variation = |gx: i64| (FIRST_SAMPLE + 64..-FIRST_SAMPLE - 64).map(|gz| (src.height(gx, gz + 1) - src.height(gx, gz)).abs()).sum::<f32>();
        let (edge, out) = (variation(east), variation(east + 64));
        eprintln!("variation along the edge {edge:.0} m, 64 samples out {out:.1} m");
        assert!(out < 0.02 * edge, "{out} vs {edge}");
        assert!((src.height(east + 1, 5) - src.height(east, 5) * (1.0 - 32.0 / 4096.0f32).powi(2)).abs() < 1e-3);
    }
}
