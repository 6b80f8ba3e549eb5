//! The world of a sketch: the terrain made from the sketch canvas ([`crate::sketch`]) laid on
//! the ground at the extent the user gave it ([`EXTENT_M`]: 0.5–8 km across), heights = the
//! terrain's 0–255 scale × relief / 255 metres. At the default 8 km
//! ([`SKETCH_EXTENT_M`]) its 256² samples are the world's 32 m samples on the 2 × 2 tiles
//! around the origin ([`SKETCH_TILES`]); a sketch 4 km across or less lies in the middle of
//! tile (0, 0) alone, its samples finer than the world's, and the tiles it covers keep them
//! as their own detail at the TEM level nearest its spacing ([`SketchSource::detail_level`]:
//! 2 m at 0.5 km), the 32 m tile being their area mean. Around it the ground falls smoothly
//! from the sketch's edge to 0 m ([`SketchSource::fade_m`]: [`FADE_M`] at 8 km); beyond that
//! it is flat. A sketch in one tile stands at the world's own level instead: its outer
//! samples' mean is lifted to the macro field of tile (0, 0) ([`super::ranges::macro_level`],
//! the level the learned world around it grows at) and its foot falls to that level by the
//! tile's edge, so the world beside it does not climb out of a pit. The falling ground follows the sketch's edge smoothed more the farther out it is (a
//! box mean of the sketch around the nearest edge sample, as wide as the distance), so the
//! edge's valleys and ridges do not run out as straight stripes across the plain.
//!
//! Where the learned world's models are at hand the sketch's tiles are pinned into it instead
//! ([`SketchSource::pins`]) and the learned world grows around them; this fading plain is the
//! world while they load, and the fallback when they fail. A sketch under 4 km across is set
//! into the learned world's own tile (0, 0) instead once that tile is at hand
//! ([`SketchSource::with_base`]): the tile is the world's own but for the sketch's square and
//! a fade around it, whose detail gives way to the TEM's ([`super::pins::SoftEdge`]), and it
//! changes no other tile of the world.

use std::sync::Arc;

use super::pins::{PinnedTile, Pins, SoftEdge, detail_centre_m, detail_side};
use super::{BASE_SPACING_M, Neighbourhood, TILE_SAMPLES, Tile, TileCoord, TileSource};
use crate::models::tem::{LEVEL_SPACING_M, LEVELS};
use crate::sketch::SKETCH_PX;

/// Ground extent of the sketch's tile at the default scale (metres): its [`SKETCH_PX`]
/// samples at the world's 32 m, 8,192 m (the generator is told the extent:
/// [`crate::models::sketch::extent_value`]).
pub const SKETCH_EXTENT_M: f64 = SKETCH_PX as f64 * BASE_SPACING_M;

/// Extents a sketch may be given (metres across): from the sketch format's own scale (~0.5 km,
/// [`crate::models::sketch::FORMAT_EXTENT_M`]) to [`SKETCH_EXTENT_M`].
pub const EXTENT_M: std::ops::RangeInclusive<f64> = 512.0..=SKETCH_EXTENT_M;
/// Distance over which the ground around an 8 km sketch falls to 0 m (metres); a smaller
/// sketch's ground falls over half its extent.
pub const FADE_M: f64 = 4096.0;
/// Default relief of a sketch 8 km across (metres between its lowest and highest point).
pub const DEFAULT_RELIEF_M: f64 = 1500.0;
/// Reliefs a sketch may be given (metres).
pub const RELIEF_M: std::ops::RangeInclusive<f64> = 10.0..=8000.0;
/// First world sample (x and z) covered by an 8 km sketch: it is centred on the origin.
pub const FIRST_SAMPLE: i64 = -(SKETCH_PX as i64) / 2;
/// The tiles an 8 km sketch covers, row-major.
pub const SKETCH_TILES: [TileCoord; 4] = [TileCoord { i: -1, j: -1 }, TileCoord { i: 0, j: -1 }, TileCoord { i: -1, j: 0 }, TileCoord { i: 0, j: 0 }];

