//! Training and validation data for the TEM from real DEMs: the resolution ladder (area
//! averaging only; never upsampling real data), a split by region, chained samples with the 8
//! rotations/flips, and self-similar reuse of coarse data for fine levels.

use std::collections::HashMap;
use std::path::Path;

use crate::dem::{Heightfield, PngScale};
use crate::models::tem::LEVEL_SPACING_M;
use crate::world::schedule::mix64;

/// Output patch side (pixels) at every level; inputs are half of it.
pub const PATCH: usize = 128;

/// Fraction of each DEM's columns (the east side) held out for validation.
pub const VALIDATION_FRACTION: f64 = 1.0 / 3.0;

/// One DEM of the data folder.
pub struct Dem {
    /// Identifier from the manifest.
    pub id: String,
    /// Heights (metres) at the native spacing.
    pub hf: Heightfield,
}

/// Reads every DEM listed in `dir/manifest.json` (file, metres_per_pixel).
pub fn load_dems(dir: &Path) -> Result<Vec<Dem>, String> {
    let text = std::fs::read_to_string(dir.join("manifest.json")).map_err(|e| format!("{}: {e}", dir.join("manifest.json").display()))?;
    let manifest: serde_json::Value = serde_json::from_str(&text).map_err(|e| format!("manifest.json: {e}"))?;
    let list = manifest["dems"].as_array().ok_or("manifest.json has no 'dems' list")?;
    let mut out = Vec::new();
    for d in list {
        let (Some(id), Some(file), Some(spacing)) = (d["id"].as_str(), d["file"].as_str(), d["metres_per_pixel"].as_f64()) else {
            return Err(format!("manifest entry without id/file/metres_per_pixel: {d}"));
        };
        let hf = Heightfield::read_path(&dir.join(file), Some(spacing), PngScale::default()).map_err(|e| format!("{file}: {e}"))?;
        out.push(Dem { id: id.to_string(), hf });
    }
    Ok(out)
}

/// Which part of a DEM a sample comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Split {
    /// The west columns.
    Train,
    /// The east third (never trained on).
    Validation,
}

/// Column range [x0, x1) of `split` in a grid `width` wide (a 16-pixel gap separates them).
pub fn split_columns(width: usize, split: Split) -> (usize, usize) {
    let cut = (width as f64 * (1.0 - VALIDATION_FRACTION)) as usize;
    match split {
        Split::Train => (0, cut.saturating_sub(8)),
        Split::Validation => ((cut + 8).min(width), width),
    }
}

/// A DEM prepared for levels whose finest output spacing is `spacing_m`: real data resampled
/// (area average) to that spacing where the DEM is fine enough, otherwise the DEM at its own
/// spacing with heights scaled by spacing / native spacing (self-similar reuse).
pub struct Working {
    /// Heights (metres, scaled if self-similar) at the working spacing.
    pub hf: Heightfield,
    /// Whether this is real data at the true spacing.
    pub real: bool,
}

/// Builds the working grid of `dem` for finest spacing `spacing_m`.
pub fn working(dem: &Heightfield, spacing_m: f64) -> Working {
    if dem.spacing_m <= spacing_m + 1e-9 {
        let hf = dem.resample_area(spacing_m).expect("coarser spacing");
        Working { hf, real: true }
    } else {
        let c = (spacing_m / dem.spacing_m) as f32;
        let data = dem.data.iter().map(|v| v * c).collect();
        Working { hf: Heightfield::new(dem.width, dem.height, spacing_m, data), real: false }
    }
}

/// A small deterministic RNG (SplitMix64).
#[derive(Clone, Debug)]
pub struct Rng(pub u64);

impl Rng {
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(1);
        mix64(self.0)
    }
    /// Uniform in 0..n.
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }
}

/// Applies dihedral transform `t` (0..8: 4 rotations × optional flip) to a square grid.
pub fn dihedral(src: &[f32], n: usize, t: usize) -> Vec<f32> {
    let mut out = vec![0f32; n * n];
    for y in 0..n {
        for x in 0..n {
            let (mut u, mut v) = (x, y);
            if t & 4 != 0 {
                u = n - 1 - u;
            }
            (u, v) = match t & 3 {
                0 => (u, v),
                1 => (n - 1 - v, u),
                2 => (n - 1 - u, n - 1 - v),
                _ => (v, n - 1 - u),
            };
            out[y * n + x] = src[v * n + u];
        }
    }
    out
}

/// Box-downsamples a square grid of side `n` by `f` (a power of two).
pub fn box_down(src: &[f32], n: usize, f: usize) -> Vec<f32> {
    let m = n / f;
    let mut out = vec![0f32; m * m];
    let inv = 1.0 / (f * f) as f32;
    for y in 0..m {
        for x in 0..m {
            let mut s = 0f32;
            for dy in 0..f {
                let row = (y * f + dy) * n + x * f;
                s += src[row..row + f].iter().sum::<f32>();
            }
            out[y * m + x] = s * inv;
        }
    }
    out
}

