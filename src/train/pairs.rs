//! Training and validation data for the TEM from real DEMs: the resolution ladder (area
//! averaging only; never upsampling real data), a split by region, chained samples with the 8
//! rotations/flips, and self-similar reuse of coarse data for fine levels.

use std::collections::HashMap;
use std::path::Path;

use crate::dem::{Heightfield, PngScale, dihedral};
use crate::grid::mix64;
use crate::models::tem::LEVEL_SPACING_M;

pub use crate::models::tem::{MARGIN, PATCH, QUAD, WINDOW};

/// Fraction of each DEM's columns (the east side) held out for validation.
pub const VALIDATION_FRACTION: f64 = 1.0 / 3.0;

/// One DEM of the data folder.
pub struct Dem {
    /// Identifier from the manifest.
    pub id: String,
    /// Heights (metres) at the native spacing.
    pub hf: Heightfield,
}

/// The JSON of `dir/manifest.json`.
fn read_manifest(dir: &Path) -> Result<serde_json::Value, String> {
    let path = dir.join("manifest.json");
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    serde_json::from_str(&text).map_err(|e| format!("manifest.json: {e}"))
}

/// Reads every DEM listed in `dir/manifest.json` (file, metres_per_pixel).
pub fn load_dems(dir: &Path) -> Result<Vec<Dem>, String> {
    let manifest = read_manifest(dir)?;
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

/// Earth radius of the spherical Web Mercator projection (metres).
const MERCATOR_RADIUS_M: f64 = 6_378_137.0;

/// Reads every Web Mercator grid listed in `dir/manifest.json`'s `files` (the layout of
/// `dem_coarse`: `file`, `mercator_metres_per_sample`, `mercator_bounds_xmin_ymin_xmax_ymax`)
/// as bands of `band_rows` rows (the last one shorter), each a [`Dem`] whose spacing is the
/// ground spacing at the band's middle row (the Mercator spacing × cos latitude: within 4 % over
/// 256 rows at 60°). Each grid is first 3×3-median-filtered (its packing puts heights near a
/// multiple of 256 m off by up to ±128 m); then the sea (below 0 m) and no-data become NaN,
/// so windows hold land only. Bands without a land sample are left out.
pub fn load_mercator_bands(dir: &Path, band_rows: usize) -> Result<Vec<Dem>, String> {
    assert!(band_rows > 0, "bands need rows");
    let manifest = read_manifest(dir)?;
    let list = manifest["files"].as_array().ok_or("manifest.json has no 'files' list")?;
    let mut out = Vec::new();
    for d in list {
        let bounds = d["mercator_bounds_xmin_ymin_xmax_ymax"].as_array().and_then(|b| b.get(3)).and_then(|v| v.as_f64());
        let (Some(id), Some(file), Some(step), Some(y_max)) = (d["id"].as_str(), d["file"].as_str(), d["mercator_metres_per_sample"].as_f64(), bounds) else {
            return Err(format!("manifest entry without id/file/mercator_metres_per_sample/mercator_bounds_xmin_ymin_xmax_ymax: {}", d["id"]));
        };
        let raw = Heightfield::read_path(&dir.join(file), Some(step), PngScale::default()).map_err(|e| format!("{file}: {e}"))?;
        let filtered = median3(&raw.data, raw.width, raw.height);
        for (b, y0) in (0..raw.height).step_by(band_rows).enumerate() {
            let rows = band_rows.min(raw.height - y0);
            let middle = y_max - (y0 as f64 + rows as f64 / 2.0) * step;
            let latitude = (middle / MERCATOR_RADIUS_M).sinh().atan();
            let data: Vec<f32> = filtered[y0 * raw.width..(y0 + rows) * raw.width].iter().map(|&v| if v >= 0.0 { v } else { f32::NAN }).collect();
            if data.iter().any(|v| v.is_finite()) {
                out.push(Dem { id: format!("{id}#{b}"), hf: Heightfield::new(raw.width, rows, step * latitude.cos(), data) });
            }
        }
    }
    Ok(out)
}

/// The 3×3 median of each finite sample of a `w`×`h` grid over its finite neighbours
/// (clamped at the edges); NaN stays NaN.
fn median3(data: &[f32], w: usize, h: usize) -> Vec<f32> {
    let mut out = data.to_vec();
    let mut near = Vec::with_capacity(9);
    for y in 0..h {
        for x in 0..w {
            if !data[y * w + x].is_finite() {
                continue;
            }
            near.clear();
            for yy in y.saturating_sub(1)..(y + 2).min(h) {
                for xx in x.saturating_sub(1)..(x + 2).min(w) {
                    let v = data[yy * w + xx];
                    if v.is_finite() {
                        near.push(v);
                    }
                }
            }
            near.sort_by(f32::total_cmp);
            out[y * w + x] = near[near.len() / 2];
        }
    }
    out
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

/// One chained training sample over `levels` consecutive levels: the input window
/// ([`WINDOW`]² at the first level's input spacing, metres) and the ground truth core
/// ([`PATCH`]², metres) of every level, each the quadrant (0..4: NW, NE, SW, SE) of the previous
/// core chosen by `quads`.
pub struct Chain {
    /// Input heights of the first level, WINDOW².
    pub input: Vec<f32>,
    /// Ground truth core per level, PATCH² each.
    pub truth: Vec<Vec<f32>>,
}

/// Side (pixels of the finest level) of the region a chain of `levels` reads.
pub fn chain_extent(levels: usize) -> usize {
    WINDOW << levels
}

/// Whether grid `w` has room for a chain of `levels` in `split`.
pub fn fits(w: &Heightfield, split: Split, levels: usize) -> bool {
    fits_square(w, split, chain_extent(levels))
}

/// Whether a `side`² window fits in `split` of `hf`.
pub fn fits_square(hf: &Heightfield, split: Split, side: usize) -> bool {
    let (c0, c1) = split_columns(hf.width, split);
    c1 >= c0 + side && hf.height >= side
}

/// A random `side`² window of `hf` in `split` without no-data, in one of the 8 rotations/flips
/// (row-major heights); `None` if it does not fit or 20 tries found only windows with
/// no-data.
pub fn random_window(hf: &Heightfield, split: Split, side: usize, rng: &mut Rng) -> Option<Vec<f32>> {
    if !fits_square(hf, split, side) {
        return None;
    }
    let (c0, c1) = split_columns(hf.width, split);
    for _ in 0..20 {
        let x0 = c0 + rng.below(c1 - c0 - side + 1);
        let y0 = rng.below(hf.height - side + 1);
        let win = hf.window(x0, y0, side, side);
        if win.data.iter().all(|v| v.is_finite()) {
            return Some(dihedral(&win.data, side, rng.below(8)));
        }
    }
    None
}

/// A DEM resampled (area average) to a training spacing.
pub struct Grid {
    /// Identifier from the manifest.
    pub id: String,
    /// Heights (metres) at that spacing.
    pub hf: Heightfield,
}

/// Every DEM at `spacing_m` or finer, area-averaged to it (never upsampled), with room for a
/// `side`² window in both splits.
pub fn grids_at(dems: &[Dem], spacing_m: f64, side: usize) -> Vec<Grid> {
    dems.iter()
        .filter(|d| d.hf.spacing_m <= spacing_m + 1e-9)
        .filter_map(|d| d.hf.resample_area(spacing_m).ok().map(|hf| Grid { id: d.id.clone(), hf }))
        .filter(|g| [Split::Train, Split::Validation].iter().all(|&s| fits_square(&g.hf, s, side)))
        .collect()
}

/// Cuts a chain sample with quadrant choices `quads` (one per level after the first) from a
/// random NaN-free window of `w` in `split`; `None` if no such window was found in 20 tries.
/// Every level's truth is the area mean of the finest grid (never upsampled).
pub fn chain_sample(w: &Heightfield, split: Split, levels: usize, quads: &[usize], rng: &mut Rng) -> Option<Chain> {
    let extent = chain_extent(levels);
    let finest = Heightfield::new(extent, extent, w.spacing_m, random_window(w, split, extent, rng)?);
    // pyramid[t]: the window at 2^t × the finest spacing.
    let mut pyramid = vec![finest];
    for _ in 0..levels {
        let next = pyramid.last().expect("non-empty").downsample2();
        pyramid.push(next);
    }
    let mut truth = Vec::with_capacity(levels);
    // Core origin of level j in its own output grid: the input margin, then quadrants.
    let mut core = (2 * MARGIN, 2 * MARGIN);
    for j in 0..levels {
        if j > 0 {
            let q = quads[j - 1];
            core = (2 * (core.0 + (q % 2) * QUAD), 2 * (core.1 + (q / 2) * QUAD));
        }
        truth.push(pyramid[levels - 1 - j].window(core.0, core.1, PATCH, PATCH).data);
    }
    let input = pyramid.pop().expect("coarsest").data;
    Some(Chain { input, truth })
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

    /// A 20×300 Mercator grid at 2446 m a sample whose top row lies at 60° N, read as bands of
    /// 128 rows: three bands (128, 128, 44 rows); each band's spacing is 2446 m × cos of its
    /// middle row's latitude (about 1,249 m at 59.3° to 1,339 m at 56.8°); a +128 m spike on a
    /// plain is gone after the median; the sea (−50 m) is NaN and the coast's land kept (the
    /// median of its rows).
    #[test]
    fn mercator_bands_have_their_latitudes_spacing_and_lose_spikes_and_sea() {
        let (w, h, step) = (20usize, 300usize, 2446.0f64);
        let mut data: Vec<f32> = (0..w * h).map(|k| 700.0 + (k / w) as f32).collect();
        data[50 * w + 10] += 128.0;
        for v in data.iter_mut().skip(290 * w) {
            *v = -50.0;
        }
        let dir = std::env::temp_dir().join(format!("terrain-mercator-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        Heightfield::new(w, h, step, data).write_tiff(std::fs::File::create(dir.join("g.tif")).unwrap()).unwrap();
        let top = 60f64.to_radians().tan().asinh() * MERCATOR_RADIUS_M;
        let manifest = serde_json::json!({ "files": [{ "id": "g", "file": "g.tif", "mercator_metres_per_sample": step, "mercator_bounds_xmin_ymin_xmax_ymax": [0.0, top - h as f64 * step, w as f64 * step, top] }] });
        std::fs::write(dir.join("manifest.json"), manifest.to_string()).unwrap();
        let bands = load_mercator_bands(&dir, 128).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(bands.iter().map(|b| (b.id.as_str(), b.hf.height)).collect::<Vec<_>>(), [("g#0", 128), ("g#1", 128), ("g#2", 44)]);
        for (b, mid_row) in bands.iter().zip([64.0, 192.0, 278.0]) {
            let lat = ((top - mid_row * step) / MERCATOR_RADIUS_M).sinh().atan();
            assert!((b.hf.spacing_m - step * lat.cos()).abs() < 1e-6, "{}: {} m", b.id, b.hf.spacing_m);
        }
        assert!((bands[0].hf.spacing_m - 1249.0).abs() < 2.0 && (bands[2].hf.spacing_m - 1339.0).abs() < 2.0, "{} m, {} m", bands[0].hf.spacing_m, bands[2].hf.spacing_m);
        assert_eq!(bands[0].hf.data[50 * w + 10], 750.0, "the spike is gone");
        let last = &bands[2].hf;
        assert!(last.data[(290 - 256) * w..].iter().all(|v| v.is_nan()), "the sea is no-data");
        assert_eq!(last.data[(289 - 256) * w + 5], 988.0, "the coast's land is kept");
    }

    #[test]
    fn chains_nest_their_regions() {
        // A smooth field: each level's truth is the area mean of its region, so the first
        // truth's chosen quadrant equals the second truth box-downsampled, and the input's
        // centre equals the first truth box-downsampled.
        let n = chain_extent(2);
        let hf = Heightfield::new(
            3 * n / 2 + 20,
            n,
            1.0,
            (0..(3 * n / 2 + 20) * n).map(|k| ((k % (3 * n / 2 + 20)) as f32 * 0.05).sin() * 9.0 + (k / (3 * n / 2 + 20)) as f32 * 0.1).collect(),
        );
        assert!(fits(&hf, Split::Train, 2));
        let mut rng = Rng(3);
        let c = chain_sample(&hf, Split::Train, 2, &[3], &mut rng).unwrap();
        assert_eq!(c.input.len(), WINDOW * WINDOW);
        assert_eq!(c.truth.len(), 2);
        let t0 = Heightfield::new(PATCH, PATCH, 2.0, c.truth[0].clone());
        let q = t0.window(QUAD, QUAD, QUAD, QUAD);
        let fine = Heightfield::new(PATCH, PATCH, 1.0, c.truth[1].clone()).downsample2();
        let err = q.data.iter().zip(&fine.data).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(err < 1e-3, "{err}");
        let centre = Heightfield::new(WINDOW, WINDOW, 4.0, c.input.clone()).window(MARGIN, MARGIN, QUAD, QUAD);
        let err = centre.data.iter().zip(&t0.downsample2().data).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
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
