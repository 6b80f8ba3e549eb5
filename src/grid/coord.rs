//! Tile coordinates of the infinite world grid and their relation to metres.

use serde::{Deserialize, Serialize};

/// Samples along one side of a tile at the coarsest scale (pixels).
///
/// 128 matches the paper's TCM tile (a 3×3 window is 384×384) and the TEM quadrant chain
/// (a 64×64 quadrant is enhanced to 128×128 at every level), and a tile of 128² samples is
/// generated in a few milliseconds, which fits a per-frame time slice.
pub const TILE_SAMPLES: usize = 128;

/// Distance between two samples of a tile at the coarsest scale (metres).
pub const BASE_SPACING_M: f64 = 32.0;

/// Side length of a tile (metres): 128 samples × 32 m = 4096 m.
pub const TILE_SIZE_M: f64 = TILE_SAMPLES as f64 * BASE_SPACING_M;

/// Integer coordinate of a tile: `i` grows towards +x (east), `j` towards +z (south).
///
/// Tile (i, j) covers world x in [i·4096, (i+1)·4096) metres and z likewise with j; its sample
/// (u, v) sits at x = i·4096 + u·32, z = j·4096 + v·32.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct TileCoord {
    /// Column of the tile (tile units, +x).
    pub i: i32,
    /// Row of the tile (tile units, +z).
    pub j: i32,
}

impl TileCoord {
    /// Tile (i, j).
    pub const fn new(i: i32, j: i32) -> Self {
        Self { i, j }
    }

    /// The tile that contains the world point (x, z) in metres.
    pub fn containing(x_m: f64, z_m: f64) -> Self {
        Self { i: (x_m / TILE_SIZE_M).floor() as i32, j: (z_m / TILE_SIZE_M).floor() as i32 }
    }

    /// World position (metres) of this tile's sample (0, 0), its north-west corner.
    pub fn origin_m(self) -> (f64, f64) {
        (self.i as f64 * TILE_SIZE_M, self.j as f64 * TILE_SIZE_M)
    }

    /// The tile offset by (di, dj) tiles.
    pub const fn offset(self, di: i32, dj: i32) -> Self {
        Self { i: self.i + di, j: self.j + dj }
    }

    /// Distance (tile units) from the world point (x, z) in metres to the nearest point of
    /// this tile; 0 inside it.
    pub fn distance_tiles(self, x_m: f64, z_m: f64) -> f64 {
        let (x0, z0) = self.origin_m();
        let dx = (x0 - x_m).max(x_m - (x0 + TILE_SIZE_M)).max(0.0);
        let dz = (z0 - z_m).max(z_m - (z0 + TILE_SIZE_M)).max(0.0);
        (dx * dx + dz * dz).sqrt() / TILE_SIZE_M
    }

    /// The eight neighbours and the tile itself, row by row (dj = −1, 0, 1; di = −1, 0, 1).
    pub fn window3x3(self) -> [TileCoord; 9] {
        let mut out = [self; 9];
        for (k, slot) in out.iter_mut().enumerate() {
            *slot = self.offset(k as i32 % 3 - 1, k as i32 / 3 - 1);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn containing_handles_negative_coordinates() {
        assert_eq!(TileCoord::containing(-0.5, 0.0), TileCoord::new(-1, 0));
        assert_eq!(TileCoord::containing(4095.9, -4096.0), TileCoord::new(0, -1));
        assert_eq!(TileCoord::containing(-4096.1, 8192.0), TileCoord::new(-2, 2));
    }

    #[test]
    fn distance_is_zero_inside_and_grows_outside() {
        let t = TileCoord::new(1, 1);
        assert_eq!(t.distance_tiles(5000.0, 5000.0), 0.0);
        assert!((t.distance_tiles(0.0, 5000.0) - 1.0).abs() < 1e-12);
        assert!((t.distance_tiles(0.0, 0.0) - 2f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn window_is_row_major_around_the_centre() {
        let w = TileCoord::new(5, -3).window3x3();
        assert_eq!(w[0], TileCoord::new(4, -4));
        assert_eq!(w[4], TileCoord::new(5, -3));
        assert_eq!(w[5], TileCoord::new(6, -3));
        assert_eq!(w[8], TileCoord::new(6, -2));
    }
}
