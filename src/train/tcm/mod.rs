//! Training the TCM (the 128 m tile generator, [`crate::models::tcm`]) on the CPU: 3×3-tile
//! windows cut from real DEMs resampled to 128 m by area averaging (never upsampled), the
//! schedule's four neighbour patterns, the 8 rotations/flips, and a loss of λ·L1 plus a small
//! PatchGAN (least squares) that sees the tile inside its real neighbours. Checkpoints (both
//! networks and the run's state) let a run resume in a later session.

use std::path::Path;

use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::tensor::{Device, Tensor, TensorData};

use super::gan::{self, Disc};
use super::pairs::{Dem, Grid, Rng, Split, grids_at, random_window};
use super::world_eval::COHERENCE_BOX_PX;
use crate::dem::Heightfield;
use crate::models::tcm::{
    COARSE_SPACING_M, CONTEXT_PX, HEIGHT_SCALE_M, IN_CHANNELS, RUGGEDNESS_BOX_PX, TILE_PX, Tcm, TcmCpu, assemble_input, assemble_input_field, centre, centre_level,
    macro_field_cells, phase_mask, tile_ruggedness,
};
use crate::world::seam;
use burn::tensor::module::avg_pool2d;
use burn::tensor::ops::AvgPoolOptions;

/// Weight of the L1 term against the adversarial term.
pub const L1_WEIGHT: f32 = 10.0;
/// The part of a context window the discriminator judges: the centre tile (first px, size px).
const CENTRE: Option<(usize, usize)> = Some((TILE_PX, TILE_PX));
/// The macro field's tile-centre values in training are the true tile means plus noise of
/// this standard deviation (metres) plus this fraction of the nine means' spread: at inference
/// the field is procedural, so the network must treat it as a hint, not as the answer.
pub const MACRO_JITTER_M: f32 = 15.0;
/// See [`MACRO_JITTER_M`].
pub const MACRO_JITTER_FRACTION: f32 = 0.15;
/// Standard deviation of the noise added to each tile's measured ruggedness in training
/// (natural-log units): the seeded field of the world is a hint of the same kind.
pub const RUGGEDNESS_JITTER: f32 = 0.2;
/// Channels the discriminator sees: heights, the macro field and the ruggedness field.
const DISC_CHANNELS: usize = 3;

/// Every DEM with room for a context window in both splits, area-averaged to 128 m.
pub fn grids(dems: &[Dem]) -> Vec<Grid> {
    grids_at(dems, COARSE_SPACING_M, CONTEXT_PX)
}

/// Statistics of real tile means at 128 m (4096 m tiles on a grid from each DEM's corner),
/// to compare with the procedural macro field: (mean level, standard deviation of the level,
/// root mean square difference between side-by-side tiles), metres.
pub fn tile_mean_stats(grids: &[Grid]) -> (f64, f64, f64) {
    let (mut means, mut diffs) = (Vec::new(), Vec::new());
    for g in grids {
        let (nx, ny) = (g.hf.width / TILE_PX, g.hf.height / TILE_PX);
        let mean = |i: usize, j: usize| -> f64 {
            let mut s = 0.0;
            for v in 0..TILE_PX {
                for u in 0..TILE_PX {
                    s += g.hf.data[(j * TILE_PX + v) * g.hf.width + i * TILE_PX + u] as f64;
                }
            }
            s / (TILE_PX * TILE_PX) as f64
        };
        let m: Vec<Vec<f64>> = (0..ny).map(|j| (0..nx).map(|i| mean(i, j)).collect()).collect();
        for j in 0..ny {
            for i in 0..nx {
                if !m[j][i].is_finite() {
                    continue;
                }
                means.push(m[j][i]);
                for (a, b) in [(i + 1, j), (i, j + 1)] {
                    if a < nx && b < ny && m[b][a].is_finite() {
                        diffs.push(m[b][a] - m[j][i]);
                    }
                }
            }
        }
    }
    let avg = means.iter().sum::<f64>() / means.len().max(1) as f64;
    let sd = (means.iter().map(|v| (v - avg).powi(2)).sum::<f64>() / means.len().max(1) as f64).sqrt();
    let rms = (diffs.iter().map(|d| d * d).sum::<f64>() / diffs.len().max(1) as f64).sqrt();
    (avg, sd, rms)
}

