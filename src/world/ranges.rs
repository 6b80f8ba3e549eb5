//! The learned world's large scale: ranges and main valleys that drain by construction, the
//! macro field the TCM grows its tiles on.
//!
//! The TCM only sees 12 km around a tile; what it is given as the macro field decides where
//! the main ridges and valleys of a 24 km view run. A seeded bilinear field over 4 km tile
//! centres gave it none (round massifs of one size), while a real range's 2 km means put the
//! main ridge and valley in place (issue 39's oracle trial). This module makes such a field:
//! - an uplift field [`uplift`]: seeded Perlin fBm at [`RANGE_SPACING_M`] (1,024 m), wavelengths
//!   [`UPLIFT_WAVELENGTH_M`] down to 3 km, stretched along the world's strike and bent by a
//!   warp field, so that ranges run side by side in arcs;
//! - eroded over square regions of [`REGION_SAMPLES`]² samples (64 km) half a region apart
//!   ([`super::erosion`], [`RANGE_EROSION`]; the stream-power law carves branching valley
//!   networks that run on for tens of kilometres, down to each region's border), each region's
//!   border fixed;
//! - a sample is the four regions that hold it blended with hat weights that vanish at each
//!   region's border ([`hat_weight`]), so the field is a pure function of (seed, position) with
//!   no seam;
//! - the TCM's macro cells are the field's means over 2,048 m cells ([`CELL_SAMPLES`]²
//!   samples): [`MACRO_CELLS`]² cells over its 12 km window ([`RangeField::macro_cells`]).
//!
//! Only IEEE-exact operations are used after the Perlin sums (which are exact too), so the
//! page's WebAssembly makes the same bits as native code.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use super::erosion::{self, Erosion};
use super::noise::perlin;
use crate::grid::coord::TileCoord;

/// Spacing of the range field (metres): 4 samples per 4,096 m tile. At 512 m the field looked
/// the same at the TCM's 2,048 m cells and its regions cost 4.7 times as much (the page's far
/// field to 60 km waited ~6 s more for them).
pub const RANGE_SPACING_M: f64 = 1024.0;
/// Samples of the range field per tile side.
pub const SAMPLES_PER_TILE: i64 = 4;
/// Side of an erosion region (samples): 64 km.
pub const REGION_SAMPLES: usize = 64;
/// Side of a macro cell (samples): 2,048 m.
pub const CELL_SAMPLES: usize = 2;
/// Macro cells a side over the TCM's 3×3-tile window ([`crate::models::tcm::macro_field_cells`]).
pub const MACRO_CELLS: usize = 6;
/// Mean level of the uplift field (metres).
pub const UPLIFT_BASE_M: f64 = 1900.0;
/// Amplitude of the uplift field's first octave (metres): the range field's 2,048 m cells then
/// step ~230 m from one to the next (root mean square), between the Colorado Rockies' 191 m
/// and the Pyrenees' 273 m (373 m around Mont Blanc, 521 m in the Annapurna range); more
/// amplitude drew parallel gullies down long steep flanks.
pub const UPLIFT_AMPLITUDE_M: f64 = 2300.0;
/// Wavelength of the uplift field's first octave across the strike (metres).
pub const UPLIFT_WAVELENGTH_M: f64 = 48_000.0;
/// Octaves of the uplift field (each half the wavelength of the one before).
pub const UPLIFT_OCTAVES: u64 = 5;
/// Each octave's amplitude over the one before's.
pub const PERSISTENCE: f64 = 0.65;
/// How much longer the uplift's forms are along the world's strike than across it: ranges
/// and main valleys run side by side in one direction ([`strike`]), as real ranges' do.
pub const STRETCH: f64 = 1.8;
/// Largest shift of the uplift field's positions by the warp field (metres), which bends the
/// ranges into arcs.
pub const WARP_M: f64 = 20_000.0;
/// Wavelength of the warp field (metres).
pub const WARP_WAVELENGTH_M: f64 = 80_000.0;
/// Below this level (metres) the uplift field falls [`LOWLAND_SLOPE`] as fast: broad lowlands
/// between the ranges instead of a fifth of the world under the sea.
pub const LOWLAND_M: f64 = 300.0;
/// How fast the uplift field falls below [`LOWLAND_M`] (a fraction of its fall above).
pub const LOWLAND_SLOPE: f64 = 0.5;
/// A high level of the range field (metres): the base plus the first octave's amplitude, the
/// scale of the terrain's colours.
pub const TOP_M: f32 = (UPLIFT_BASE_M + UPLIFT_AMPLITUDE_M) as f32;
/// The erosion of the range field's regions (parameters in samples of [`RANGE_SPACING_M`]):
/// water spread over all lower neighbours up to 64 samples of drainage area and stronger
/// hillslope diffusion than at 128 m, against the straight parallel rills one flow direction
/// per sample cuts.
pub const RANGE_EROSION: Erosion = Erosion { iterations: 60, k: 0.03, alpha: 0.01, kappa: 0.05, taper: 8.0, spread_below: 64.0 };
/// Eroded regions kept (each 16 KiB).
pub const REGION_CACHE: usize = 256;

