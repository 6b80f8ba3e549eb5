//! Terrain a user pinned into the world: whole tiles of their own heights at the world's 32 m
//! spacing. The learned world keeps them exactly and grows around them
//! ([`super::learned::LearnedSource::with_pins`]): each pinned tile's 128 m tile is its area
//! mean, the tiles beside it take it as a given neighbour and are joined to its edges, and the
//! drainage treats it as an outlet it never changes. A world with pins is a pure function of
//! (seed, weights, pins).

use std::collections::BTreeMap;
use std::sync::Arc;

use crate::dem::Heightfield;
use crate::grid::{BASE_SPACING_M, TILE_SAMPLES, TileCoord};
use crate::models::tcm::TILE_PX;

/// Pinned tiles at most (each 64 KiB at 32 m and 4 KiB at 128 m): a 32 × 32 km import.
pub const MAX_PINNED_TILES: usize = 64;

/// One pinned tile.
#[derive(Clone, Debug, PartialEq)]
pub struct PinnedTile {
    /// Its 32 m heights ([`TILE_SAMPLES`]², metres, row-major).
    pub fine: Arc<Vec<f32>>,
    /// Its 128 m area means ([`TILE_PX`]², metres): the tile as the TCM sees it.
    pub coarse: Arc<Vec<f32>>,
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
        Ok(Self { fine: Arc::new(tile.data), coarse: Arc::new(coarse.data) })
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

    /// Pins `hf` with its north-west sample on the north-west sample of tile `at`: area-averaged
    /// to 32 m (a coarser DEM is refused: pins are never upsampled), no-data filled from the
    /// nearest data, cut into the whole tiles it covers (its last partial row and column of
    /// tiles are left out). Returns the tiles pinned; on an error nothing is pinned.
    pub fn add(&mut self, hf: &Heightfield, at: TileCoord) -> Result<Vec<TileCoord>, String> {
        if hf.spacing_m > BASE_SPACING_M * 1.0001 {
            return Err(format!("pinned terrain must be {BASE_SPACING_M} m or finer; this is {} m", hf.spacing_m));
        }
        let grid = hf.resample_area(BASE_SPACING_M).map_err(|e| e.to_string())?;
        let grid = grid.fill_nodata().ok_or("the pinned terrain has no data")?;
        let n = TILE_SAMPLES;
        let (w, h) = (grid.width / n, grid.height / n);
        if w == 0 || h == 0 {
            return Err(format!(
                "pinned terrain covers {:.1} × {:.1} km; a pin needs at least one whole tile ({:.1} km square)",
                grid.width as f64 * BASE_SPACING_M / 1000.0,
                grid.height as f64 * BASE_SPACING_M / 1000.0,
                n as f64 * BASE_SPACING_M / 1000.0
            ));
        }
        if self.tiles.len() + w * h > MAX_PINNED_TILES {
            return Err(format!("{} tiles pinned with this one, more than {MAX_PINNED_TILES}", self.tiles.len() + w * h));
        }
        let mut new = Vec::new();
        for j in 0..h {
            for i in 0..w {
                let tile = PinnedTile::new(grid.window(i * n, j * n, n, n).data)?;
                new.push((at.offset(i as i32, j as i32), tile));
            }
        }
        let coords = new.iter().map(|(c, _)| *c).collect();
        self.tiles.extend(new);
        Ok(coords)
    }

    /// Pins one tile's 32 m heights ([`TILE_SAMPLES`]², finite), replacing any pin there.
    pub fn insert(&mut self, c: TileCoord, fine: Vec<f32>) -> Result<(), String> {
        if !self.tiles.contains_key(&c) && self.tiles.len() >= MAX_PINNED_TILES {
            return Err(format!("at most {MAX_PINNED_TILES} tiles can be pinned"));
        }
        self.tiles.insert(c, PinnedTile::new(fine)?);
        Ok(())
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

    /// Whether tile `c` lies within `reach` tiles (Chebyshev distance) of a pinned tile.
    pub fn within(&self, c: TileCoord, reach: i32) -> bool {
        self.tiles.keys().any(|p| (p.i - c.i).abs().max((p.j - c.j).abs()) <= reach)
    }

    /// The pinned tiles' coordinates, in tile order.
    pub fn coords(&self) -> Vec<TileCoord> {
        self.tiles.keys().copied().collect()
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
        assert_eq!(got, vec![TileCoord::new(-1, 3), TileCoord::new(0, 3), TileCoord::new(-1, 4), TileCoord::new(0, 4)]);
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
}