/// Mean, standard deviation and 95th percentile of the centre tiles' ruggedness
/// ([`tile_ruggedness`], natural-log units) over every context window on a 32-sample grid
/// inside `split` of each grid with no missing data; `None` when no window fits.
pub fn ruggedness_stats(grids: &[&Grid], split: Split) -> Option<(f32, f32, f32)> {
    let mut v = Vec::new();
    for g in grids {
        let (x0, x1) = super::pairs::split_columns(g.hf.width, split);
        for y in (0..g.hf.height.saturating_sub(CONTEXT_PX - 1)).step_by(TILE_PX) {
            for x in (x0..x1.saturating_sub(CONTEXT_PX - 1)).step_by(TILE_PX) {
                let h: Vec<f32> = (0..CONTEXT_PX * CONTEXT_PX).map(|p| g.hf.data[(y + p / CONTEXT_PX) * g.hf.width + x + p % CONTEXT_PX]).collect();
                if h.iter().all(|v| v.is_finite()) {
                    v.push(tile_ruggedness(&h)[4] as f64);
                }
            }
        }
    }
    if v.is_empty() {
        return None;
    }
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    let sd = (v.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
    v.sort_by(f64::total_cmp);
    Some((mean as f32, sd as f32, v[v.len() * 95 / 100] as f32))
}

/// One training example.
pub struct Sample {
    /// The network's input ([`IN_CHANNELS`] × 96²).
    pub input: Vec<f32>,
    /// The real window's heights relative to the centre's macro level, in units of
    /// [`HEIGHT_SCALE_M`] (96²): the discriminator's context and, in the centre, the truth.
    pub real: Vec<f32>,
    /// The schedule phase whose neighbour pattern the input has (0..4).
    pub phase: usize,
}

/// Cuts a sample for phase `phase` from a random window of `hf` in `split`
/// ([`random_window`]): the macro field from the jittered means of `macro_cells`² cells
/// ([`macro_field_cells`]; 3: the tile means, the world's field; 6: 2048 m cells), the
/// ruggedness field from the jittered measured ruggedness, noise from `rng`.
pub fn sample(hf: &Heightfield, split: Split, phase: usize, macro_cells: usize, rng: &mut Rng) -> Option<Sample> {
    let h = random_window(hf, split, CONTEXT_PX, rng)?;
    let tiles: Vec<Vec<f32>> = (0..9).map(|t| tile_of(&h, t)).collect();
    let means: Vec<f32> = tiles.iter().map(|t| t.iter().sum::<f32>() / t.len() as f32).collect();
    let avg = means.iter().sum::<f32>() / 9.0;
    let spread = (means.iter().map(|m| (m - avg).powi(2)).sum::<f32>() / 9.0).sqrt();
    let jitter = MACRO_JITTER_M + MACRO_JITTER_FRACTION * spread;
    let centres: [f32; 9] = std::array::from_fn(|t| means[t] + jitter * crate::models::tcm::gauss(rng.next_u64()));
    let rugged = tile_ruggedness(&h).map(|r| r + RUGGEDNESS_JITTER * crate::models::tcm::gauss(rng.next_u64()));
    let mask = phase_mask(phase);
    let given: [Option<&[f32]>; 9] = std::array::from_fn(|t| mask[t].then_some(tiles[t].as_slice()));
    if macro_cells == 3 {
        let input = assemble_input(&given, &centres, &rugged, rng.next_u64());
        let real = h.iter().map(|v| (v - centres[4]) / HEIGHT_SCALE_M).collect();
        return Some(Sample { input, real, phase });
    }
    let k = macro_cells;
    let cells: Vec<f32> = cell_means(&h, k).into_iter().map(|m| m + jitter * crate::models::tcm::gauss(rng.next_u64())).collect();
    let level = centre_level(&cells, k);
    let input = assemble_input_field(&given, &macro_field_cells(&cells, k), level, &rugged, rng.next_u64());
    let real = h.iter().map(|v| (v - level) / HEIGHT_SCALE_M).collect();
    Some(Sample { input, real, phase })
}

/// The means (metres) of the `k`×`k` square cells of a context window `h` ([`CONTEXT_PX`]²,
/// row-major), row-major.
fn cell_means(h: &[f32], k: usize) -> Vec<f32> {
    let side = CONTEXT_PX / k;
    let mut sums = vec![0f32; k * k];
    for (p, &v) in h.iter().enumerate() {
        sums[(p / CONTEXT_PX / side) * k + p % CONTEXT_PX / side] += v;
    }
    sums.into_iter().map(|s| s / (side * side) as f32).collect()
}

/// Whether `k` cells a side can carry the macro field of a TCM training run: a multiple of 3
/// (whole cells per tile) that divides [`CONTEXT_PX`].
pub fn valid_macro_cells(k: usize) -> bool {
    k >= 3 && k.is_multiple_of(3) && CONTEXT_PX.is_multiple_of(k)
}

/// Settings of a TCM training run.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TcmConfig {
    /// Windows per step.
    pub batch: usize,
    /// Adam learning rate of the generator (the discriminator's is half).
    pub lr: f64,
    /// Weight of the adversarial term (0: L1 only).
    pub adversarial: f32,
    /// Seed of the sampler.
    pub seed: u64,
    /// Weight of the ruggedness term ([`log_relief_gap`]; 0: none). Runs saved before it
    /// existed read 0.
    #[serde(default)]
    pub ruggedness: f32,
    /// Weight of the drainage term ([`depression_depth`]; 0: none). Runs saved before it
    /// existed read 0.
    #[serde(default)]
    pub drainage: f32,
    /// Weight of the coarse term ([`coarse_gap`]; 0: none). Runs saved before it existed
    /// read 0.
    #[serde(default)]
    pub coarse: f32,
    /// Weight of the L1 term far from every given neighbour and everywhere in phase-0 windows
    /// ([`l1_weight_map`]): there the real tile is one of many plausible ones, and L1 towards it
    /// pulls towards their smooth mean. Runs saved before it existed read 1.
    #[serde(default = "one")]
    pub free_l1: f32,
    /// Reach (samples at 128 m) of the full L1 weight from the given neighbours
    /// ([`l1_weight_map`]); 0: every window with a neighbour weighs L1 fully. Runs saved
    /// before it existed read 0.
    #[serde(default)]
    pub l1_reach_px: f32,
    /// Train on the tiles as the world shows them: each made tile joined to its given side
    /// neighbours ([`joined_offsets`]) before the losses see it. Runs saved before it existed
    /// read false.
    #[serde(default)]
    pub joined: bool,
    /// Weight of the dome term ([`dome_gap`]; 0: none). Runs saved before it existed read 0.
    #[serde(default)]
    pub dome: f32,
    /// The discriminator also sees the window's slopes ([`with_slopes`]): the texture of
    /// valleys and ridges is in the slopes, while the heights are dominated by the tile's
    /// level and tilt. Runs saved before it existed read false.
    #[serde(default)]
    pub disc_slopes: bool,
    /// Weight of the position term ([`position_gap`]; 0: none). A loss weight only, so a
    /// resumed run may change it. Runs saved before it existed read 0.
    #[serde(default)]
    pub position: f32,
    /// Cells a side of the macro field the generator is given ([`sample`]; 3: one per tile,
    /// as the world's; 6: 2048 m). Runs saved before it existed read 3.
    #[serde(default = "three")]
    pub macro_cells: usize,
    /// Weight of the coherence term ([`coherence_gap`]; 0: none). A loss weight only, so a
    /// resumed run may change it. Runs saved before it existed read 0.
    #[serde(default)]
    pub coherence: f32,
}