const _: () = assert!(SAMPLES_PER_TILE as f64 * RANGE_SPACING_M == crate::grid::TILE_SIZE_M);
const _: () = assert!(3 * SAMPLES_PER_TILE as usize == MACRO_CELLS * CELL_SAMPLES);

/// The hat weight of sample `u` (along x or y) of a region `side` samples across:
/// (u + ½) / (side / 2) over the first half, mirrored over the second. With regions half their
/// side apart, the two that hold a sample along one axis weigh it by w and 1 − w; each is a
/// multiple of 1 / side, exact in f32.
pub fn hat_weight(u: usize, side: usize) -> f32 {
    let d = 2 * u + 1;
    d.min(2 * side - d) as f32 / side as f32
}

/// The strike of world `seed`: (cos, sin) of the direction its ranges run in, from the seed.
pub fn strike(seed: u64) -> (f64, f64) {
    let theta = (crate::grid::mix64(seed ^ 0x5354_5249_4B45) >> 11) as f64 / (1u64 << 53) as f64 * std::f64::consts::PI;
    // libm's own functions: the same bits natively and in the page's WebAssembly.
    (libm::cos(theta), libm::sin(theta))
}

/// The uplift field of world `seed` at range sample (gx, gy) (metres): [`UPLIFT_OCTAVES`]
/// octaves of Perlin noise at the sample's centre, its position bent by a warp field
/// ([`WARP_M`]) and turned to the world's [`strike`], along which it is stretched
/// ([`STRETCH`]).
pub fn uplift(seed: u64, gx: i64, gy: i64) -> f32 {
    let (x, y) = ((gx as f64 + 0.5) * RANGE_SPACING_M, (gy as f64 + 0.5) * RANGE_SPACING_M);
    let l = WARP_WAVELENGTH_M;
    let (x, y) = (x + WARP_M * perlin(seed ^ 0x5741_5250_0001, x / l, y / l), y + WARP_M * perlin(seed ^ 0x5741_5250_0002, x / l, y / l));
    let (c, s) = strike(seed);
    let (x, y) = ((x * c + y * s) / STRETCH, -x * s + y * c);
    let (mut sum, mut f, mut a) = (0.0, 1.0 / UPLIFT_WAVELENGTH_M, 1.0);
    for o in 0..UPLIFT_OCTAVES {
        sum += a * perlin(seed ^ 0x5241_4E47_4500 ^ o, x * f, y * f);
        f *= 2.0;
        a *= PERSISTENCE;
    }
    let h = UPLIFT_BASE_M + UPLIFT_AMPLITUDE_M * sum;
    (if h < LOWLAND_M { LOWLAND_M + LOWLAND_SLOPE * (h - LOWLAND_M) } else { h }) as f32
}

/// The eroded region (rx, ry) of world `seed` ([`REGION_SAMPLES`]², metres, row-major): its
/// corner sample is (rx, ry) × [`REGION_SAMPLES`] / 2.
pub fn eroded_region(seed: u64, rx: i64, ry: i64) -> Vec<f32> {
    let n = REGION_SAMPLES;
    let (x0, y0) = (rx * (n as i64 / 2), ry * (n as i64 / 2));
    let mut h: Vec<f32> = (0..n * n).map(|q| uplift(seed, x0 + (q % n) as i64, y0 + (q / n) as i64)).collect();
    erosion::erode(&mut h, n, None, &RANGE_EROSION);
    h
}