/// The relief (metres) a sketch `extent_m` across gets unless the user sets one: relief grows
/// as the square root of the extent, [`DEFAULT_RELIEF_M`] at 8 km and 375 m at 0.5 km (the
/// North Tyrol DEMs' 500 m windows span 170–480 m), rounded to 5 m.
pub fn default_relief_m(extent_m: f64) -> f64 {
    (DEFAULT_RELIEF_M * (clamp_extent_m(extent_m) / SKETCH_EXTENT_M).sqrt() / 5.0).round() * 5.0
}

/// `extent_m` (metres across) within [`EXTENT_M`]; a number that is not finite is
/// [`SKETCH_EXTENT_M`].
pub fn clamp_extent_m(extent_m: f64) -> f64 {
    if extent_m.is_finite() { extent_m.clamp(*EXTENT_M.start(), *EXTENT_M.end()) } else { SKETCH_EXTENT_M }
}

/// Whether a sketch `extent_m` across ([`clamp_extent_m`]) lies in tile (0, 0) alone (a tile
/// across or less), else on the 2 × 2 tiles at the origin ([`SKETCH_TILES`]).
pub fn in_one_tile(extent_m: f64) -> bool {
    clamp_extent_m(extent_m) <= super::TILE_SIZE_M
}

/// Whether a sketch `extent_m` across ([`clamp_extent_m`]) is set into the learned world's own
/// tile (0, 0) when that tile is at hand ([`SketchSource::with_base`]): one in that tile with
/// room around it (under 4 km across).
pub fn sets_into_tile(extent_m: f64) -> bool {
    clamp_extent_m(extent_m) < super::TILE_SIZE_M
}

/// World x = z (metres) of the centre of a sketch `extent_m` across: the origin's corner of
/// the 2 × 2 tiles around it (−16 m: samples are cell centres) for one wider than a tile, else
/// the middle of tile (0, 0) (2,032 m).
pub fn centre_m(extent_m: f64) -> f64 {
    let half = BASE_SPACING_M / 2.0;
    if in_one_tile(extent_m) { super::TILE_SIZE_M / 2.0 - half } else { -half }
}

/// The level (metres) a sketch `extent_m` across stands at in world `seed`: 0 m for one wider
/// than a tile; for one in tile (0, 0), the world's macro field there
/// ([`super::ranges::macro_level`], the level the learned world around it grows at).
pub fn base_level_m(extent_m: f64, seed: u64) -> f32 {
    if in_one_tile(extent_m) { super::ranges::macro_level(seed, TileCoord::new(0, 0)) } else { 0.0 }
}

/// Tile source of a sketch's terrain.
pub struct SketchSource {
    heights: Arc<Vec<f32>>,
    relief_m: f32,
    /// Metres across (clamped to [`EXTENT_M`]).
    extent_m: f64,
    /// World x = z (metres) of the sketch's north-west corner.
    corner_m: f64,
    /// [`fade_m`](Self::fade_m).
    fade_m: f64,
    /// [`base_m`](Self::base_m).
    base_m: f32,
    /// [`lift_m`](Self::lift_m).
    lift_m: f32,
    /// Summed-area table of the heights ((SKETCH_PX + 1)², row-major): box means in O(1).
    sums: Vec<f64>,
    /// The learned world's own tile (0, 0) the sketch is set into ([`with_base`](Self::with_base)),
    /// and where its samples hold.
    base: Option<(Arc<Vec<f32>>, SoftEdge)>,
}

impl SketchSource {
    /// The world of `heights` ([`SKETCH_PX`]² on the 0–255 scale) with `relief_m` metres from
    /// 0 to 255 (clamped to [`RELIEF_M`]), [`SKETCH_EXTENT_M`] across.
    pub fn new(heights: Arc<Vec<f32>>, relief_m: f64) -> Self {
        Self::with_extent(heights, relief_m, SKETCH_EXTENT_M, 0)
    }