fn three() -> usize {
    3
}

fn one() -> f32 {
    1.0
}

impl Default for TcmConfig {
    fn default() -> Self {
        Self {
            batch: 8,
            lr: 2e-4,
            adversarial: 1.0,
            seed: 1,
            ruggedness: 0.0,
            drainage: 0.0,
            coarse: 0.0,
            free_l1: 1.0,
            l1_reach_px: 0.0,
            joined: false,
            dome: 0.0,
            disc_slopes: false,
            position: 0.0,
            macro_cells: 3,
            coherence: 0.0,
        }
    }
}

/// Per window of a batch [B, 1, 96, 96] (heights in units of [`HEIGHT_SCALE_M`]): the natural
/// log of the rms difference between the centre tile and its [`RUGGEDNESS_BOX_PX`]² box mean
/// — the centre value of [`tile_ruggedness`] up to the constant ln([`HEIGHT_SCALE_M`] /
/// [`RUGGEDNESS_REF_M`](crate::models::tcm::RUGGEDNESS_REF_M)). [B].
fn centre_log_relief(window: Tensor<4>) -> Tensor<1> {
    let b = window.dims()[0];
    let (t, r) = (TILE_PX, RUGGEDNESS_BOX_PX / 2);
    let around = window.clone().slice([0..b, 0..1, t - r..2 * t + r, t - r..2 * t + r]);
    let boxed = avg_pool2d(around, AvgPoolOptions::new([RUGGEDNESS_BOX_PX, RUGGEDNESS_BOX_PX]).with_stride([1, 1]));
    let square = (centre(window, t) - boxed).powf_scalar(2.0).mean_dim(3).mean_dim(2);
    (square + 1e-8).sqrt().log().reshape([b])
}

/// The ruggedness term: the mean over the batch of |ln relief of the made centre − ln relief
/// of the real one| ([`centre_log_relief`]), so a generator that makes tiles smoother (or
/// rougher) than the real ones it stands for pays for it whatever the phase of their detail.
pub fn log_relief_gap(made: Tensor<4>, real: Tensor<4>) -> Tensor<1> {
    (centre_log_relief(made) - centre_log_relief(real)).abs().mean()
}

/// The drainage term: for windows [B, 1, 96, 96] (heights in units of [`HEIGHT_SCALE_M`]),
/// the mean over the centre tiles' samples of how far each lies below the level that a
/// depression fill of its window ([`crate::world::drainage::fill_depressions`], the window's
/// border the outlet, level lakes) raises it to. The fill levels are held fixed, so the
/// gradient lifts the floors of the made tile's closed depressions and nothing else: real
/// terrain drains, and a generator whose tiles are full of basins makes a world of lakes
/// once they are filled.
pub fn depression_depth(window: Tensor<4>) -> Tensor<1> {
    let [b, _, n, _] = window.dims();
    let device = window.device();
    let heights: Vec<f32> = window.clone().detach().into_data().try_to_vec::<f32>().expect("f32 heights");
    let mut filled = heights.clone();
    for w in filled.chunks_mut(n * n) {
        crate::world::drainage::fill_depressions(w, n, 0.0);
    }
    let mask: Vec<f32> = filled.iter().zip(&heights).map(|(f, h)| if f > h { 1.0 } else { 0.0 }).collect();
    let (filled, mask) = (tensor(filled, [b, 1, n, n], &device), tensor(mask, [b, 1, n, n], &device));
    centre((filled - window) * mask, TILE_PX).mean()
}

/// Side (samples) of the blocks whose means the coarse term ([`coarse_gap`]) compares.
pub const COARSE_BLOCK_PX: usize = 8;

