//! Terrain a user pinned into the world: whole tiles of their own heights at the world's 32 m
//! spacing. The learned world keeps them exactly and grows around them
//! ([`super::learned::LearnedSource::with_pins`]): each pinned tile's 128 m tile is its area
//! mean, the tiles beside it take it as a given neighbour and are joined to its edges, and the
//! drainage treats it as an outlet it never changes. A world with pins is a pure function of
//! (seed, weights, pins).
//!
//! Detail. Terrain at 16 m or finer keeps its own samples for the TEM levels it covers (a 5 m
//! DEM at 16 and 8 m, a 1 m DEM at every level): the refined patches over a pinned tile take
//! them instead of the TEM's output ([`super::refine::PatchStore::with_pins`]), and the levels
//! below the finest kept are refined from them. The levels form one ladder: each is the 2 × 2
//! box mean of the level below, down to the 32 m tile, as the TEM's training pairs are.

use std::collections::BTreeMap;
use std::sync::Arc;

use crate::dem::Heightfield;
use crate::grid::{BASE_SPACING_M, TILE_SAMPLES, TileCoord};
use crate::models::tcm::TILE_PX;
use crate::models::tem::{LEVEL_SPACING_M, LEVELS};

/// Pinned tiles at most (each 64 KiB at 32 m and 4 KiB at 128 m): a 32 × 32 km import.
pub const MAX_PINNED_TILES: usize = 64;

/// Most detail samples the pins of a world keep, all levels together (2²⁵: 128 MiB of
/// float32): a 4096² DEM at 8 m (64 tiles at 16 and 8 m, 21 M samples) or at 1 m (one tile at
/// every level, 22 M) fits. An import whose finer levels would pass it keeps the coarser ones
/// only ([`Pins::add`] says which).
pub const MAX_DETAIL_SAMPLES: usize = 1 << 25;

/// Side (samples) of a pinned tile's detail at TEM level `level` (spacing
/// [`LEVEL_SPACING_M`]`[level]`): 256 at 16 m … 4,096 at 1 m.
pub const fn detail_side(level: usize) -> usize {
    TILE_SAMPLES << (level + 1)
}

/// World x (or z) in metres of the centre of pixel `p` of TEM level `level`, pixels counted
/// from tile (0, 0)'s north-west corner ([`crate::world::refine`]'s geometry: the first 32 m
/// sample's centre is at 0 m, its cell's corner at −16 m).
pub fn detail_centre_m(level: usize, p: i64) -> f64 {
    LEVEL_SPACING_M[level] * (p as f64 + 0.5) - BASE_SPACING_M / 2.0
}

/// A tile set into the world as it is, and its 32 m heights ([`Pins::split_soft`]).
pub type SetIn = (TileCoord, Arc<Vec<f32>>);

/// One pinned tile.
#[derive(Clone, Debug, PartialEq)]
pub struct PinnedTile {
    /// Its 32 m heights ([`TILE_SAMPLES`]², metres, row-major).
    pub fine: Arc<Vec<f32>>,
    /// Its 128 m area means ([`TILE_PX`]², metres): the tile as the TCM sees it.
    pub coarse: Arc<Vec<f32>>,
    /// Its own heights at TEM levels 0, 1, … (16 m, 8 m, …; [`detail_side`]² metres each,
    /// row-major, the tile's north-west corner first) as far as the terrain is that fine; empty
    /// for terrain coarser than 16 m.
    pub detail: Vec<Arc<Vec<f32>>>,
    /// Where its detail blends into the TEM's refinement of its 32 m heights instead of
    /// replacing it ([`SoftEdge`]); `None`: the detail replaces it everywhere.
    pub soft: Option<SoftEdge>,
}

/// A rectangle of a pinned tile where its own detail holds, fading out around it: a small
/// sketch set into the learned world's own tile keeps its samples inside the rectangle, and
/// the TEM's detail of that tile comes back over [`fade_m`](Self::fade_m) around it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SoftEdge {
    /// World x and z (metres) of the rectangle's west and north edges.
    pub min_m: [f64; 2],
    /// World x and z (metres) of its east and south edges.
    pub max_m: [f64; 2],
    /// Distance (metres) outside it over which the weight falls from 1 to 0 (> 0).
    pub fade_m: f64,
}

