//! Training the ×4 step of the learned world ([`crate::models::grow`]) on the CPU: 32 m windows
//! from the DEMs fine enough for them (area averaging only), their 128 m area means as input,
//! the 8 rotations/flips, and λ·L1 plus a PatchGAN that sees the 32 m tile beside its bicubic
//! base. Resumable like the TCM's run.

use std::path::Path;

use burn::module::Module;
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::tensor::{Device, Tensor, TensorData};

use super::gan::{self, Disc};
use super::pairs::{Dem, Grid, Rng, Split, grids_at, random_window};
use super::tcm::{L1_WEIGHT, TcmProgress};
use crate::dem::Heightfield;
use crate::models::grow::{FACTOR, Grow, HEIGHT_SCALE_M, MARGIN, OUT_TILE, WINDOW, assemble, base};

/// The discriminator sees the residual (the detail the ×4 step adds to the bicubic base, a few
/// metres, ~0.03 in [`HEIGHT_SCALE_M`] units) times this gain beside the base: on the heights
/// themselves the detail was too small a part of the signal for it to learn anything (its loss
/// sat at the uninformed 0.25).
pub const DISC_RESIDUAL_GAIN: f32 = 20.0;
/// Spacing (metres) of the training targets: the world's.
pub const FINE_SPACING_M: f64 = 32.0;
/// Side (32 m samples) of the region one sample reads.
pub const EXTENT: usize = WINDOW * FACTOR;
/// Offset (32 m samples) of the output tile inside that region.
pub const CORE_OFFSET: usize = MARGIN * FACTOR;

/// Every DEM at 32 m or finer with room for a sample in both splits, area-averaged to 32 m.
pub fn grids(dems: &[Dem]) -> Vec<Grid> {
    grids_at(dems, FINE_SPACING_M, EXTENT)
}

/// One example: the network's inputs, the bicubic base of the tile and the true tile.
pub struct Sample {
    /// 128 m heights of the window (metres, [`WINDOW`]²).
    pub coarse: Vec<f32>,
    /// Inputs from [`assemble`]: 6 channels at 128 m, 1 at 64 m, 1 at 32 m.
    pub x: (Vec<f32>, Vec<f32>, Vec<f32>),
    /// The bicubic base of the output tile (metres, [`OUT_TILE`]²).
    pub base: Vec<f32>,
    /// The true 32 m tile (metres, [`OUT_TILE`]²).
    pub truth: Vec<f32>,
}

fn core(v: &[f32]) -> Vec<f32> {
    let n = EXTENT;
    (0..OUT_TILE * OUT_TILE).map(|p| v[(CORE_OFFSET + p / OUT_TILE) * n + CORE_OFFSET + p % OUT_TILE]).collect()
}

/// Cuts an example from a random window of `hf` (32 m) in `split` ([`random_window`]).
pub fn sample(hf: &Heightfield, split: Split, rng: &mut Rng) -> Option<Sample> {
    let fine = Heightfield::new(EXTENT, EXTENT, FINE_SPACING_M, random_window(hf, split, EXTENT, rng)?);
    let coarse = fine.downsample2().downsample2().data;
    let (gx0, gy0) = (rng.below(1 << 20) as i64 - (1 << 19), rng.below(1 << 20) as i64 - (1 << 19));
    let x = assemble(&coarse, rng.next_u64(), gx0, gy0);
    let b = core(&base(&coarse));
    Some(Sample { coarse, x, base: b, truth: core(&fine.data) })
}

/// How much the steps of a batch of 32 m tiles [B, 1, T, T] (T a multiple of [`FACTOR`],
/// the tiles' corners on the 128 m grid) depend on where they lie in the 4×4 cell of the
/// 128 m sample they were grown from: the mean |step| across x between columns c − 1 and c
/// for each c mod 4 (and across y by rows), each divided by the mean of all of them; the
/// mean |ratio − 1| over the 8 values. [1]. 0 when steps are as large at every place of the
/// cell. The trained network's steps were 5 % larger on the cell borders than inside them: a
/// texture of stripes every 128 m, and a tile edge (a cell border) measures as a slight seam.
pub fn cell_position_gap(h: Tensor<4>) -> Tensor<1> {
    let [b, c, rows, cols] = h.dims();
    let f = FACTOR;
    // Steps between columns j and j + 1 for the whole cells' worth of j, grouped by j mod f.
    let cells = (cols - 1) / f;
    let dx = (h.clone().narrow(3, 1, cells * f) - h.clone().narrow(3, 0, cells * f)).abs();
    let px = dx.reshape([b, c, rows, cells, f]).mean_dim(0).mean_dim(2).mean_dim(3).reshape([f]);
    let cells = (rows - 1) / f;
    let dy = (h.clone().narrow(2, 1, cells * f) - h.narrow(2, 0, cells * f)).abs();
    let py = dy.reshape([b, c, cells, f, cols]).mean_dim(0).mean_dim(2).mean_dim(4).reshape([f]);
    super::tcm::profile_gap(Tensor::cat(vec![px, py], 0))
}