/// The range field every world shares ([`RangeField`]; regions are keyed by seed).
pub fn shared() -> &'static RangeField {
    static FIELD: std::sync::LazyLock<RangeField> = std::sync::LazyLock::new(RangeField::default);
    &FIELD
}

/// The macro level of tile `c` of world `seed` (metres): the mean of its 2×2 macro cells
/// ([`RangeField::macro_cells`], [`crate::models::tcm::centre_level`]), the level its TCM
/// tile's heights are taken relative to.
pub fn macro_level(seed: u64, c: TileCoord) -> f32 {
    crate::models::tcm::centre_level(&shared().macro_cells(seed, c), MACRO_CELLS)
}

/// Eroded regions by (world seed, region x, region y).
type RegionCache = HashMap<(u64, i64, i64), Arc<Vec<f32>>>;

/// The range field of a world: eroded regions made on demand and kept in a bounded cache.
#[derive(Default)]
pub struct RangeField {
    regions: Mutex<RegionCache>,
}

impl RangeField {
    /// The eroded region (rx, ry) of world `seed`, made if not cached.
    fn region(&self, seed: u64, rx: i64, ry: i64) -> Arc<Vec<f32>> {
        if let Some(r) = self.regions.lock().unwrap_or_else(|p| p.into_inner()).get(&(seed, rx, ry)) {
            return r.clone();
        }
        let r = Arc::new(eroded_region(seed, rx, ry));
        let mut cache = self.regions.lock().unwrap_or_else(|p| p.into_inner());
        if cache.len() >= REGION_CACHE {
            // Regions are remade identically: dropping them all only costs time.
            cache.clear();
        }
        cache.insert((seed, rx, ry), r.clone());
        r
    }

