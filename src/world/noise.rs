//! The papers' procedural baseline: fractal gradient (Perlin) noise, as fBm or ridged
//! multifractal, evaluated on global sample positions so that tiles are seamless by
//! construction and identical on every platform (only +, −, ×, ÷ and floor on f64).

use serde::{Deserialize, Serialize};

use super::tile::{Neighbourhood, Tile, TileSource};
use crate::grid::coord::{BASE_SPACING_M, TILE_SAMPLES, TileCoord};
use crate::grid::mix64;

/// How octaves are combined.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum NoiseKind {
    /// Fractional Brownian motion: a plain sum of octaves (rolling hills).
    Fbm,
    /// Ridged multifractal (Musgrave): folded octaves weighted by the previous one (sharp crests).
    Ridged,
}

/// The range of each parameter: what [`NoiseParams::validate`] accepts, what a link may carry
/// and what the settings panel offers (one table, so no value is clamped on the way).
pub mod ranges {
    use std::ops::RangeInclusive;
    /// Octaves.
    pub const OCTAVES: RangeInclusive<u32> = 1..=16;
    /// Persistence.
    pub const PERSISTENCE: RangeInclusive<f32> = 0.0..=1.0;
    /// Lacunarity.
    pub const LACUNARITY: RangeInclusive<f32> = 1.0..=4.0;
    /// Wavelength of the first octave (metres).
    pub const WAVELENGTH_M: RangeInclusive<f32> = 100.0..=1.0e6;
    /// Amplitude (metres).
    pub const AMPLITUDE_M: RangeInclusive<f32> = 0.0..=20_000.0;
    /// Base height (metres).
    pub const BASE_M: RangeInclusive<f32> = -20_000.0..=20_000.0;
}

/// Parameters of the procedural source. Units: metres unless stated.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct NoiseParams {
    /// Octave combination.
    pub kind: NoiseKind,
    /// Number of octaves (1..=16).
    pub octaves: u32,
    /// Amplitude ratio between successive octaves (0..1).
    pub persistence: f32,
    /// Frequency ratio between successive octaves (> 1; the papers use 2).
    pub lacunarity: f32,
    /// Wavelength of the first octave (metres).
    pub wavelength_m: f32,
    /// Height range of the terrain (metres).
    pub amplitude_m: f32,
    /// Height added everywhere (metres); sea level is 0.
    pub base_m: f32,
}

impl Default for NoiseParams {
    fn default() -> Self {
        Self { kind: NoiseKind::Ridged, octaves: 8, persistence: 0.5, lacunarity: 2.0, wavelength_m: 20_000.0, amplitude_m: 2_400.0, base_m: -250.0 }
    }
}

impl NoiseParams {
    /// Checks that every field is in a range that makes a terrain; the message names the field.
    pub fn validate(&self) -> Result<(), String> {
        let finite = [self.persistence, self.lacunarity, self.wavelength_m, self.amplitude_m, self.base_m].iter().all(|v| v.is_finite());
        if !finite {
            return Err("noise parameters must be finite numbers".into());
        }
        if !ranges::OCTAVES.contains(&self.octaves) {
            return Err(format!("octaves must be 1..=16, got {}", self.octaves));
        }
        if !ranges::PERSISTENCE.contains(&self.persistence) {
            return Err(format!("persistence must be in 0..1, got {}", self.persistence));
        }
        if !ranges::LACUNARITY.contains(&self.lacunarity) {
            return Err(format!("lacunarity must be in 1..4, got {}", self.lacunarity));
        }
        if !ranges::WAVELENGTH_M.contains(&self.wavelength_m) {
            return Err(format!("wavelength must be 100 m..1000 km, got {} m", self.wavelength_m));
        }
        if !ranges::AMPLITUDE_M.contains(&self.amplitude_m) || !ranges::BASE_M.contains(&self.base_m) {
            return Err("amplitude and base must be within ±20 km".into());
        }
        Ok(())
    }
}

/// Smoothstep of order 5 (Perlin's improved fade curve).
fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