/// The coarse term: the mean |difference| between the [`COARSE_BLOCK_PX`]² block means of
/// the made centre tiles and of the real ones ([B, 1, 32, 32] each, units of
/// [`HEIGHT_SCALE_M`]). The per-sample L1 leaves the tile's large-scale shape nearly free (a
/// bowl of 20 m is small beside 100 m of detail errors), and the generator learned a shape
/// per phase — bowls in phases 0 and 2, domes in 1 and 3, 12–23 m deep on real validation
/// windows whose centres average < 9 m — that draws the tile grid on the world; this term
/// weighs exactly those errors.
pub fn coarse_gap(made: Tensor<4>, real: Tensor<4>) -> Tensor<1> {
    let pool = |t: Tensor<4>| avg_pool2d(t, AvgPoolOptions::new([COARSE_BLOCK_PX, COARSE_BLOCK_PX]).with_stride([COARSE_BLOCK_PX, COARSE_BLOCK_PX]));
    (pool(made) - pool(real)).abs().mean()
}

/// Per schedule phase present in a batch of centre tiles [B, 1, T, T] (`phases`, B values),
/// |mean [`dome_height`] of the made tiles − that of the real ones|, weighted by the phase's
/// share of the batch and summed. [1]. The PatchGAN judges patches, not a whole tile's
/// shape, and far from the neighbours L1 weighs little ([`l1_weight_map`]): this term keeps
/// the made tiles from being bowls or domes on average (each phase drew the tile grid on the
/// world with its own bias), without pulling any one tile towards the real one's shape.
pub fn dome_gap(made: Tensor<4>, real: Tensor<4>, phases: &[usize]) -> Tensor<1> {
    let b = phases.len();
    // dome_height is linear: its weights are its values on the unit impulses, found once.
    static WEIGHTS: std::sync::OnceLock<Vec<f32>> = std::sync::OnceLock::new();
    let weights = WEIGHTS.get_or_init(|| {
        let n = TILE_PX * TILE_PX;
        let mut unit = vec![0f32; n];
        (0..n)
            .map(|p| {
                unit[p] = 1.0;
                let w = dome_height(&unit) as f32;
                unit[p] = 0.0;
                w
            })
            .collect()
    });
    let w = tensor(weights.clone(), [1, 1, TILE_PX, TILE_PX], &made.device());
    let domes = ((made - real) * w).sum_dim(3).sum_dim(2).reshape([b]);
    let mut total = None;
    for phase in 0..4 {
        let share: Vec<f32> = phases.iter().map(|&p| if p == phase { 1.0 } else { 0.0 }).collect();
        let count: f32 = share.iter().sum();
        if count == 0.0 {
            continue;
        }
        let pick = Tensor::<1>::from_data(TensorData::new(share, [b]), &domes.device());
        let term = (domes.clone() * pick).sum().abs() / b as f32;
        total = Some(match total {
            Some(t) => t + term,
            None => term,
        });
    }
    total.unwrap_or_else(|| Tensor::<1>::zeros([1], &domes.device()))
}

/// Per window of a batch [B, 1, 96, 96] (heights in units of [`HEIGHT_SCALE_M`]): the mean
/// orientation coherence around the centre tile — the measure of
/// [`crate::train::world_eval::orientation_coherence`] at 128 m (forward differences, the
/// structure tensor averaged over [`COHERENCE_BOX_PX`]² boxes, `√((Jxx − Jyy)² + 4·Jxy²) /
/// (Jxx + Jyy)`) over the boxes centred within about a sample of the centre tile. [B].
fn centre_coherence(window: Tensor<4>) -> Tensor<1> {
    let b = window.dims()[0];
    let (t, r) = (TILE_PX, COHERENCE_BOX_PX / 2 + 1);
    let m = t + 2 * r;
    let region = window.slice([0..b, 0..1, t - r..2 * t + r, t - r..2 * t + r]);
    let dx = (region.clone().narrow(3, 1, m - 1) - region.clone().narrow(3, 0, m - 1)).narrow(2, 0, m - 1);
    let dy = (region.clone().narrow(2, 1, m - 1) - region.narrow(2, 0, m - 1)).narrow(3, 0, m - 1);
    let boxed = |v: Tensor<4>| avg_pool2d(v, AvgPoolOptions::new([COHERENCE_BOX_PX, COHERENCE_BOX_PX]).with_stride([1, 1]));
    let (xx, yy, xy) = (boxed(dx.clone() * dx.clone()), boxed(dy.clone() * dy.clone()), boxed(dx * dy));
    let eps = 1e-10;
    let coherence = (((xx.clone() - yy.clone()).powf_scalar(2.0) + xy.powf_scalar(2.0) * 4.0 + eps).sqrt()) / (xx + yy + eps);
    coherence.mean_dim(3).mean_dim(2).reshape([b])
}

/// The coherence term: the mean over the batch of |orientation coherence around the made
/// centre tile − around the real one| ([`centre_coherence`]; windows [B, 1, 96, 96]). Real
/// mountains at 128 m are ridges and valleys, their gradients parallel over a kilometre
/// (`terrain eval-tcm`'s orientation coherence: 0.40–0.62 on real ranges); the generator
/// made round bumps (0.3), which L1, the ruggedness term and a patch discriminator all let
/// pass.
pub fn coherence_gap(made: Tensor<4>, real: Tensor<4>) -> Tensor<1> {
    (centre_coherence(made) - centre_coherence(real)).abs().mean()
}

