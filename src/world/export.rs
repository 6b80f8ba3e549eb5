//! A rectangle of tiles as one heightfield: the CLI's `terrain world`, and the page's export
//! of the tiles around the eye.

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
    from_tiles(x0, y0, w, h, |c| Some(world.ensure(c))).expect("every tile made")
}

/// The largest square of whole tiles centred on the tile under (x, z) metres, at most
/// `2·radius + 1` tiles across, that `world` has made, as one heightfield like [`region`]'s:
/// what the page exports of the view. `None` when not even that tile is made.
pub fn around(world: &WorldStream, x_m: f64, z_m: f64, radius: u32) -> Option<Heightfield> {
    let c = TileCoord::containing(x_m, z_m);
    (0..=radius as i32).rev().find_map(|k| from_tiles(c.i - k, c.j - k, 2 * k as u32 + 1, 2 * k as u32 + 1, |t| world.get(t).cloned()))
}

/// Tiles [x0, x0 + w) × [y0, y0 + h) from `get`, as one heightfield like [`region`]'s; `None`
/// if one is missing.
pub fn from_tiles(x0: i32, y0: i32, w: u32, h: u32, mut get: impl FnMut(TileCoord) -> Option<std::sync::Arc<super::tile::Tile>>) -> Option<Heightfield> {
    let n = TILE_SAMPLES;
    let (width, height) = (w as usize * n, h as usize * n);
    let mut data = vec![0f32; width * height];
    for tj in 0..h as usize {
        for ti in 0..w as usize {
            let tile = get(TileCoord::new(x0 + ti as i32, y0 + tj as i32))?;
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
    Some(Heightfield::new(width, height, BASE_SPACING_M, data).with_geo(Some(GeoRef { origin_m: corner, epsg: None })))
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

    /// Around the eye, the largest made square of tiles is exported, equal to the same
    /// region made afresh: a 3 × 3 square of a world streamed with radius 1 (its ring of
    /// neighbours is made too), a 1 × 1 square when only the eye's tile is made, nothing
    /// before that.
    #[test]
    fn around_the_eye_the_largest_made_square_is_exported() {
        let src = || Box::new(ProceduralSource::default()) as Box<dyn TileSource>;
        let mut w = WorldStream::new(42, src(), 1.0);
        assert!(around(&w, 100.0, 100.0, 2).is_none());
        w.ensure(TileCoord::new(0, 0));
        assert_eq!(around(&w, 100.0, 100.0, 2).unwrap().width, TILE_SAMPLES);
        w.update(100.0, 100.0, 1e9);
        let hf = around(&w, 100.0, 100.0, 2).unwrap();
        assert_eq!((hf.width, hf.height), (3 * TILE_SAMPLES, 3 * TILE_SAMPLES), "radius 1 + its ring makes 3 × 3 (not 5 × 5)");
        assert_eq!(hf, region(42, src(), -1, -1, 3, 3));
    }
}