fn lattice_hash(seed: u64, ix: i64, iy: i64) -> u64 {
    mix64(seed ^ (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F))
}

fn gradient_dot(h: u64, dx: f64, dy: f64) -> f64 {
    match h >> 61 {
        0 => dx + dy,
        1 => dy - dx,
        2 => dx - dy,
        3 => -dx - dy,
        4 => dx * std::f64::consts::SQRT_2,
        5 => -dx * std::f64::consts::SQRT_2,
        6 => dy * std::f64::consts::SQRT_2,
        _ => -dy * std::f64::consts::SQRT_2,
    }
}

/// 2-D gradient noise at (x, y) (noise units = lattice cells), roughly in −1..1, exactly 0 on
/// lattice points.
pub fn perlin(seed: u64, x: f64, y: f64) -> f64 {
    let x0 = x.floor();
    let y0 = y.floor();
    let (fx, fy) = (x - x0, y - y0);
    let (ix, iy) = (x0 as i64, y0 as i64);
    let n00 = gradient_dot(lattice_hash(seed, ix, iy), fx, fy);
    let n10 = gradient_dot(lattice_hash(seed, ix + 1, iy), fx - 1.0, fy);
    let n01 = gradient_dot(lattice_hash(seed, ix, iy + 1), fx, fy - 1.0);
    let n11 = gradient_dot(lattice_hash(seed, ix + 1, iy + 1), fx - 1.0, fy - 1.0);
    let (u, v) = (fade(fx), fade(fy));
    let a = n00 + u * (n10 - n00);
    let b = n01 + u * (n11 - n01);
    a + v * (b - a)
}

/// Height (metres) of the procedural terrain of world `seed` at world position (x, z) metres.
pub fn height_at(seed: u64, p: &NoiseParams, x_m: f64, z_m: f64) -> f32 {
    let mut x = x_m / p.wavelength_m as f64;
    let mut y = z_m / p.wavelength_m as f64;
    let (mut amp, mut sum, mut norm, mut weight) = (1.0f64, 0.0f64, 0.0f64, 1.0f64);
    for o in 0..p.octaves {
        let n = perlin(mix64(seed.wrapping_add(o as u64)), x, y);
        match p.kind {
            NoiseKind::Fbm => sum += amp * n,
            NoiseKind::Ridged => {
                let r = 1.0 - n.abs();
                let signal = r * r * weight;
                weight = (signal * 2.0).clamp(0.0, 1.0);
                sum += amp * signal;
            }
        }
        norm += amp;
        amp *= p.persistence as f64;
        // Rotate each octave (a 3-4-5 rotation, exact in binary) and scale: no axis-aligned
        // lattice artefacts, no shared lattice points between octaves.
        let (nx, ny) = (x * 0.8 - y * 0.6, x * 0.6 + y * 0.8);
        x = nx * p.lacunarity as f64 + 17.25;
        y = ny * p.lacunarity as f64 - 9.5;
    }
    let value = if p.kind == NoiseKind::Fbm { 0.5 + 0.7 * sum / norm } else { sum / norm };
    (p.base_m as f64 + p.amplitude_m as f64 * value) as f32
}

/// Tile `coord`'s far-field tile ([`super::stream::far_samples`]): the same values as the
/// tile's own samples there.
pub fn coarse_tile(seed: u64, p: &NoiseParams, coord: TileCoord) -> Vec<f32> {
    super::stream::far_samples(coord, |gx, gz| height_at(seed, p, gx as f64 * BASE_SPACING_M, gz as f64 * BASE_SPACING_M))
}

/// The procedural tile source: fractal noise sampled at the tile's global sample positions.
#[derive(Clone, Debug, Default)]
pub struct ProceduralSource {
    /// Noise parameters.
    pub params: NoiseParams,
}

impl ProceduralSource {
    /// A source with parameters `params`.
    pub fn new(params: NoiseParams) -> Self {
        Self { params }
    }
}

impl TileSource for ProceduralSource {
    fn name(&self) -> String {
        match self.params.kind {
            NoiseKind::Fbm => "procedural fBm".into(),
            NoiseKind::Ridged => "procedural ridged".into(),
        }
    }