    /// The world of `heights` ([`SKETCH_PX`]² on the 0–255 scale) with `relief_m` metres from
    /// 0 to 255 (clamped to [`RELIEF_M`]), `extent_m` metres across (clamped to [`EXTENT_M`]),
    /// in world `seed` (a sketch in one tile stands at its level: [`base_m`](Self::base_m)).
    pub fn with_extent(heights: Arc<Vec<f32>>, relief_m: f64, extent_m: f64, seed: u64) -> Self {
        assert_eq!(heights.len(), SKETCH_PX * SKETCH_PX, "a sketch's terrain is {SKETCH_PX}² samples");
        let extent_m = clamp_extent_m(extent_m);
        let n = SKETCH_PX;
        let mut sums = vec![0f64; (n + 1) * (n + 1)];
        for y in 0..n {
            for x in 0..n {
                sums[(y + 1) * (n + 1) + x + 1] = heights[y * n + x] as f64 + sums[y * (n + 1) + x + 1] + sums[(y + 1) * (n + 1) + x] - sums[y * (n + 1) + x];
            }
        }
        let centre = centre_m(extent_m);
        let half = FADE_M * extent_m / SKETCH_EXTENT_M;
        let one_tile = in_one_tile(extent_m);
        let fade_m = if one_tile { half.max((super::TILE_SIZE_M - extent_m) / 2.0) } else { half };
        let relief_m = relief_m.clamp(*RELIEF_M.start(), *RELIEF_M.end()) as f32;
        let (base_m, lift_m) = if one_tile {
            let ring_m = outer_mean(|k| heights[k] as f64) / 255.0 * relief_m as f64;
            let base = base_level_m(extent_m, seed);
            (base, (base as f64 - ring_m) as f32)
        } else {
            (0.0, 0.0)
        };
        Self { heights, relief_m, extent_m, corner_m: centre - extent_m / 2.0, fade_m, base_m, lift_m, sums, base: None }
    }

    /// Whether the sketch is set into the learned world's own tile when it has one
    /// ([`with_base`](Self::with_base)): a sketch in tile (0, 0) with room around it (under
    /// 4 km across).
    pub fn takes_base(&self) -> bool {
        sets_into_tile(self.extent_m)
    }

    /// The sketch set into `base`, the learned world's tile (0, 0) as it is without the
    /// sketch ([`TILE_SAMPLES`]² metres), instead of on a smooth foot: its samples hold
    /// inside its square, and around it the ground goes over to `base` within half its
    /// extent (less where the tile's edge is nearer: [`SoftEdge`]), where the pinned tile's
    /// detail gives way to the TEM's. The sketch stands at `base`'s mean level around it
    /// (its outer samples' mean is lifted to that of `base` there). A sketch that does not
    /// [`take a base`](Self::takes_base), or a `base` of another size, changes nothing.
    pub fn with_base(mut self, base: Arc<Vec<f32>>) -> Self {
        if !self.takes_base() || base.len() != TILE_SAMPLES * TILE_SAMPLES || base.iter().any(|v| !v.is_finite()) {
            return self;
        }
        let base = Arc::new(unblurred(&base));
        let n = SKETCH_PX;
        let spacing = self.extent_m / n as f64;
        let at = |k: usize| self.corner_m + spacing * (k as f64 + 0.5);
        let sketch_ring = outer_mean(|k| self.heights[k] as f64) / 255.0 * self.relief_m as f64;
        let base_ring = outer_mean(|k| bilinear_tile(&base, at(k % n), at(k / n)) as f64);
        self.base_m = base_ring as f32;
        self.lift_m = (base_ring - sketch_ring) as f32;
        let edge = (self.corner_m, self.corner_m + self.extent_m);
        // The tile's cells reach from −16 m to 4,080 m.
        let (west, east) = (-BASE_SPACING_M / 2.0, super::TILE_SIZE_M - BASE_SPACING_M / 2.0);
        let room = (edge.0 - west).min(east - edge.1);
        let soft = SoftEdge { min_m: [edge.0; 2], max_m: [edge.1; 2], fade_m: (self.extent_m / 2.0).min(room).max(BASE_SPACING_M) };
        self.base = Some((base, soft));
        self
    }