    /// The range field of world `seed` over `w`×`h` samples from sample (x0, y0) (metres,
    /// row-major): each sample the hat-weighted blend of the four regions that hold it.
    pub fn samples(&self, seed: u64, x0: i64, y0: i64, w: usize, h: usize) -> Vec<f32> {
        let half = REGION_SAMPLES as i64 / 2;
        let mut out = vec![0f32; w * h];
        for (q, v) in out.iter_mut().enumerate() {
            let (gx, gy) = (x0 + (q % w) as i64, y0 + (q / w) as i64);
            // The two regions along each axis whose corner is at most one region behind.
            let (ax, ay) = (gx.div_euclid(half) - 1, gy.div_euclid(half) - 1);
            let mut sum = 0f32;
            for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                let (rx, ry) = (ax + dx, ay + dy);
                let (u, t) = ((gx - rx * half) as usize, (gy - ry * half) as usize);
                let r = self.region(seed, rx, ry);
                sum += hat_weight(u, REGION_SAMPLES) * hat_weight(t, REGION_SAMPLES) * r[t * REGION_SAMPLES + u];
            }
            *v = sum;
        }
        out
    }

    /// The TCM's macro cells around tile `c` of world `seed` ([`MACRO_CELLS`]², metres,
    /// row-major over the 3×3 tiles centred on `c`): means of the range field over cells of
    /// [`CELL_SAMPLES`]² samples.
    pub fn macro_cells(&self, seed: u64, c: TileCoord) -> Vec<f32> {
        let side = MACRO_CELLS * CELL_SAMPLES;
        let (x0, y0) = ((c.i as i64 - 1) * SAMPLES_PER_TILE, (c.j as i64 - 1) * SAMPLES_PER_TILE);
        let s = self.samples(seed, x0, y0, side, side);
        let mut cells = vec![0f32; MACRO_CELLS * MACRO_CELLS];
        for (k, cell) in cells.iter_mut().enumerate() {
            let (ci, cj) = (k % MACRO_CELLS * CELL_SAMPLES, k / MACRO_CELLS * CELL_SAMPLES);
            let mut sum = 0f32;
            for v in 0..CELL_SAMPLES {
                for u in 0..CELL_SAMPLES {
                    sum += s[(cj + v) * side + ci + u];
                }
            }
            *cell = sum / (CELL_SAMPLES * CELL_SAMPLES) as f32;
        }
        cells
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Hat weights of two regions half a side apart sum to exactly 1 at every sample.
    #[test]
    fn hat_weights_of_offset_regions_sum_to_one() {
        for side in [4usize, 16, REGION_SAMPLES] {
            for u in side / 2..side {
                assert_eq!(hat_weight(u, side) + hat_weight(u - side / 2, side), 1.0, "side {side}, sample {u}");
            }
        }
    }

    /// A sample of the range field is the same whether it is read alone or inside a larger
    /// window, and from a fresh cache: a pure function of (seed, position).
    #[test]
    fn range_field_sample_does_not_depend_on_the_window_or_cache() {
        let a = RangeField::default().samples(5, 60, -70, 12, 9);
        let f = RangeField::default();
        let b = f.samples(5, 50, -80, 40, 30);
        for y in 0..9 {
            for x in 0..12 {
                assert_eq!(a[y * 12 + x].to_bits(), b[(y + 10) * 40 + x + 10].to_bits(), "sample ({x}, {y})");
            }
        }
    }

    /// Neighbouring 2,048 m cells of the range field step about as much as real mountain
    /// terrain's do (root mean square 191 m in the Colorado Rockies, 273–521 m over the
    /// Pyrenees, Ötztal, Mont Blanc and Annapurna DEMs; here 200–450 m over 131 km squares of
    /// two seeds), and each square spans more than 1,500 m.
    #[test]
    fn range_cells_step_like_real_alpine_cells() {
        for seed in [3, 11] {
            let n = 128;
            let s = RangeField::default().samples(seed, -64, -64, n, n);
            let m = n / CELL_SAMPLES;
            let cell = |i: usize, j: usize| {
                (0..CELL_SAMPLES * CELL_SAMPLES).map(|q| s[(j * CELL_SAMPLES + q / CELL_SAMPLES) * n + i * CELL_SAMPLES + q % CELL_SAMPLES] as f64).sum::<f64>()
                    / (CELL_SAMPLES * CELL_SAMPLES) as f64
            };
            let (mut sum2, mut k) = (0.0, 0usize);
            for j in 0..m - 1 {
                for i in 0..m - 1 {
                    sum2 += (cell(i + 1, j) - cell(i, j)).powi(2) + (cell(i, j + 1) - cell(i, j)).powi(2);
                    k += 2;
                }
            }
            let rms = (sum2 / k as f64).sqrt();
            let (lo, hi) = s.iter().fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
            println!("seed {seed}: rms cell step {rms:.0} m, range {lo:.0} .. {hi:.0} m");
            assert!((200.0..=450.0).contains(&rms), "seed {seed}: rms step {rms} m");
            assert!(hi - lo > 1500.0, "seed {seed}: range {lo} .. {hi}");
        }
    }

    /// The macro cells of tile (i, j) are the means of the range field over 2×2-sample cells of
    /// the 12×12 samples around it, and neighbouring tiles share their overlapping cells.
    #[test]
    fn macro_cells_are_cell_means_shared_by_neighbours() {
        let f = RangeField::default();
        let c = TileCoord::new(3, -2);
        let cells = f.macro_cells(9, c);
        let s = f.samples(9, 2 * 4, -3 * 4, 12, 12);
        let mean: f32 = (0..2).flat_map(|v| (0..2).map(move |u| (v, u))).map(|(v, u)| s[(2 + v) * 12 + 4 + u]).sum::<f32>() / 4.0;
        assert_eq!(cells[6 + 2], mean);
        let right = f.macro_cells(9, c.offset(1, 0));
        for j in 0..MACRO_CELLS {
            for i in 2..MACRO_CELLS {
                assert_eq!(cells[j * MACRO_CELLS + i], right[j * MACRO_CELLS + i - 2], "cell ({i}, {j})");
            }
        }
    }

    /// The macro level of a tile is the mean of the 2×2 range-field cells over it, the same
    /// on every call.
    #[test]
    fn macro_level_is_the_mean_of_the_tiles_range_cells() {
        let c = TileCoord::new(-2, 5);
        let cells = shared().macro_cells(4, c);
        let mean = (cells[14] + cells[15] + cells[20] + cells[21]) / 4.0;
        assert_eq!(macro_level(4, c), mean);
        assert_eq!(macro_level(4, c), macro_level(4, c));
    }
}