/// The windows of one training step of the ×4 network ([`GrowRun::batch`]).
#[derive(Clone, Debug)]
pub struct GrowBatch {
    /// Windows in the batch.
    n: usize,
    /// The 128 m inputs, [n, 6, WINDOW, WINDOW].
    xs: Vec<f32>,
    /// The 64 m input, [n, 1, 2·WINDOW, 2·WINDOW].
    n64s: Vec<f32>,
    /// The 32 m input, [n, 1, 4·WINDOW, 4·WINDOW].
    n32s: Vec<f32>,
    /// The true residual over the bicubic base, [n, 1, OUT_TILE, OUT_TILE] (units of
    /// [`HEIGHT_SCALE_M`]).
    targets: Vec<f32>,
    /// The bicubic base less its mean, [n, 1, OUT_TILE, OUT_TILE] (units of
    /// [`HEIGHT_SCALE_M`]).
    bases: Vec<f32>,
}

/// A run of the ×4 network in progress.
pub struct GrowRun {
    /// The network.
    pub g: Grow,
    d: Disc,
    og: ModuleOptimizer,
    od: ModuleOptimizer,
    /// Windows per step.
    pub batch: usize,
    /// Generator learning rate (the discriminator's is half).
    pub lr: f64,
    /// Weight of the adversarial term.
    pub adversarial: f32,
    /// Weight of the position term ([`cell_position_gap`]; 0: none).
    pub position: f32,
    /// Progress (the same record as the TCM's).
    pub progress: TcmProgress,
    device: Device,
}

/// The network's checkpoint and weight file name (the learned world reads it).
pub use crate::world::learned::GROW_FILE;

fn tensor(data: Vec<f32>, shape: [usize; 4], device: &Device) -> Tensor<4> {
    Tensor::<4>::from_data(TensorData::new(data, shape), device)
}

impl GrowRun {
    /// Starts a run on `device` (an autodiff device) or resumes the one saved in `dir`.
    pub fn start(batch: usize, adversarial: f32, device: &Device, resume_from: Option<&Path>) -> Result<Self, String> {
        let mut run = Self {
            g: Grow::new(device),
            d: Disc::new(device),
            og: gan::adam(),
            od: gan::adam(),
            batch,
            lr: 2e-4,
            adversarial,
            position: 0.0,
            progress: TcmProgress::default(),
            device: device.clone(),
        };
        if let Some(dir) = resume_from {
            let state;
            (run.og, run.od, state) = gan::load_run(dir, "grow", GROW_FILE, &mut run.g, &mut run.d)?;
            run.progress = serde_json::from_value(state["progress"].clone()).map_err(|e| format!("grow_state.json: {e}"))?;
            run.batch = state["batch"].as_u64().map_or(batch, |b| b as usize);
            run.adversarial = state["adversarial"].as_f64().map_or(adversarial, |a| a as f32);
            run.position = state["position"].as_f64().map_or(0.0, |a| a as f32);
        }
        Ok(run)
    }

    /// One optimiser step of both networks on a batch from `grids` (train split):
    /// [`Self::batch`] then [`Self::fit`].
    pub fn step(&mut self, grids: &[Grid], seed: u64) -> Result<(), String> {
        let batch = self.batch(grids, seed)?;
        self.fit(&batch).map(|_| ())
    }