impl SoftEdge {
    /// The weight (0–1) of the pinned detail at world point (`x`, `z`) metres: 1 in the
    /// rectangle, a smoothstep of the distance to it down to 0 at [`fade_m`](Self::fade_m).
    pub fn weight(&self, x: f64, z: f64) -> f32 {
        let dx = (self.min_m[0] - x).max(x - self.max_m[0]).max(0.0);
        let dz = (self.min_m[1] - z).max(z - self.max_m[1]).max(0.0);
        let t = (1.0 - libm::hypot(dx, dz) / self.fade_m).clamp(0.0, 1.0);
        (t * t * (3.0 - 2.0 * t)) as f32
    }

    /// `a` where the weight `w` is 1, `b` where it is 0, between them linearly.
    pub fn mix(w: f32, a: f32, b: f32) -> f32 {
        if w >= 1.0 {
            a
        } else if w <= 0.0 {
            b
        } else {
            b + w * (a - b)
        }
    }
}

impl PinnedTile {
    /// A pinned tile from its 32 m heights (finite, [`TILE_SAMPLES`]²).
    pub fn new(fine: Vec<f32>) -> Result<Self, String> {
        let n = TILE_SAMPLES;
        if fine.len() != n * n {
            return Err(format!("a pinned tile has {} samples, not {}", n * n, fine.len()));
        }
        if let Some(p) = fine.iter().position(|v| !v.is_finite()) {
            return Err(format!("a pinned tile's height at sample {p} is {}", fine[p]));
        }
        // Two 2×2 box means, as the training cuts its 128 m fields from 32 m windows.
        let tile = Heightfield::new(n, n, BASE_SPACING_M, fine);
        let coarse = tile.downsample2().downsample2();
        assert_eq!(coarse.width, TILE_PX, "a 32 m tile is {TILE_PX} samples at 128 m");
        Ok(Self { fine: Arc::new(tile.data), coarse: Arc::new(coarse.data), detail: Vec::new(), soft: None })
    }

    /// A pinned tile from its heights at TEM level `finest` ([`detail_side`]`(finest)`²,
    /// finite): the coarser levels and the 32 m tile are 2 × 2 box means of the level below.
    pub fn with_detail(finest: usize, heights: Vec<f32>) -> Result<Self, String> {
        if finest >= LEVELS {
            return Err(format!("detail level {finest} is not one of the {LEVELS} TEM levels"));
        }
        let side = detail_side(finest);
        if heights.len() != side * side {
            return Err(format!("{} m detail has {} samples, not {}", LEVEL_SPACING_M[finest], heights.len(), side * side));
        }
        if let Some(p) = heights.iter().position(|v| !v.is_finite()) {
            return Err(format!("a pinned tile's {} m height at sample {p} is {}", LEVEL_SPACING_M[finest], heights[p]));
        }
        let mut levels = vec![Heightfield::new(side, side, LEVEL_SPACING_M[finest], heights)];
        while levels.len() <= finest {
            let next = levels.last().expect("one level at least").downsample2();
            levels.push(next);
        }
        let top = levels.last().expect("one level at least").downsample2();
        let mut tile = Self::new(top.data)?;
        tile.detail = levels.into_iter().rev().map(|l| Arc::new(l.data)).collect();
        Ok(tile)
    }

    /// The tile with its detail blending into the TEM's around `soft` ([`SoftEdge`]).
    pub fn with_soft_edge(mut self, soft: SoftEdge) -> Self {
        self.soft = Some(soft);
        self
    }

    /// Its heights at TEM level `level` ([`detail_side`]² metres), where it keeps them.
    pub fn detail(&self, level: usize) -> Option<&[f32]> {
        self.detail.get(level).map(|d| d.as_slice())
    }

    /// Detail samples it keeps, all levels together.
    pub fn detail_samples(&self) -> usize {
        self.detail.iter().map(|d| d.len()).sum()
    }
}