/// Crops the square [x0, x0+m) × [y0, y0+m) of a square grid of side `n`.
pub fn crop(src: &[f32], n: usize, x0: usize, y0: usize, m: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(m * m);
    for y in y0..y0 + m {
        out.extend_from_slice(&src[y * n + x0..y * n + x0 + m]);
    }
    out
}

/// One chained training sample over `levels` consecutive levels: the input (PATCH/2)² of the
/// first level, the quadrant (0..4: NW, NE, SW, SE) each later level enhances, and the ground
/// truth PATCH² of every level (metres).
pub struct Chain {
    /// Input heights of the first level, (PATCH/2)².
    pub input: Vec<f32>,
    /// Ground truth per level, PATCH² each.
    pub truth: Vec<Vec<f32>>,
}

/// Cuts a chain sample with quadrant choices `quads` (one per level after the first) from a
/// random NaN-free window of `w` in `split`; `None` if no such window was found in 20 tries.
pub fn chain_sample(w: &Heightfield, split: Split, levels: usize, quads: &[usize], rng: &mut Rng) -> Option<Chain> {
    let extent = PATCH << (levels - 1);
    let (c0, c1) = split_columns(w.width, split);
    if c1 < c0 + extent || w.height < extent {
        return None;
    }
    for _ in 0..20 {
        let x0 = c0 + rng.below(c1 - c0 - extent + 1);
        let y0 = rng.below(w.height - extent + 1);
        let win = w.window(x0, y0, extent, extent);
        if win.data.iter().any(|v| v.is_nan()) {
            continue;
        }
        let win = dihedral(&win.data, extent, rng.below(8));
        let mut truth = Vec::with_capacity(levels);
        let (mut rx, mut ry, mut size) = (0usize, 0usize, extent);
        for level in 0..levels {
            if level > 0 {
                let q = quads[level - 1];
                size /= 2;
                rx += (q % 2) * size;
                ry += (q / 2) * size;
            }
            let region = crop(&win, extent, rx, ry, size);
            truth.push(box_down(&region, size, size / PATCH));
        }
        let input = box_down(&truth[0], PATCH, 2);
        return Some(Chain { input, truth });
    }
    None
}

/// Working grids per (DEM index, finest spacing), built on first use.
#[derive(Default)]
pub struct WorkingCache {
    grids: HashMap<(usize, u64), Working>,
}

impl WorkingCache {
    /// The working grid of DEM `k` for finest spacing `spacing_m`.
    pub fn get<'a>(&'a mut self, dems: &[Dem], k: usize, spacing_m: f64) -> &'a Working {
        self.grids.entry((k, spacing_m.to_bits())).or_insert_with(|| working(&dems[k].hf, spacing_m))
    }
}

/// Finest output spacing (metres) of a chain that starts at level `first` and spans `levels`.
pub fn finest_spacing(first: usize, levels: usize) -> f64 {
    LEVEL_SPACING_M[first + levels - 1]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dihedral_transforms_are_the_eight_symmetries() {
        let src: Vec<f32> = (0..9).map(|k| k as f32).collect();
        let all: std::collections::HashSet<Vec<u32>> = (0..8).map(|t| dihedral(&src, 3, t).iter().map(|v| *v as u32).collect()).collect();
        assert_eq!(all.len(), 8);
        assert_eq!(dihedral(&src, 3, 0), src);
        assert_eq!(dihedral(&dihedral(&src, 3, 2), 3, 2), src, "two half-turns are the identity");
    }

    #[test]
    fn chains_nest_their_regions() {
        // A ramp: each level's truth is the box mean of its region, so the first truth's
        // quadrant, box-downsampled, equals the second truth box-downsampled twice.
        let n = 2 * PATCH;
        let hf = Heightfield::new(3 * n, n, 1.0, (0..3 * n * n).map(|k| ((k % (3 * n)) as f32 * 0.5) + (k / (3 * n)) as f32).collect());
        let mut rng = Rng(3);
        let c = chain_sample(&hf, Split::Train, 2, &[3], &mut rng).unwrap();
        assert_eq!(c.input.len(), PATCH * PATCH / 4);
        assert_eq!(c.truth.len(), 2);
        let q = crop(&c.truth[0], PATCH, PATCH / 2, PATCH / 2, PATCH / 2);
        let fine = box_down(&c.truth[1], PATCH, 2);
        let err = q.iter().zip(&fine).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(err < 1e-3, "{err}");
    }

    #[test]
    fn splits_do_not_overlap_and_working_grids_never_upsample() {
        let (a0, a1) = split_columns(900, Split::Train);
        let (b0, b1) = split_columns(900, Split::Validation);
        assert!(a0 == 0 && a1 < b0 && b1 == 900 && b1 - b0 >= 290);
        let coarse = Heightfield::new(4, 4, 30.0, vec![300.0; 16]);
        let w = working(&coarse, 2.0);
        assert!(!w.real);
        assert!((w.hf.data[0] - 20.0).abs() < 1e-4, "self-similar scaling keeps slopes: 300 m × 2/30");
        let fine = Heightfield::new(8, 8, 1.0, vec![5.0; 64]);
        let w = working(&fine, 2.0);
        assert!(w.real && w.hf.width == 4 && w.hf.spacing_m == 2.0);
    }
}