    /// Where the sketch's samples hold in its pinned tile, when it is set into a base
    /// ([`with_base`](Self::with_base)).
    pub fn soft_edge(&self) -> Option<SoftEdge> {
        self.base.as_ref().map(|b| b.1)
    }

    /// Metres across.
    pub fn extent_m(&self) -> f64 {
        self.extent_m
    }

    /// Distance (metres) over which the ground around the sketch falls to 0 m: half its
    /// extent ([`FADE_M`] at 8 km), but for a sketch in one tile at least out to the tile's
    /// edge, so its tile is a broad foot around it rather than a level plain.
    pub fn fade_m(&self) -> f64 {
        self.fade_m
    }

    /// The level (metres) the ground around the sketch falls to: 0 m for a sketch wider than a
    /// tile; for one in tile (0, 0), the world's macro field there, or, set into the world's
    /// own tile ([`with_base`](Self::with_base)), that tile's mean height around the sketch.
    pub fn base_m(&self) -> f32 {
        self.base_m
    }

    /// Metres added to the sketch's terrain (its 0–255 scale × relief / 255): 0 for a sketch
    /// wider than a tile; for one in tile (0, 0), what lifts the mean of its outer samples to
    /// [`base_m`](Self::base_m).
    pub fn lift_m(&self) -> f32 {
        self.lift_m
    }

    /// World x = z (metres) of the sketch's centre.
    pub fn centre_m(&self) -> f64 {
        self.corner_m + self.extent_m / 2.0
    }

    /// The tiles the sketch lies on (they are its pins), row-major.
    pub fn tiles(&self) -> Vec<TileCoord> {
        if in_one_tile(self.extent_m) { vec![TileCoord::new(0, 0)] } else { SKETCH_TILES.to_vec() }
    }