/// What [`Pins::add`] pinned.
#[derive(Clone, Debug, PartialEq)]
pub struct Added {
    /// The tiles pinned, in row order.
    pub tiles: Vec<TileCoord>,
    /// The finest detail kept (metres per sample; `None`: the 32 m tiles only).
    pub detail_m: Option<f64>,
    /// The finest TEM level's spacing the terrain reaches (metres; finer than `detail_m` when
    /// the memory bound left levels out).
    pub finest_m: Option<f64>,
}

impl Added {
    /// What became of the terrain's detail, for a message after "N tiles pinned": "" for
    /// terrain coarser than 16 m.
    pub fn detail_said(&self) -> String {
        match (self.detail_m, self.finest_m) {
            (Some(d), Some(f)) if d > f => format!("; its detail is kept to {d} m (finer, to {f} m, would pass the {} MiB the pins may keep)", (MAX_DETAIL_SAMPLES * 4) >> 20),
            (Some(d), _) if d > LEVEL_SPACING_M[LEVELS - 1] => format!("; its own detail is kept to {d} m, the learned detail goes on below"),
            (Some(d), _) => format!("; its own detail is kept to {d} m"),
            (None, Some(f)) => format!("; its detail (to {f} m) would pass the {} MiB the pins may keep, so the TEM refines it", (MAX_DETAIL_SAMPLES * 4) >> 20),
            (None, None) => String::new(),
        }
    }
}

/// The pinned tiles of a world, by tile.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Pins {
    tiles: BTreeMap<TileCoord, PinnedTile>,
}

impl Pins {
    /// No pins.
    pub fn new() -> Self {
        Self::default()
    }

    /// Pins `hf` with its north-west sample on the north-west sample of tile `at`, cut into
    /// the whole tiles it covers (its last partial row and column of tiles are left out),
    /// no-data filled from the nearest data. Terrain at 16 m or finer keeps its detail: it is
    /// area-averaged to the finest TEM level its spacing reaches (within
    /// [`MAX_DETAIL_SAMPLES`] for all pins together), and that level's 2 × 2 box means give
    /// the coarser levels and the 32 m tiles; coarser terrain is area-averaged to 32 m (a DEM
    /// coarser than 32 m is refused: pins are never upsampled). On an error nothing is pinned.
    pub fn add(&mut self, hf: &Heightfield, at: TileCoord) -> Result<Added, String> {
        if hf.spacing_m > BASE_SPACING_M * 1.0001 {
            return Err(format!("pinned terrain must be {BASE_SPACING_M} m or finer; this is {} m", hf.spacing_m));
        }
        let n = TILE_SAMPLES;
        // Whole tiles across and down: the 32 m grid's size, as area resampling rounds it, over 128.
        let tiles_of = |len: usize| (len as f64 / (BASE_SPACING_M / hf.spacing_m)).floor() as usize / n;
        let (w, h) = (tiles_of(hf.width), tiles_of(hf.height));
        if w == 0 || h == 0 {
            return Err(format!(
                "pinned terrain covers {:.1} × {:.1} km; a pin needs at least one whole tile ({:.1} km square)",
                hf.width as f64 * hf.spacing_m / 1000.0,
                hf.height as f64 * hf.spacing_m / 1000.0,
                n as f64 * BASE_SPACING_M / 1000.0
            ));
        }
        if self.tiles.len() + w * h > MAX_PINNED_TILES {
            return Err(format!("{} tiles pinned with this one, more than {MAX_PINNED_TILES}", self.tiles.len() + w * h));
        }
        // The finest TEM level the terrain reaches, then the finest the memory allows.
        let reach = (0..LEVELS).take_while(|&k| hf.spacing_m <= LEVEL_SPACING_M[k] * 1.0001).last();
        let room = MAX_DETAIL_SAMPLES.saturating_sub(self.detail_samples());
        let levels_samples = |k: usize| w * h * (0..=k).map(|l| detail_side(l).pow(2)).sum::<usize>();
        let kept = reach.and_then(|r| (0..=r).rev().find(|&k| levels_samples(k) <= room));
        let (spacing_m, cut) = match kept {
            Some(k) => (LEVEL_SPACING_M[k], detail_side(k)),
            None => (BASE_SPACING_M, n),
        };
        let grid = if (hf.spacing_m - spacing_m).abs() < 1e-9 { hf.window(0, 0, w * cut, h * cut) } else { hf.resample_area(spacing_m).map_err(|e| e.to_string())? };
        let grid = grid.fill_nodata().ok_or("the pinned terrain has no data")?;
        if grid.width < w * cut || grid.height < h * cut {
            return Err(format!("the terrain at {spacing_m} m is {} × {} samples, short of {} × {} whole tiles", grid.width, grid.height, w, h));
        }
        let mut new = Vec::new();
        for j in 0..h {
            for i in 0..w {
                let heights = grid.window(i * cut, j * cut, cut, cut).data;
                let tile = match kept {
                    Some(k) => PinnedTile::with_detail(k, heights)?,
                    None => PinnedTile::new(heights)?,
                };
                new.push((at.offset(i as i32, j as i32), tile));
            }
        }
        let tiles = new.iter().map(|(c, _)| *c).collect();
        self.tiles.extend(new);
        Ok(Added { tiles, detail_m: kept.map(|k| LEVEL_SPACING_M[k]), finest_m: reach.map(|k| LEVEL_SPACING_M[k]) })
    }