    fn uses_neighbours(&self) -> bool {
        false
    }

    fn far_tile(&self, seed: u64, coord: TileCoord) -> Option<Vec<f32>> {
        Some(coarse_tile(seed, &self.params, coord))
    }

    fn generate(&self, seed: u64, coord: TileCoord, _: &Neighbourhood<'_>) -> Tile {
        let n = TILE_SAMPLES as i64;
        let mut heights = Vec::with_capacity(TILE_SAMPLES * TILE_SAMPLES);
        for v in 0..n {
            let z = (coord.j as i64 * n + v) as f64 * BASE_SPACING_M;
            for u in 0..n {
                let x = (coord.i as i64 * n + u) as f64 * BASE_SPACING_M;
                heights.push(height_at(seed, &self.params, x, z));
            }
        }
        Tile::new(coord, heights)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn perlin_is_zero_on_lattice_points_and_bounded() {
        let mut max = 0f64;
        for k in 0..2000 {
            let (x, y) = (k as f64 * 0.137 - 50.0, k as f64 * 0.291 - 120.0);
            max = max.max(perlin(3, x, y).abs());
            assert_eq!(perlin(3, (k % 40) as f64 - 20.0, (k / 40) as f64), 0.0);
        }
        assert!(max > 0.4 && max <= 1.5, "range {max}");
    }

    #[test]
    fn noise_is_continuous_across_tile_borders() {
        // Heights on both sides of every border of tile (0,0) differ no more than heights
        // between neighbouring samples inside the tile: no step at the seam.
        let src = ProceduralSource::default();
        let nb = Neighbourhood::default();
        let c = src.generate(9, TileCoord::new(0, 0), &nb);
        let e = src.generate(9, TileCoord::new(1, 0), &nb);
        let s = src.generate(9, TileCoord::new(0, 1), &nb);
        let last = TILE_SAMPLES - 1;
        let mut inner = 0f32;
        for v in 0..TILE_SAMPLES {
            for u in 0..last {
                inner = inner.max((c.at(u + 1, v) - c.at(u, v)).abs());
                inner = inner.max((c.at(v, u + 1) - c.at(v, u)).abs());
            }
        }
        let mut across = 0f32;
        for k in 0..TILE_SAMPLES {
            across = across.max((e.at(0, k) - c.at(last, k)).abs());
            across = across.max((s.at(k, 0) - c.at(k, last)).abs());
        }
        assert!(across > 0.0, "terrain must not be flat");
        assert!(across <= 1.2 * inner, "step across the seam {across} m vs at most {inner} m between neighbours inside");
        // The sample one past the border, evaluated directly, is the neighbour's first sample.
        let direct = height_at(9, &src.params, TILE_SAMPLES as f64 * BASE_SPACING_M, 5.0 * BASE_SPACING_M);
        assert_eq!(direct.to_bits(), e.at(0, 5).to_bits());
    }

    #[test]
    fn kinds_and_parameters_change_the_terrain() {
        let mut p = NoiseParams::default();
        let a = height_at(1, &p, 1234.0, 5678.0);
        p.kind = NoiseKind::Fbm;
        let b = height_at(1, &p, 1234.0, 5678.0);
        assert_ne!(a, b);
        assert_ne!(height_at(1, &p, 1234.0, 5678.0), height_at(2, &p, 1234.0, 5678.0));
        p.octaves = 0;
        assert!(p.validate().is_err());
        assert!(NoiseParams::default().validate().is_ok());
    }

    #[test]
    fn heights_stay_within_base_and_amplitude() {
        let p = NoiseParams::default();
        let t = ProceduralSource::new(p).generate(4, TileCoord::new(-3, 7), &Neighbourhood::default());
        assert!(t.min_m >= p.base_m - 1.0 && t.max_m <= p.base_m + p.amplitude_m + 1.0, "{} {}", t.min_m, t.max_m);
        assert!(t.max_m - t.min_m > 50.0, "relief {}", t.max_m - t.min_m);
    }
}