/// How much the made tiles' roughness depends on the position inside the tile, for a batch
/// of centre tiles [B, 1, T, T]: the mean |second difference| across x at each column 1..T−2
/// (over the batch and the rows) and across y at each row, each divided by the mean of all
/// of them; the mean |ratio − 1|. [1]. 0 for a batch whose tiles are as rough at every
/// position. Real terrain knows nothing of tile positions; the trained generator drew a
/// grid — tiles rough 2–3 samples inside their edges (1.3–1.5 × the mean) and smooth on them.
pub fn position_gap(made: Tensor<4>) -> Tensor<1> {
    let [_, _, h, w] = made.dims();
    let d2x = made.clone().narrow(3, 2, w - 2) - made.clone().narrow(3, 1, w - 2) * 2.0 + made.clone().narrow(3, 0, w - 2);
    let d2y = made.clone().narrow(2, 2, h - 2) - made.clone().narrow(2, 1, h - 2) * 2.0 + made.narrow(2, 0, h - 2);
    let px = d2x.abs().mean_dim(0).mean_dim(2).reshape([w - 2]);
    let py = d2y.abs().mean_dim(0).mean_dim(3).reshape([h - 2]);
    profile_gap(Tensor::cat(vec![px, py], 0))
}

/// How far a profile of positive values (e.g. roughness by position) is from flat: each
/// value divided by their mean, the mean |ratio − 1|. [1]; 0 for a flat profile.
pub fn profile_gap(profile: Tensor<1>) -> Tensor<1> {
    let mean = profile.clone().mean();
    (profile / (mean + 1e-6) - 1.0).abs().mean()
}

/// The dome height of a tile (`TILE_PX`², any unit): after removing its best-fit plane, the
/// mean of the samples at least [`COARSE_BLOCK_PX`] from every edge minus the mean of the
/// edge samples — positive for a dome, negative for a bowl, 0 for a plane.
pub fn dome_height(t: &[f32]) -> f64 {
    let n = TILE_PX;
    let c = (n as f64 - 1.0) / 2.0;
    let mean = t.iter().map(|&v| v as f64).sum::<f64>() / (n * n) as f64;
    // The grid is symmetric, so the plane's slopes are independent least-squares fits.
    let (mut sx, mut sy, mut ss) = (0.0, 0.0, 0.0);
    for p in 0..n * n {
        let (x, y) = ((p % n) as f64 - c, (p / n) as f64 - c);
        sx += x * t[p] as f64;
        sy += y * t[p] as f64;
        ss += x * x;
    }
    let (bx, by) = (sx / ss, sy / ss);
    let (mut inner, mut ni, mut edge, mut ne) = (0.0, 0.0, 0.0, 0.0);
    for p in 0..n * n {
        let (x, y) = (p % n, p / n);
        let r = t[p] as f64 - mean - bx * (x as f64 - c) - by * (y as f64 - c);
        let d = x.min(n - 1 - x).min(y).min(n - 1 - y);
        if d == 0 {
            edge += r;
            ne += 1.0;
        } else if d >= COARSE_BLOCK_PX {
            inner += r;
            ni += 1.0;
        }
    }
    inner / ni - edge / ne
}

/// Per phase, over `windows` windows of the validation split of `grids`: the mean
/// [`dome_height`] (metres) of the tiles `g` makes minus that of the real centre tiles of the
/// same windows, and its standard error, with the world's macro field (one cell per tile). A
/// generator that continues its neighbours without bias scores 0 within the error.
pub fn phase_dome_bias(g: &TcmCpu, grids: &[Grid], windows: usize, threads: usize) -> [(f64, f64); 4] {
    let mut rng = Rng(0x444F_4D45);
    let mut s = crate::models::tcm::TcmScratch::default();
    std::array::from_fn(|phase| {
        let mut gaps = Vec::new();
        for t in 0..windows * 4 {
            if gaps.len() == windows || grids.is_empty() {
                break;
            }
            let Some(smp) = sample(&grids[t % grids.len()].hf, Split::Validation, phase, 3, &mut rng) else { continue };
            let made = dome_height(&g.forward(&smp.input, &mut s, threads));
            gaps.push((made - dome_height(&tile_of(&smp.real, 4))) * HEIGHT_SCALE_M as f64);
        }
        let k = gaps.len().max(2) as f64;
        let mean = gaps.iter().sum::<f64>() / k;
        let sd = (gaps.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (k - 1.0)).sqrt();
        (mean, sd / k.sqrt())
    })
}

/// Tile `t` (row-major over the 3×3; 4 is the centre) of a context window (`CONTEXT_PX`²,
/// row-major): `TILE_PX`² samples.
fn tile_of(window: &[f32], t: usize) -> Vec<f32> {
    crate::world::tile::cut(window, CONTEXT_PX, TILE_PX, (t % 3) * TILE_PX, (t / 3) * TILE_PX)
}