    /// Detail samples the pins keep, all tiles and levels together (at most
    /// [`MAX_DETAIL_SAMPLES`] through [`Self::add`]).
    pub fn detail_samples(&self) -> usize {
        self.tiles.values().map(PinnedTile::detail_samples).sum()
    }

    /// Pins a tile made elsewhere (a bundle's), replacing any pin there; at most
    /// [`MAX_PINNED_TILES`] tiles and [`MAX_DETAIL_SAMPLES`] detail samples.
    pub fn insert_tile(&mut self, c: TileCoord, tile: PinnedTile) -> Result<(), String> {
        if !self.tiles.contains_key(&c) && self.tiles.len() >= MAX_PINNED_TILES {
            return Err(format!("at most {MAX_PINNED_TILES} tiles can be pinned"));
        }
        let others = self.detail_samples() - self.tiles.get(&c).map_or(0, PinnedTile::detail_samples);
        if others + tile.detail_samples() > MAX_DETAIL_SAMPLES {
            return Err(format!("the pins' detail would pass {MAX_DETAIL_SAMPLES} samples"));
        }
        self.tiles.insert(c, tile);
        Ok(())
    }

    /// Pins one tile's 32 m heights ([`TILE_SAMPLES`]², finite), replacing any pin there.
    pub fn insert(&mut self, c: TileCoord, fine: Vec<f32>) -> Result<(), String> {
        self.insert_tile(c, PinnedTile::new(fine)?)
    }

    /// The pinned tile at `c`, if any.
    pub fn get(&self, c: TileCoord) -> Option<&PinnedTile> {
        self.tiles.get(&c)
    }

    /// Whether tile `c` is pinned.
    pub fn contains(&self, c: TileCoord) -> bool {
        self.tiles.contains_key(&c)
    }

    /// Whether nothing is pinned.
    pub fn is_empty(&self) -> bool {
        self.tiles.is_empty()
    }

    /// Whether tile `c` lies within `reach` tiles (Chebyshev distance) of a pinned tile, or
    /// is a tile set in with a soft edge (which changes no other tile:
    /// [`crate::world::learned::LearnedSource::with_pins`]).
    pub fn within(&self, c: TileCoord, reach: i32) -> bool {
        self.tiles.iter().any(|(p, t)| (p.i - c.i).abs().max((p.j - c.j).abs()) <= if t.soft.is_some() { 0 } else { reach })
    }

    /// The pinned tiles' coordinates, in tile order.
    pub fn coords(&self) -> Vec<TileCoord> {
        self.tiles.keys().copied().collect()
    }

