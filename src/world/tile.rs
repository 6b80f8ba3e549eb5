//! A generated tile and the interface every tile source (procedural noise now, the TCM next)
//! implements.

use crate::grid::coord::{TILE_SAMPLES, TileCoord};

/// Copies the `n`×`n` field `piece` (row-major) into `field` (row-major, `width` samples per
/// row) with its first sample at column `x0`, row `y0`: how tiles are put side by side.
pub fn paste(field: &mut [f32], width: usize, piece: &[f32], n: usize, x0: usize, y0: usize) {
    for v in 0..n {
        field[(y0 + v) * width + x0..][..n].copy_from_slice(&piece[v * n..(v + 1) * n]);
    }
}

/// The `n`×`n` field (row-major) whose first sample is at column `x0`, row `y0` of `field`
/// (row-major, `width` samples per row): the inverse of [`paste`].
pub fn cut(field: &[f32], width: usize, n: usize, x0: usize, y0: usize) -> Vec<f32> {
    (0..n).flat_map(|v| field[(y0 + v) * width + x0..][..n].iter().copied()).collect()
}

/// One tile of the world at the coarsest scale: `TILE_SAMPLES`² heights in metres, row-major
/// with rows along +z (index `v * TILE_SAMPLES + u`, u along +x).
#[derive(Clone, Debug, PartialEq)]
pub struct Tile {
    /// Which tile this is.
    pub coord: TileCoord,
    /// Heights above sea level (metres), `TILE_SAMPLES`² of them.
    pub heights: Vec<f32>,
    /// Lowest height in the tile (metres).
    pub min_m: f32,
    /// Highest height in the tile (metres).
    pub max_m: f32,
    /// FNV-1a hash of the heights' bits: equal checksums mean bit-identical tiles.
    pub checksum: u64,
}

impl Tile {
    /// Wraps `heights` (metres, `TILE_SAMPLES`² row-major) as tile `coord`.
    ///
    /// # Panics
    /// If `heights` does not hold exactly `TILE_SAMPLES`² values: that is a bug in a source.
    pub fn new(coord: TileCoord, heights: Vec<f32>) -> Self {
        assert_eq!(heights.len(), TILE_SAMPLES * TILE_SAMPLES, "a tile holds {0}×{0} samples", TILE_SAMPLES);
        let (min_m, max_m) = heights.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &h| (lo.min(h), hi.max(h)));
        let checksum = heights.iter().fold(crate::grid::Fnv::default(), |h, v| h.word(v.to_bits() as u64)).0;
        Self { coord, heights, min_m, max_m, checksum }
    }

    /// Height (metres) of sample (u, v), u along +x and v along +z, both in 0..TILE_SAMPLES.
    pub fn at(&self, u: usize, v: usize) -> f32 {
        self.heights[v * TILE_SAMPLES + u]
    }
}

/// The neighbours a tile is generated from: a 3×3 window in row-major order (dj = −1, 0, 1;
/// di = −1, 0, 1) with `None` where a neighbour is not an input (the centre is always `None`).
#[derive(Clone, Copy, Debug, Default)]
pub struct Neighbourhood<'a> {
    /// The window's tiles; index `(dj + 1) * 3 + (di + 1)`.
    pub tiles: [Option<&'a Tile>; 9],
}

impl<'a> Neighbourhood<'a> {
    /// The neighbour at offset (di, dj), each in −1..=1, if it is an input.
    pub fn get(&self, di: i32, dj: i32) -> Option<&'a Tile> {
        self.tiles[((dj + 1) * 3 + (di + 1)) as usize]
    }
}

/// A generator of tiles. `generate` must be a pure function of (seed, coordinate, neighbours):
/// the world's reproducibility and share links rest on it.
pub trait TileSource: Send + Sync {
    /// Short human-readable name, shown in the overlay (e.g. "procedural fBm").
    fn name(&self) -> String;

    /// Whether `generate` reads its neighbours; if not, the streamer skips the schedule's
    /// dependency resolution.
    fn uses_neighbours(&self) -> bool;

    /// Generates tile `coord` of world `seed` from the neighbours the schedule names.
    fn generate(&self, seed: u64, coord: TileCoord, neighbours: &Neighbourhood<'_>) -> Tile;

    /// Tile `coord`'s heights at every 4th sample (32² values, metres, row-major: the
    /// tile's own values, so a far-field tile meets a detailed one exactly), where that is
    /// cheap enough to make a few a frame on the page's main thread; `None` otherwise (the
    /// learned world's come from its worker).
    fn far_tile(&self, _seed: u64, _coord: TileCoord) -> Option<Vec<f32>> {
        None
    }
}

/// Which generator makes a world's tiles (a share link names it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum SourceKind {
    /// The learned world: the TCM and its ×4 step ([`super::learned`]).
    #[default]
    Learned,
    /// Procedural noise ([`super::noise`]).
    Procedural,
    /// The terrain drawn on the sketch canvas ([`super::sketched`]).
    Sketch,
}

impl SourceKind {
    /// The name in share links and on the command line (`tcm`, `procedural`, `sketch`).
    pub fn key(self) -> &'static str {
        match self {
            SourceKind::Learned => "tcm",
            SourceKind::Procedural => "procedural",
            SourceKind::Sketch => "sketch",
        }
    }

    /// Reads [`key`](Self::key)'s names.
    pub fn from_key(key: &str) -> Option<Self> {
        [SourceKind::Learned, SourceKind::Procedural, SourceKind::Sketch].into_iter().find(|k| k.key() == key)
    }

    /// The name shown to the user ("learned", "procedural").
    pub fn label(self) -> &'static str {
        match self {
            SourceKind::Learned => "learned",
            SourceKind::Procedural => "procedural",
            SourceKind::Sketch => "sketch",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2×2 piece pasted at column 1, row 2 of a 4-wide field lands on samples 9, 10, 13 and
    /// 14 and nowhere else, and cutting the same place gives it back.
    #[test]
    fn paste_puts_a_piece_where_cut_takes_it_from() {
        let mut field = vec![0f32; 16];
        paste(&mut field, 4, &[1.0, 2.0, 3.0, 4.0], 2, 1, 2);
        let want: Vec<f32> = (0..16)
            .map(|p| match p {
                9 => 1.0,
                10 => 2.0,
                13 => 3.0,
                14 => 4.0,
                _ => 0.0,
            })
            .collect();
        assert_eq!(field, want);
        assert_eq!(cut(&field, 4, 2, 1, 2), vec![1.0, 2.0, 3.0, 4.0]);
    }
}