/// Running losses and progress of a run (saved with every checkpoint).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct TcmProgress {
    /// Steps done.
    pub step: usize,
    /// Seconds of training so far (all sessions).
    pub seconds: f64,
    /// Exponential running mean of the L1 term (units of [`HEIGHT_SCALE_M`]).
    pub l1: f64,
    /// Running mean of the generator's adversarial term.
    pub adv: f64,
    /// Running mean of the discriminator's loss.
    pub disc: f64,
    /// (step, l1, adv, disc, seconds) every 50 steps: the training curve.
    pub curve: Vec<(usize, f64, f64, f64, f64)>,
    /// Running mean of the drainage term ([`depression_depth`] of the made tiles, units of
    /// [`HEIGHT_SCALE_M`]), measured whatever its weight.
    #[serde(default)]
    pub depression: f64,
}

impl TcmProgress {
    /// The running mean `old` updated with this step's value `new`: the first step's value as
    /// it is, then 2 % of each new one.
    fn running(&self, old: f64, new: f64) -> f64 {
        if self.step == 0 { new } else { 0.98 * old + 0.02 * new }
    }

    /// Records one step's losses and seconds.
    pub fn record(&mut self, l1: f64, adv: f64, disc: f64, seconds: f64) {
        let mix = |old: f64, new: f64| self.running(old, new);
        (self.l1, self.adv, self.disc) = (mix(self.l1, l1), mix(self.adv, adv), mix(self.disc, disc));
        self.step += 1;
        self.seconds += seconds;
        if self.step.is_multiple_of(50) {
            self.curve.push((self.step, self.l1, self.adv, self.disc, self.seconds));
        }
    }
}

/// The windows of one training step ([`TcmRun::batch`]).
#[derive(Clone, Debug)]
pub struct TcmBatch {
    /// Network inputs, [n, IN_CHANNELS, CONTEXT_PX, CONTEXT_PX] row-major.
    inputs: Vec<f32>,
    /// The real windows, [n, 1, CONTEXT_PX, CONTEXT_PX] (units of [`HEIGHT_SCALE_M`] about
    /// the centre tile's jittered mean).
    reals: Vec<f32>,
    /// L1 weight of each centre sample ([`l1_weight_map`]), [n, TILE_PX²].
    l1_weights: Vec<f32>,
    /// Phase of each window.
    phases: Vec<usize>,
}

/// A run in progress: both networks, their optimisers and the progress.
pub struct TcmRun {
    /// The generator.
    pub g: Tcm,
    /// The discriminator.
    pub d: Disc,
    og: ModuleOptimizer,
    od: ModuleOptimizer,
    /// Settings.
    pub cfg: TcmConfig,
    /// Progress so far.
    pub progress: TcmProgress,
    device: Device,
}

fn tensor(data: Vec<f32>, shape: [usize; 4], device: &Device) -> Tensor<4> {
    Tensor::<4>::from_data(TensorData::new(data, shape), device)
}

/// The window `real` [B, 1, 96, 96] with its centre tile replaced by `tile` [B, 1, 32, 32].
fn with_centre(real: Tensor<4>, tile: Tensor<4>) -> Tensor<4> {
    let t = TILE_PX;
    real.slice_assign([0..tile.dims()[0], 0..1, t..2 * t, t..2 * t], tile)
}

/// Weight of the L1 term at each sample of the centre tile ([`TILE_PX`]², row-major) for a
/// window whose given neighbours are `mask` ([`phase_mask`] order): `free` + (1 − `free`) ·
/// exp(−d / `reach_px`), d the distance (samples at 128 m) to the nearest given neighbour.
/// Where the neighbours fix the answer (near them) L1 counts fully; far from them the centre
/// is one of many plausible tiles, and L1 towards the real one pulls towards their smooth
/// mean, so it counts `free` and the adversarial term shapes the tile. No neighbour: `free`
/// everywhere; `reach_px` 0: 1 everywhere if any neighbour is given.
pub fn l1_weight_map(mask: &[bool; 9], free: f32, reach_px: f32) -> Vec<f32> {
    let t = TILE_PX as f32;
    let mut w = vec![free; TILE_PX * TILE_PX];
    if !mask.iter().any(|&m| m) {
        return w;
    }
    if reach_px <= 0.0 {
        w.fill(1.0);
        return w;
    }
    for (p, w) in w.iter_mut().enumerate() {
        let (x, y) = (t + (p % TILE_PX) as f32 + 0.5, t + (p / TILE_PX) as f32 + 0.5);
        let d = (0..9).filter(|&k| mask[k]).map(|k| {
            let (x0, y0) = ((k % 3) as f32 * t, (k / 3) as f32 * t);
            let dx = (x0 - x).max(x - (x0 + t)).max(0.0);
            let dy = (y0 - y).max(y - (y0 + t)).max(0.0);
            dx.hypot(dy)
        });
        let d = d.fold(f32::INFINITY, f32::min);
        *w = free + (1.0 - free) * (-d / reach_px).exp();
    }
    w
}

/// The mean |`made` − `real`| over a batch of centre tiles [B, 1, T, T] weighted sample by
/// sample by `weights` (B·T², [`l1_weight_map`] per window) and divided by their sum; equal
/// weights give the plain mean. [1].
pub fn weighted_l1(made: Tensor<4>, real: Tensor<4>, weights: Vec<f32>) -> Tensor<1> {
    let dims = made.dims();
    let total: f32 = weights.iter().sum();
    let w = tensor(weights.iter().map(|v| v / total.max(1e-6)).collect(), dims, &made.device());
    ((made - real).abs() * w).sum()
}