    /// The pins without a soft edge, and the 32 m heights of those with one
    /// ([`PinnedTile::soft`]: tiles set into the world as they are).
    pub fn split_soft(&self) -> (Pins, Vec<SetIn>) {
        let hard = Pins { tiles: self.tiles.iter().filter(|(_, t)| t.soft.is_none()).map(|(c, t)| (*c, t.clone())).collect() };
        let soft = self.tiles.iter().filter(|(_, t)| t.soft.is_some()).map(|(c, t)| (*c, t.fine.clone())).collect();
        (hard, soft)
    }

    /// The pinned tiles in tile order, with their 32 m heights.
    pub fn iter(&self) -> impl Iterator<Item = (TileCoord, &PinnedTile)> {
        self.tiles.iter().map(|(c, t)| (*c, t))
    }

    /// A short hash of the pins (their tiles and heights; "" for none).
    pub fn hash(&self) -> String {
        if self.is_empty() {
            return String::new();
        }
        let mut h = crate::grid::Fnv::default();
        for (c, t) in &self.tiles {
            h = h.bytes(&c.i.to_le_bytes()).bytes(&c.j.to_le_bytes());
            for v in t.fine.iter() {
                h = h.bytes(&v.to_le_bytes());
            }
        }
        format!("{:08x}", h.0 >> 32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 10 m DEM of 1,000 × 900 samples (10 × 9 km) pins the 2 × 2 whole 32 m tiles it covers
    /// at the asked place; each tile is the DEM's area mean (a plane with 0.5 m steps: to 5 cm,
    /// the area resampling's own rounding; 1.6 cm measured) and its
    /// 128 m tile the mean of its 4 × 4 blocks. A 90 m DEM, a DEM smaller than a tile and one
    /// with no data are refused, and a refused pin adds nothing.
    #[test]
    fn a_dem_pins_the_whole_tiles_it_covers_as_area_means() {
        let plane = |x: usize, y: usize| 500.0 + x as f32 * 0.5 - y as f32 * 0.25;
        let hf = Heightfield::new(1000, 900, 10.0, (0..1000 * 900).map(|k| plane(k % 1000, k / 1000)).collect());
        let mut pins = Pins::new();
        let got = pins.add(&hf, TileCoord::new(-1, 3)).unwrap();
        assert_eq!(got.tiles, vec![TileCoord::new(-1, 3), TileCoord::new(0, 3), TileCoord::new(-1, 4), TileCoord::new(0, 4)]);
        // Sample (u, v) of tile (0, 4) covers DEM samples 3.2·(128 + u) … 3.2·(129 + u): its
        // mean is the plane at the centre.
        let t = pins.get(TileCoord::new(0, 4)).unwrap();
        let at = |u: usize, v: usize| plane(0, 0) + (3.2 * (128.0 + u as f32 + 0.5) - 0.5) * 0.5 - (3.2 * (128.0 + v as f32 + 0.5) - 0.5) * 0.25;
        for (u, v) in [(0, 0), (127, 0), (0, 127), (64, 77)] {
            assert!((t.fine[v * 128 + u] - at(u, v)).abs() < 0.05, "({u}, {v}): {} vs {}", t.fine[v * 128 + u], at(u, v));
        }
        let c = t.coarse[5 * 32 + 7];
        let mean: f32 = (0..16).map(|k| t.fine[(20 + k / 4) * 128 + 28 + k % 4]).sum::<f32>() / 16.0;
        assert!((c - mean).abs() < 1e-3);
        let before = pins.clone();
        assert!(pins.add(&Heightfield::new(100, 100, 90.0, vec![1.0; 100 * 100]), TileCoord::new(5, 5)).unwrap_err().contains("32 m or finer"));
        assert!(pins.add(&Heightfield::new(300, 300, 10.0, vec![1.0; 300 * 300]), TileCoord::new(5, 5)).unwrap_err().contains("at least one whole tile"));
        assert!(pins.add(&Heightfield::new(500, 500, 10.0, vec![f32::NAN; 500 * 500]), TileCoord::new(5, 5)).is_err());
        assert_eq!(pins, before);
        assert_eq!(pins.hash().len(), 8);
        assert_eq!(Pins::new().hash(), "");
    }

    /// A 5 m DEM keeps its own heights at the TEM levels it reaches (16 and 8 m): the 8 m
    /// level is the DEM's area mean (a plane: to 2 cm), the 16 m level and the 32 m tile the
    /// 2 × 2 box means of the level below, bit for bit; the message says so. A 10 m DEM keeps
    /// 16 m only, a 20 m DEM none. A second 1 m tile after a first (22.4 M detail samples)
    /// keeps only what fits in [`MAX_DETAIL_SAMPLES`] (to 2 m), and says what was left out.
    #[test]
    fn terrain_finer_than_16_m_keeps_its_own_detail_at_the_levels_it_reaches() {
        let plane = |x: f64, y: f64| (700.0 + x * 0.02 - y * 0.01) as f32;
        let dem = |spacing: f64, n: usize| Heightfield::new(n, n, spacing, (0..n * n).map(|k| plane((k % n) as f64 * spacing, (k / n) as f64 * spacing)).collect());
        let mut pins = Pins::new();
        let added = pins.add(&dem(5.0, 830), TileCoord::new(2, -1)).unwrap();
        assert_eq!((added.tiles.clone(), added.detail_m, added.finest_m), (vec![TileCoord::new(2, -1)], Some(8.0), Some(8.0)));
        assert!(added.detail_said().contains("kept to 8 m"), "{}", added.detail_said());
        let t = pins.get(TileCoord::new(2, -1)).unwrap();
        assert_eq!(t.detail.len(), 2);
        let d8 = t.detail(1).unwrap();
        assert_eq!(d8.len(), 512 * 512);
        // Sample (u, v) at 8 m covers [8u, 8u + 8) m: the plane at its centre.
        for (u, v) in [(0, 0), (511, 3), (100, 400)] {
            let want = plane(8.0 * u as f64 + 4.0 - 2.5, 8.0 * v as f64 + 4.0 - 2.5);
            assert!((d8[v * 512 + u] - want).abs() < 0.02, "({u}, {v}): {} vs {want}", d8[v * 512 + u]);
        }
        let halve = |d: &[f32], side: usize| Heightfield::new(side, side, 1.0, d.to_vec()).downsample2().data;
        assert!(halve(d8, 512).iter().zip(t.detail(0).unwrap()).all(|(a, b)| a.to_bits() == b.to_bits()));
        assert!(halve(t.detail(0).unwrap(), 256).iter().zip(t.fine.iter()).all(|(a, b)| a.to_bits() == b.to_bits()));
        assert_eq!(t.detail(2), None);
        assert_eq!(pins.detail_samples(), 512 * 512 + 256 * 256);
        let mut ten = Pins::new();
        assert_eq!(ten.add(&dem(10.0, 420), TileCoord::new(0, 0)).unwrap().detail_m, Some(16.0));
        let mut twenty = Pins::new();
        let a = twenty.add(&dem(20.0, 210), TileCoord::new(0, 0)).unwrap();
        assert_eq!((a.detail_m, a.finest_m, a.detail_said()), (None, None, String::new()));
        assert!(twenty.get(TileCoord::new(0, 0)).unwrap().detail.is_empty());
        // Two 1 m tiles: the first keeps every level, the second what is left of the bound.
        let mut lidar = Pins::new();
        let one_m = dem(1.0, 4096);
        assert_eq!(lidar.add(&one_m, TileCoord::new(0, 0)).unwrap().detail_m, Some(1.0));
        let second = lidar.add(&one_m, TileCoord::new(1, 0)).unwrap();
        assert_eq!((second.detail_m, second.finest_m), (Some(2.0), Some(1.0)));
        assert!(second.detail_said().contains("kept to 2 m (finer, to 1 m, would pass the 128 MiB"), "{}", second.detail_said());
        assert!(lidar.detail_samples() <= MAX_DETAIL_SAMPLES);
        let t0 = lidar.get(TileCoord::new(0, 0)).unwrap();
        assert!(t0.detail(4).unwrap().iter().zip(&one_m.data).all(|(a, b)| a.to_bits() == b.to_bits()), "a 1 m tile at 1 m is the DEM itself");
    }
}
