//! Writing a rectangle of tiles as one heightfield: the CLI's `terrain world`.

use super::stream::WorldStream;
use super::tile::TileSource;
use crate::dem::{GeoRef, Heightfield};
use crate::grid::coord::{BASE_SPACING_M, TILE_SAMPLES, TILE_SIZE_M, TileCoord};

/// The 32 m heights (metres) of tiles [x0, x0 + w) × [y0, y0 + h) of world `seed`, as one
/// heightfield of (w·128) × (h·128) samples, row 0 at the north (lowest z).
///
/// Every tile is a pure function of (seed, source, coordinate), so overlapping requests agree
/// bit for bit whatever their extent or order.
pub fn region(seed: u64, source: Box<dyn TileSource>, x0: i32, y0: i32, w: u32, h: u32) -> Heightfield {
    let mut world = WorldStream::new(seed, source, 1.0);
    let n = TILE_SAMPLES;
    let (width, height) = (w as usize * n, h as usize * n);
    let mut data = vec![0f32; width * height];
    for tj in 0..h as usize {
        for ti in 0..w as usize {
            let tile = world.ensure(TileCoord::new(x0 + ti as i32, y0 + tj as i32));
            for v in 0..n {
                let row = (tj * n + v) * width + ti * n;
                data[row..row + n].copy_from_slice(&tile.heights[v * n..(v + 1) * n]);
            }
        }
    }
    // The world's own metric frame (x east, z south; GeoTIFF's y points north): sample i covers
    // [32 i − 16, 32 i + 16) m.
    let half = BASE_SPACING_M / 2.0;
    let corner = [x0 as f64 * TILE_SIZE_M - half, -(y0 as f64 * TILE_SIZE_M - half)];
    Heightfield::new(width, height, BASE_SPACING_M, data).with_geo(Some(GeoRef { origin_m: corner, epsg: None }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::noise::ProceduralSource;

    #[test]
    fn overlapping_regions_agree_bit_for_bit() {
        let src = || Box::new(ProceduralSource::default()) as Box<dyn TileSource>;
        let a = region(42, src(), -2, -1, 3, 2);
        let b = region(42, src(), -1, -2, 2, 3);
        // Tiles (-1,-1) and (0,-1) lie in both: a covers them at tile columns 1..3 of row 0,
        // b at columns 0..2 of row 1.
        let n = TILE_SAMPLES;
        for v in 0..n {
            for u in 0..2 * n {
                let ha = a.data[v * a.width + n + u];
                let hb = b.data[(n + v) * b.width + u];
                assert_eq!(ha.to_bits(), hb.to_bits(), "sample ({u},{v})");
            }
        }
        assert_eq!((a.width, a.height), (3 * n, 2 * n));
        assert_ne!(region(43, src(), -1, -1, 1, 1).data, region(42, src(), -1, -1, 1, 1).data);
    }
}