    /// The batch this step trains on: `self.batch` windows from `grids` (train split),
    /// seeded by `seed` and the step count.
    pub fn batch(&self, grids: &[Grid], seed: u64) -> Result<GrowBatch, String> {
        let mut rng = Rng(seed.wrapping_mul(0x2_0000_0003) ^ self.progress.step as u64 ^ 0x5151);
        let (mut xs, mut n64s, mut n32s, mut targets, mut bases) = (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut got = 0;
        for _ in 0..self.batch * 20 {
            if got == self.batch {
                break;
            }
            let g = &grids[rng.below(grids.len())];
            if let Some(s) = sample(&g.hf, Split::Train, &mut rng) {
                let mean = s.base.iter().sum::<f32>() / s.base.len() as f32;
                xs.extend(s.x.0);
                n64s.extend(s.x.1);
                n32s.extend(s.x.2);
                targets.extend(s.truth.iter().zip(&s.base).map(|(t, b)| (t - b) / HEIGHT_SCALE_M));
                bases.extend(s.base.iter().map(|b| (b - mean) / HEIGHT_SCALE_M));
                got += 1;
            }
        }
        if got == 0 {
            return Err("no NaN-free 32 m training window in any DEM".into());
        }
        Ok(GrowBatch { n: got, xs, n64s, n32s, targets, bases })
    }

    /// One optimiser step of both networks on `batch`. Returns the batch's L1 term before
    /// the step (units of [`HEIGHT_SCALE_M`]).
    pub fn fit(&mut self, batch: &GrowBatch) -> Result<f64, String> {
        let t0 = web_time::Instant::now();
        let (dev, w, got) = (&self.device, WINDOW, batch.n);
        let b = batch.clone();
        let residual = self.g.forward(tensor(b.xs, [got, 6, w, w], dev), tensor(b.n64s, [got, 1, 2 * w, 2 * w], dev), tensor(b.n32s, [got, 1, 4 * w, 4 * w], dev));
        let fake = residual.narrow(2, CORE_OFFSET, OUT_TILE).narrow(3, CORE_OFFSET, OUT_TILE);
        let target = tensor(b.targets, [got, 1, OUT_TILE, OUT_TILE], dev);
        let cond = tensor(b.bases, [got, 1, OUT_TILE, OUT_TILE], dev);
        let mut disc_v = 0.0;
        let mut adv_v = 0.0;
        if self.adversarial > 0.0 {
            let real_in = Tensor::cat(vec![target.clone() * DISC_RESIDUAL_GAIN, cond.clone()], 1);
            let fake_in = Tensor::cat(vec![fake.clone().detach() * DISC_RESIDUAL_GAIN, cond.clone()], 1);
            disc_v = gan::disc_step(&mut self.d, &mut self.od, self.lr * 0.5, real_in, fake_in, None);
        }
        let l1 = (fake.clone() - target).abs().mean();
        let l1_v = l1.clone().into_scalar::<f32>() as f64;
        let mut loss = l1 * L1_WEIGHT;
        if self.position > 0.0 {
            loss = loss + cell_position_gap(fake.clone() + cond.clone()) * self.position;
        }
        if self.adversarial > 0.0 {
            let adv = gan::gen_adversarial(&self.d, Tensor::cat(vec![fake * DISC_RESIDUAL_GAIN, cond], 1), None);
            adv_v = adv.clone().into_scalar::<f32>() as f64;
            loss = loss + adv * self.adversarial;
        }
        let gp = GradientsParams::from_grads(loss.backward(), &self.g);
        self.g = self.og.step(self.lr, self.g.clone(), gp);
        self.progress.record(l1_v, adv_v, disc_v, t0.elapsed().as_secs_f64());
        Ok(l1_v)
    }

    /// Saves the checkpoint in `dir`.
    pub fn save(&self, dir: &Path) -> Result<(), String> {
        let state = serde_json::json!({ "batch": self.batch, "adversarial": self.adversarial, "position": self.position, "lr": self.lr, "progress": self.progress });
        gan::save_run(dir, "grow", GROW_FILE, &self.g, &self.d, &self.og, &self.od, &state)
    }

    /// The network's parameter count.
    pub fn parameters(&self) -> usize {
        self.g.num_params()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ramp (every step 1) scores 0; a ramp whose steps across x are 2 on the cell borders
    /// and 1 inside the cells (across y all 1) scores the profile's mean |ratio − 1|: the 8
    /// values are 1 seven times and 2 once, mean 9/8, so (7 · 1/9 + 7/9) / 8 = 7/36.
    #[test]
    fn cell_position_gap_is_zero_for_even_steps_and_7_36_for_double_border_steps() {
        let n = OUT_TILE;
        let dev = Device::flex();
        let field = |f: &dyn Fn(usize, usize) -> f32| Tensor::<4>::from_data(TensorData::new((0..n * n).map(|p| f(p % n, p / n)).collect::<Vec<f32>>(), [1, 1, n, n]), &dev);
        let even = cell_position_gap(field(&|x, y| (x + y) as f32)).into_scalar::<f32>();
        assert!(even.abs() < 1e-5, "{even}");
        let striped = cell_position_gap(field(&|x, y| (x + x / FACTOR + y) as f32)).into_scalar::<f32>();
        assert!((striped - 7.0 / 36.0).abs() < 1e-4, "{striped}");
    }
}