    /// The TEM level (0 = 16 m … 4 = 1 m) whose samples the sketch's tiles keep as their own
    /// detail: the finest no finer than 2/3 of the sketch's spacing (its extent / 256), so the
    /// sketch is never stretched more than 1.5× to it; `None` when that is coarser than 16 m
    /// (a sketch over 6 km across: the 32 m tiles only).
    pub fn detail_level(&self) -> Option<usize> {
        let spacing = self.extent_m / SKETCH_PX as f64;
        (0..LEVELS).rev().find(|&l| LEVEL_SPACING_M[l] >= spacing / 1.5)
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

    /// The tiles the sketch lies on ([`tiles`](Self::tiles)) as pins of the learned world
    /// ([`super::learned::LearnedSource::with_pins`]): its terrain in metres, with its own
    /// detail where it is finer than the world's 32 m, so the learned world grows around the
    /// sketch.
    pub fn pins(&self) -> Pins {
        let mut pins = Pins::new();
        for c in self.tiles() {
            pins.insert_tile(c, self.pinned_tile(c)).expect("a sketch's terrain is finite (checked when it arrives) and its detail fits");
        }
        pins
    }

    /// Tile `c` as a pin: its samples at [`detail_level`](Self::detail_level) (pixel centres,
    /// [`crate::world::refine`]'s geometry) and their area means above, or its 32 m samples.
    fn pinned_tile(&self, c: TileCoord) -> PinnedTile {
        match self.detail_level() {
            Some(level) => {
                let side = detail_side(level);
                let (p0, q0) = (c.i as i64 * side as i64, c.j as i64 * side as i64);
                let centre = |p: i64| detail_centre_m(level, p);
                let heights = (0..side * side).map(|k| self.height_m(centre(p0 + (k % side) as i64), centre(q0 + (k / side) as i64))).collect();
                let tile = PinnedTile::with_detail(level, heights).expect("a sketch's terrain is finite");
                match self.soft_edge() {
                    Some(soft) => tile.with_soft_edge(soft),
                    None => tile,
                }
            }
            None => PinnedTile::new(self.point_tile(c)).expect("a sketch's terrain is finite"),
        }
    }

    /// Tile `c`'s 32 m samples taken at their centres.
    fn point_tile(&self, c: TileCoord) -> Vec<f32> {
        let (x0, z0) = (c.i as i64 * TILE_SAMPLES as i64, c.j as i64 * TILE_SAMPLES as i64);
        (0..TILE_SAMPLES * TILE_SAMPLES).map(|p| self.height(x0 + (p % TILE_SAMPLES) as i64, z0 + (p / TILE_SAMPLES) as i64)).collect()
    }

    /// Tile `coord` of this world: on the sketch's own tiles with detail, the area mean of it
    /// (the pinned tile's 32 m heights), elsewhere the heights at the samples' centres.
    pub fn tile(&self, coord: TileCoord) -> Tile {
        if self.detail_level().is_some() && self.tiles().contains(&coord) {
            return Tile::new(coord, self.pinned_tile(coord).fine.to_vec());
        }
        Tile::new(coord, self.point_tile(coord))
    }

    /// Height (metres) at the centre of world sample (`gx`, `gz`) (32 m apart).
    pub fn height(&self, gx: i64, gz: i64) -> f32 {
        self.height_m(gx as f64 * BASE_SPACING_M, gz as f64 * BASE_SPACING_M)
    }

    /// Height (metres) at world point (`x`, `z`) metres: bilinear between the sketch's
    /// samples (their centres) on the sketch; beyond its outer samples, the box mean of the
    /// sketch around the nearest of them, the box as wide as the distance in samples, faded
    /// to [`base_m`](Self::base_m) over [`fade_m`](Self::fade_m); plus [`lift_m`](Self::lift_m).
    pub fn height_m(&self, x: f64, z: f64) -> f32 {
        let n = SKETCH_PX as i64;
        let spacing = self.extent_m / SKETCH_PX as f64;
        let (fu, fv) = ((x - self.corner_m) / spacing - 0.5, (z - self.corner_m) / spacing - 0.5);
        let last = (n - 1) as f64;
        let (cu, cv) = (fu.clamp(0.0, last), fv.clamp(0.0, last));
        if (cu, cv) == (fu, fv) {
            let (u0, v0) = ((fu.floor() as i64).min(n - 2), (fv.floor() as i64).min(n - 2));
            let (tu, tv) = ((fu - u0 as f64) as f32, (fv - v0 as f64) as f32);
            let at = |u: i64, v: i64| self.heights[(v * n + u) as usize];
            let top = at(u0, v0) * (1.0 - tu) + at(u0 + 1, v0) * tu;
            let bottom = at(u0, v0 + 1) * (1.0 - tu) + at(u0 + 1, v0 + 1) * tu;
            return (top * (1.0 - tv) + bottom * tv) / 255.0 * self.relief_m + self.lift_m;
        }
        // The first sample out holds the edge sample's height (r = 0); farther out, the box
        // widens with the distance.
        let (du, dv) = (fu - cu, fv - cv);
        let r = (libm::hypot(du, dv).round() as i64 - 1).max(0);
        let h = self.box_mean(cu.round() as i64, cv.round() as i64, r) / 255.0 * self.relief_m as f64 + self.lift_m as f64;
        if let Some((base, soft)) = &self.base {
            // The base's own ground, raised or lowered by what the sketch's edge stands above
            // it, that difference fading out: the base keeps its valleys and ridges all
            // round, and the sketch's edge runs out into them.
            let edge = |c: f64| self.corner_m + spacing * (c + 0.5);
            let above = h as f32 - bilinear_tile(base, edge(cu), edge(cv));
            return bilinear_tile(base, x, z) + soft.weight(x, z) * above;
        }
        let d = libm::hypot(du, dv) * spacing;
        let t = (1.0 - d / self.fade_m()).max(0.0);
        let base = self.base_m as f64;
        (base + (h - base) * t * t) as f32
    }
}

/// The mean of `value` over the sketch's outer samples (by index into its [`SKETCH_PX`]²
/// samples, row-major).
fn outer_mean(value: impl Fn(usize) -> f64) -> f64 {
    let n = SKETCH_PX;
    let ring: Vec<usize> = (0..n * n).filter(|k| [0, n - 1].contains(&(k % n)) || [0, n - 1].contains(&(k / n))).collect();
    ring.iter().map(|&k| value(k)).sum::<f64>() / ring.len() as f64
}

/// Samples (a [`TILE_SAMPLES`]² tile) whose [`bilinear_tile`] heights at any finer TEM level,
/// area-averaged back to 32 m, are `tile` again (to float rounding): bilinear samples
/// averaged over a 32 m cell weigh the cell by ¾ and its neighbours along an axis by ⅛ each
/// (the cell itself by ⅞ at the tile's edge, where they are clamped), per axis, which blurs a
/// rugged tile by metres. That blur is undone exactly, a tridiagonal solve per row, then per
/// column.
fn unblurred(tile: &[f32]) -> Vec<f32> {
    let n = TILE_SAMPLES;
    // Solves the blur along one line of `n` values (Thomas algorithm; diagonally dominant).
    let solve = |rhs: &mut [f64]| {
        let diag = |i: usize| if i == 0 || i == n - 1 { 0.875 } else { 0.75 };
        let (off, mut c) = (0.125, vec![0f64; n]);
        c[0] = off / diag(0);
        rhs[0] /= diag(0);
        for i in 1..n {
            let m = diag(i) - off * c[i - 1];
            c[i] = off / m;
            rhs[i] = (rhs[i] - off * rhs[i - 1]) / m;
        }
        for i in (0..n - 1).rev() {
            rhs[i] -= c[i] * rhs[i + 1];
        }
    };
    let mut u: Vec<f64> = tile.iter().map(|&v| v as f64).collect();
    for row in u.chunks_mut(n) {
        solve(row);
    }
    let mut column = vec![0f64; n];
    for x in 0..n {
        (0..n).for_each(|y| column[y] = u[y * n + x]);
        solve(&mut column);
        (0..n).for_each(|y| u[y * n + x] = column[y]);
    }
    u.into_iter().map(|v| v as f32).collect()
}

/// Tile (0, 0)'s 32 m samples `tile` ([`TILE_SAMPLES`]², sample (p, q) at world (32p, 32q)
/// metres) bilinear at world point (`x`, `z`), clamped to the tile's outer samples.
fn bilinear_tile(tile: &[f32], x: f64, z: f64) -> f32 {
    let last = (TILE_SAMPLES - 1) as f64;
    let (u, v) = ((x / BASE_SPACING_M).clamp(0.0, last), (z / BASE_SPACING_M).clamp(0.0, last));
    let (u0, v0) = ((u.floor() as usize).min(TILE_SAMPLES - 2), (v.floor() as usize).min(TILE_SAMPLES - 2));
    let (tu, tv) = ((u - u0 as f64) as f32, (v - v0 as f64) as f32);
    let at = |p: usize, q: usize| tile[q * TILE_SAMPLES + p];
    let top = at(u0, v0) * (1.0 - tu) + at(u0 + 1, v0) * tu;
    let bottom = at(u0, v0 + 1) * (1.0 - tu) + at(u0 + 1, v0 + 1) * tu;
    top * (1.0 - tv) + bottom * tv
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

    /// The relief that fits an extent grows as its square root: 1,500 m at 8 km, 375 m at
    /// 0.5 km; extents outside 0.5–8 km are clamped.
    #[test]
    fn the_default_relief_is_1500_m_at_8_km_and_375_m_at_half_a_km() {
        assert_eq!(default_relief_m(SKETCH_EXTENT_M), 1500.0);
        assert_eq!(default_relief_m(512.0), 375.0);
        assert_eq!(default_relief_m(2048.0), 750.0);
        assert_eq!(default_relief_m(100.0), 375.0);
    }

    /// A half-km sketch set into the learned world's own tile (here a tilted, rippled base):
    /// its 2 m detail in its square is the ramp lifted by one constant (to 1 mm), so that its
    /// outer samples' mean is the base's level there (within 1 m of the base's 32 m samples
    /// around the square); the pinned 32 m tile is the base (to 1 cm) over 256 m from the
    /// square (the fade: half its extent), and the tile's detail gives way to the TEM's around
    /// the square; sketches 4 km across or wider take no base.
    #[test]
    fn a_half_km_sketch_set_into_a_base_keeps_its_square_and_is_the_base_beyond_its_fade() {
        let h: Vec<f32> = (0..SKETCH_PX * SKETCH_PX).map(|p| (p % SKETCH_PX) as f32 / (SKETCH_PX - 1) as f32 * 255.0).collect();
        let n = TILE_SAMPLES;
        let base: Vec<f32> = (0..n * n).map(|k| 600.0 + 3.2 * (k % n) as f32 + 30.0 * ((k % n) as f32 * 0.7).sin() * ((k / n) as f32 * 0.4).cos()).collect();
        for e in [4096.0, 8192.0] {
            let s = SketchSource::with_extent(Arc::new(h.clone()), 400.0, e, 7);
            assert!(!s.takes_base() && s.with_base(Arc::new(base.clone())).soft_edge().is_none(), "{e} m");
        }
        let s = SketchSource::with_extent(Arc::new(h), 400.0, 512.0, 7).with_base(Arc::new(base.clone()));
        let soft = s.soft_edge().expect("a half-km sketch is set into its base");
        assert_eq!((soft.min_m, soft.max_m, soft.fade_m), ([1776.0; 2], [2288.0; 2], 256.0));
        let pins = s.pins();
        let tile = pins.get(TileCoord::new(0, 0)).unwrap();
        assert_eq!(tile.soft, Some(soft));
        let (d2, side) = (tile.detail(3).unwrap(), detail_side(3));
        let lift = s.lift_m();
        let ramp = |p: usize| ((p as f64 - 896.0) / 255.0 * 400.0) as f32 + lift;
        let mut ring = Vec::new();
        for q in 896..1152 {
            for p in 896..1152 {
                assert!((d2[q * side + p] - ramp(p)).abs() < 1e-3, "({p}, {q})");
                if [896, 1151].contains(&p) || [896, 1151].contains(&q) {
                    ring.push(d2[q * side + p] as f64);
                }
            }
        }
        let ring = ring.iter().sum::<f64>() / ring.len() as f64;
        assert!((ring - s.base_m() as f64).abs() < 1e-3, "outer samples {ring} m, base level {} m", s.base_m());
        // 32 m samples 55–71 hold the square's edges (1,776 and 2,288 m lie in 56 and 72).
        let around: Vec<f64> = (55..=72)
            .flat_map(|q| (55..=72).map(move |p| (p, q)))
            .filter(|&(p, q)| [55, 56, 71, 72].contains(&p) || [55, 56, 71, 72].contains(&q))
            .map(|(p, q)| base[q * n + p] as f64)
            .collect();
        let around = around.iter().sum::<f64>() / around.len() as f64;
        assert!((s.base_m() as f64 - around).abs() < 1.0, "base level {} m, the base around the square {around} m", s.base_m());
        // Over 256 m from the square: 32 m samples below 47 or above 80.
        let mut far = 0f32;
        for q in 0..n {
            for p in 0..n {
                if !(47..=80).contains(&p) || !(47..=80).contains(&q) {
                    far = far.max((tile.fine[q * n + p] - base[q * n + p]).abs());
                }
            }
        }
        assert!(far < 0.01, "beyond the fade the tile is {far} m from its base");
    }

    /// Where a sketch lies and what it pins, by extent: 8 km on the four tiles at the origin
    /// with no detail; 6 km the same with 16 m detail; 4 km in tile (0, 0) alone at 16 m; 0.5 km
    /// in the middle of tile (0, 0) with 2 m detail (the sketch's own 2 m samples, bilinear at
    /// worst), lifted so its outer samples' mean is the world's macro level there, its foot
    /// falling to that level by the tile's edge; the 32 m tile their area mean.
    #[test]
    fn a_half_km_sketch_lies_in_tile_0_0_with_its_own_2_m_detail() {
        // A ramp along x: bilinear interpolation gives it back exactly between samples.
        let h: Vec<f32> = (0..SKETCH_PX * SKETCH_PX).map(|p| (p % SKETCH_PX) as f32 / (SKETCH_PX - 1) as f32 * 255.0).collect();
        let at = |e: f64| SketchSource::with_extent(Arc::new(h.clone()), 400.0, e, 7);
        for (e, tiles, level) in [(8192.0, 4, None), (6000.0, 4, Some(0)), (4096.0, 1, Some(0)), (1000.0, 1, Some(2)), (512.0, 1, Some(3))] {
            let s = at(e);
            assert_eq!((s.tiles().len(), s.detail_level()), (tiles, level), "{e} m");
            let pins = s.pins();
            let mut tiles = s.tiles();
            tiles.sort();
            assert_eq!(pins.coords(), tiles);
            assert_eq!(pins.iter().next().unwrap().1.detail.len(), level.map_or(0, |l| l + 1), "{e} m");
        }
        assert_eq!((at(8192.0).base_m(), at(8192.0).lift_m()), (0.0, 0.0), "an 8 km sketch stands at 0 m");
        let s = at(512.0);
        assert_eq!(s.centre_m(), 2032.0);
        // The ramp's outer samples average 127.5 of 255: 200 m.
        let (base, lift) = (s.base_m(), s.lift_m());
        assert_eq!(base, crate::world::ranges::macro_level(7, TileCoord::new(0, 0)));
        assert!((lift - (base - 200.0)).abs() < 1e-3, "lift {lift} m, base {base} m");
        let pins = s.pins();
        let tile = pins.get(TileCoord::new(0, 0)).unwrap();
        let d2 = tile.detail(3).unwrap();
        let side = detail_side(3);
        assert_eq!(side, 2048);
        // 2 m pixel p of tile (0, 0) has its centre at 2p + 1 − 16 m; the sketch starts at
        // 2032 − 256 = 1776 m, so pixel 896 is the sketch's first sample, 1151 its last.
        let ramp = |x: f64| (((x - 1776.0) / 2.0 - 0.5) / 255.0 * 400.0) as f32 + lift;
        for (p, q) in [(896, 896), (1000, 1100), (1151, 1151), (1023, 900)] {
            let x = 2.0 * p as f64 + 1.0 - 16.0;
            assert!((d2[q * side + p] - ramp(x)).abs() < 1e-3, "({p}, {q}): {} vs {}", d2[q * side + p], ramp(x));
        }
        assert_eq!(d2[896 * side + 896], lift, "the sketch's lowest sample");
        assert!((d2[1000 * side + 1151] - (400.0 + lift)).abs() < 1e-3, "the sketch's highest sample");
        // Its foot falls to the base by the tile's edge (1,792 m from the sketch's).
        assert_eq!(s.fade_m(), 1792.0);
        assert_eq!(d2[1000 * side + side - 1], base);
        let foot = d2[1000 * side + 1200];
        assert!(foot > base.min(400.0 + lift) && foot < base.max(400.0 + lift), "{foot} m between {base} and {}", 400.0 + lift);
        // The 32 m tile is the area mean of the 2 m samples (to 1 cm: f32 sums of 256 heights
        // near 1 km, in another order).
        let mean: f32 = (0..16 * 16).map(|k| d2[(640 + k / 16) * side + 960 + k % 16]).sum::<f32>() / 256.0;
        assert!((tile.fine[40 * 128 + 60] - mean).abs() < 1e-2, "{} vs {mean}", tile.fine[40 * 128 + 60]);
        assert_eq!(s.tile(TileCoord::new(0, 0)).heights, tile.fine.to_vec());
    }
}