/// What the world's join ([`seam::join_edges`]) adds to each made centre tile of a batch:
/// `made` (B·[`TILE_PX`]²) next to the real windows `real` (B·[`CONTEXT_PX`]²) whose side
/// tiles are given where `masks` says (the four sides only, as in the world). Added to the
/// generator's output as a constant (the gradient passes straight through), so the losses and
/// the discriminator judge the tile as the world shows it, while the generator learns as if
/// its own output were moved. B·[`TILE_PX`]².
pub fn joined_offsets(made: &[f32], real: &[f32], masks: &[[bool; 9]]) -> Vec<f32> {
    let (t2, c2) = (TILE_PX * TILE_PX, CONTEXT_PX * CONTEXT_PX);
    let mut out = vec![0f32; made.len()];
    for (b, mask) in masks.iter().enumerate() {
        let window = &real[b * c2..(b + 1) * c2];
        let tiles: Vec<Option<Vec<f32>>> = seam::SIDES
            .iter()
            .map(|&(di, dj)| {
                let t = ((dj + 1) * 3 + di + 1) as usize;
                mask[t].then(|| tile_of(window, t))
            })
            .collect();
        let mut tile = made[b * t2..(b + 1) * t2].to_vec();
        seam::join_edges(&mut tile, TILE_PX, std::array::from_fn(|k| tiles[k].as_deref()));
        for (o, (j, m)) in out[b * t2..(b + 1) * t2].iter_mut().zip(tile.iter().zip(&made[b * t2..(b + 1) * t2])) {
            *o = j - m;
        }
    }
    out
}

/// Slope gain of [`with_slopes`]: a 128 m step of 0.1 × [`HEIGHT_SCALE_M`] (50 m, 21°)
/// becomes 0.5.
pub const DISC_SLOPE_GAIN: f32 = 5.0;

/// Windows [B, 1, H, W] (heights) with their slopes appended: [B, 3, H, W], the forward
/// differences along x and along y times [`DISC_SLOPE_GAIN`] (0 in the last column / row).
pub fn with_slopes(h: Tensor<4>) -> Tensor<4> {
    let [b, _, rows, cols] = h.dims();
    let dev = h.device();
    let dx = h.clone().narrow(3, 1, cols - 1) - h.clone().narrow(3, 0, cols - 1);
    let dx = Tensor::cat(vec![dx, Tensor::zeros([b, 1, rows, 1], &dev)], 3);
    let dy = h.clone().narrow(2, 1, rows - 1) - h.clone().narrow(2, 0, rows - 1);
    let dy = Tensor::cat(vec![dy, Tensor::zeros([b, 1, 1, cols], &dev)], 2);
    Tensor::cat(vec![h, dx * DISC_SLOPE_GAIN, dy * DISC_SLOPE_GAIN], 1)
}

/// Starts a run on `device` (an autodiff device): resumes the checkpoint in `resume_from`, or
/// else starts the generator from `init` (weights the CPU kernels read, e.g.
/// [`TcmCpu::widened`]) or from random weights.
pub fn start_run(cfg: TcmConfig, device: &Device, resume_from: Option<&Path>, init: Option<&TcmCpu>) -> Result<TcmRun, String> {
    let mut g = Tcm::new(device);
    if let Some(w) = init {
        g = w.into_model(g);
    }
    let mut cfg = cfg;
    if let Some(dir) = resume_from {
        // The saved settings decide the discriminator's inputs.
        cfg = serde_json::from_value(gan::read_state(dir, "tcm")?["config"].clone()).map_err(|e| format!("tcm_state.json: {e}"))?;
    }
    let mut d = Disc::with_inputs(DISC_CHANNELS + if cfg.disc_slopes { 2 } else { 0 }, device);
    let (mut og, mut od) = (gan::adam(), gan::adam());
    let mut progress = TcmProgress::default();
    if let Some(dir) = resume_from {
        let state;
        (og, od, state) = gan::load_run(dir, "tcm", GEN_FILE, &mut g, &mut d)?;
        progress = serde_json::from_value(state["progress"].clone()).map_err(|e| format!("tcm_state.json: {e}"))?;
    }
    Ok(TcmRun { g, d, og, od, cfg, progress, device: device.clone() })
}

/// The generator's checkpoint and weight file name (the learned world reads it).
pub use crate::world::learned::TCM_FILE as GEN_FILE;

impl TcmRun {
    /// One optimiser step of both networks on a batch cut from `grids` (train split, phases
    /// drawn uniformly): [`Self::batch`] then [`Self::fit`].
    pub fn step(&mut self, grids: &[Grid]) -> Result<(), String> {
        let batch = self.batch(grids)?;
        self.fit(&batch).map(|_| ())
    }

    /// The batch this step trains on: [`TcmConfig::batch`] windows cut from `grids` (train
    /// split, phases drawn uniformly), seeded by the run's seed and step count.
    pub fn batch(&self, grids: &[Grid]) -> Result<TcmBatch, String> {
        let mut rng = Rng(self.cfg.seed.wrapping_mul(0x1_0000_0001) ^ self.progress.step as u64);
        let b = self.cfg.batch;
        let (mut inputs, mut reals, mut l1_weights, mut phases) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut tries = 0;
        while reals.len() < b * CONTEXT_PX * CONTEXT_PX && tries < b * 20 {
            tries += 1;
            let g = &grids[rng.below(grids.len())];
            let phase = rng.below(4);
            if let Some(s) = sample(&g.hf, Split::Train, phase, self.cfg.macro_cells, &mut rng) {
                inputs.extend(s.input);
                reals.extend(s.real);
                l1_weights.extend(l1_weight_map(&phase_mask(s.phase), self.cfg.free_l1, self.cfg.l1_reach_px));
                phases.push(s.phase);
            }
        }
        let n = reals.len() / (CONTEXT_PX * CONTEXT_PX);
        if n == 0 {
            return Err("no NaN-free training window in any DEM".into());
        }
        Ok(TcmBatch { inputs, reals, l1_weights, phases })
    }

    /// One optimiser step of both networks on `batch`. Returns the batch's L1 term before
    /// the step (units of [`HEIGHT_SCALE_M`]).
    pub fn fit(&mut self, batch: &TcmBatch) -> Result<f64, String> {
        let t0 = web_time::Instant::now();
        let n = batch.phases.len();
        let (phases, l1_weights) = (&batch.phases, batch.l1_weights.clone());
        let dev = &self.device;
        let x = tensor(batch.inputs.clone(), [n, IN_CHANNELS, CONTEXT_PX, CONTEXT_PX], dev);
        let real = tensor(batch.reals.clone(), [n, 1, CONTEXT_PX, CONTEXT_PX], dev);
        let cond = Tensor::cat(vec![x.clone().narrow(1, 4, 1), x.clone().narrow(1, 7, 1)], 1);
        let truth = centre(real.clone(), TILE_PX);
        let mut fake = self.g.forward(x);
        if self.cfg.joined {
            let values = |t: Tensor<4>| t.detach().into_data().try_to_vec::<f32>().map_err(|e| format!("{e:?}"));
            let masks: Vec<[bool; 9]> = phases.iter().map(|&p| phase_mask(p)).collect();
            let offsets = joined_offsets(&values(fake.clone())?, &values(real.clone())?, &masks);
            fake = fake + tensor(offsets, [n, 1, TILE_PX, TILE_PX], dev);
        }
        let adv_w = self.cfg.adversarial;
        let (mut adv_v, mut disc_v) = (0.0, 0.0);
        if adv_w > 0.0 {
            let judged = |w: Tensor<4>| Tensor::cat(vec![if self.cfg.disc_slopes { with_slopes(w) } else { w }, cond.clone()], 1);
            let real_in = judged(real.clone());
            let fake_in = judged(with_centre(real.clone(), fake.clone().detach()));
            disc_v = gan::disc_step(&mut self.d, &mut self.od, self.cfg.lr * 0.5, real_in, fake_in, CENTRE);
        }
        let l1 = weighted_l1(fake.clone(), truth, l1_weights);
        let l1_v = l1.clone().into_scalar::<f32>() as f64;
        let mut loss = l1 * L1_WEIGHT;
        if self.cfg.ruggedness > 0.0 {
            loss = loss + log_relief_gap(with_centre(real.clone(), fake.clone()), real.clone()) * self.cfg.ruggedness;
        }
        if self.cfg.dome > 0.0 {
            loss = loss + dome_gap(fake.clone(), centre(real.clone(), TILE_PX), phases) * self.cfg.dome;
        }
        if self.cfg.position > 0.0 {
            loss = loss + position_gap(fake.clone()) * self.cfg.position;
        }
        if self.cfg.coarse > 0.0 {
            loss = loss + coarse_gap(fake.clone(), centre(real.clone(), TILE_PX)) * self.cfg.coarse;
        }
        if self.cfg.coherence > 0.0 {
            loss = loss + coherence_gap(with_centre(real.clone(), fake.clone()), real.clone()) * self.cfg.coherence;
        }
        let depression = depression_depth(with_centre(real.clone(), fake.clone()));
        let depression_v = depression.clone().into_scalar::<f32>() as f64;
        if self.cfg.drainage > 0.0 {
            loss = loss + depression * self.cfg.drainage;
        }
        if adv_w > 0.0 {
            let window = with_centre(real, fake);
            let window = if self.cfg.disc_slopes { with_slopes(window) } else { window };
            let adv = gan::gen_adversarial(&self.d, Tensor::cat(vec![window, cond], 1), CENTRE);
            adv_v = adv.clone().into_scalar::<f32>() as f64;
            loss = loss + adv * adv_w;
        }
        let grads = loss.backward();
        let gp = GradientsParams::from_grads(grads, &self.g);
        self.g = self.og.step(self.cfg.lr, self.g.clone(), gp);
        self.progress.depression = self.progress.running(self.progress.depression, depression_v);
        self.progress.record(l1_v, adv_v, disc_v, t0.elapsed().as_secs_f64());
        Ok(l1_v)
    }

    /// Saves the checkpoint (generator, discriminator, optimisers, settings and progress) in
    /// `dir`.
    pub fn save(&self, dir: &Path) -> Result<(), String> {
        let state = serde_json::json!({ "config": self.cfg, "progress": self.progress });
        gan::save_run(dir, "tcm", GEN_FILE, &self.g, &self.d, &self.og, &self.od, &state)
    }
}

#[cfg(test)]
mod tests;
