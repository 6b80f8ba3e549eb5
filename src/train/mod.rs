//! Training and evaluation of the TEM, and what every trainer shares: where it runs
//! ([`Backend`]: burn's CPU backend, or its wgpu backend on a GPU) and how long
//! ([`Budget`]). Native only, behind the `train` feature.
//!
//! Chained training as in the paper: a step runs `chain_levels` consecutive models, each on a
//! quadrant of the previous one's output, and minimises the sum of their L1 losses (heights in
//! units of 40 m) with one backward pass through the whole chain.

pub mod gan;
pub mod grow;
pub mod pairs;
pub mod sketch;
pub mod sketch_vae;
pub mod tcm;
pub mod world_eval;

use std::path::Path;

use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::store::{BurnpackStore, ModuleSnapshot};
use burn::tensor::{Device, Tensor, TensorData};

use crate::models::tem::{LEVEL_SPACING_M, LEVELS, Tem, level_scale_m};
use pairs::{Dem, MARGIN, PATCH, QUAD, Rng, Split, WINDOW, WorkingCache, chain_sample, finest_spacing};

/// Where a training runs. Both are burn backends with autodiff, so every trainer runs the same
/// code on either.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// burn's CPU backend (flex, SIMD kernels on all cores).
    #[default]
    Cpu,
    /// burn's wgpu backend on the machine's default adapter (natively Vulkan: a GPU's driver,
    /// or Mesa's lavapipe on a machine without one).
    Gpu,
}

impl Backend {
    /// The autodiff device of this backend. The GPU runtime comes up once per process (burn
    /// cannot register it twice); a machine without any Vulkan adapter is an error, not a
    /// panic.
    pub fn device(self) -> Result<Device, String> {
        match self {
            Backend::Cpu => Ok(Device::flex().autodiff()),
            Backend::Gpu => crate::models::native_gpu().map(Device::autodiff).map_err(|e| format!("no GPU for training: {e}")),
        }
    }

    /// What this backend runs on, for logs and the weights manifest: "cpu (N threads)" or the
    /// Vulkan adapters' names and drivers (the default one is among them).
    pub fn describe(self) -> String {
        match self {
            Backend::Cpu => format!("cpu ({} threads)", rayon::current_num_threads()),
            Backend::Gpu => {
                let names = vulkan_adapters();
                if names.is_empty() { "wgpu: no Vulkan adapter".into() } else { format!("wgpu on Vulkan: {}", names.join("; ")) }
            }
        }
    }
}

/// Name, type and driver of every Vulkan adapter of this machine.
pub fn vulkan_adapters() -> Vec<String> {
    use burn::tensor::wgpu::wgpu;
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor { backends: wgpu::Backends::VULKAN, ..wgpu::InstanceDescriptor::new_without_display_handle() });
    let adapters = block_on(instance.enumerate_adapters(wgpu::Backends::VULKAN));
    adapters
        .iter()
        .map(|a| {
            let i = a.get_info();
            format!("{} ({:?}, {} {})", i.name, i.device_type, i.driver, i.driver_info)
        })
        .collect()
}

/// Runs a future that needs no executor (wgpu's native adapter queries) to completion.
fn block_on<F: std::future::Future>(f: F) -> F::Output {
    let mut f = std::pin::pin!(f);
    let mut cx = std::task::Context::from_waker(std::task::Waker::noop());
    loop {
        if let std::task::Poll::Ready(v) = f.as_mut().poll(&mut cx) {
            return v;
        }
        std::thread::yield_now();
    }
}

/// A run's wall-clock budget: stop after `minutes`, save a checkpoint every
/// `checkpoint_minutes` (besides any step-count checkpoints of the trainer).
#[derive(Clone, Debug)]
pub struct Budget {
    start: web_time::Instant,
    last_save: web_time::Instant,
    /// Stop once this many seconds have passed (None: no limit).
    pub limit_s: Option<f64>,
    /// Save at least this often (seconds; None: only at the trainer's step counts).
    pub save_every_s: Option<f64>,
}

impl Budget {
    /// A budget from now: `minutes` of running, a checkpoint every `checkpoint_minutes`.
    /// Each must be a positive number of minutes where given.
    pub fn new(minutes: Option<f64>, checkpoint_minutes: Option<f64>) -> Result<Self, String> {
        for (flag, m) in [("--minutes", minutes), ("--checkpoint-minutes", checkpoint_minutes)] {
            if m.is_some_and(|m| !(m.is_finite() && m > 0.0)) {
                return Err(format!("{flag} must be a positive number of minutes, not {}", m.unwrap_or_default()));
            }
        }
        let now = web_time::Instant::now();
        Ok(Self { start: now, last_save: now, limit_s: minutes.map(|m| m * 60.0), save_every_s: checkpoint_minutes.map(|m| m * 60.0) })
    }

    /// Seconds since the budget started.
    pub fn elapsed_s(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }

    /// Whether the run has used up its time.
    pub fn spent(&self) -> bool {
        self.limit_s.is_some_and(|l| self.elapsed_s() >= l)
    }

    /// Whether a timed checkpoint is due now; if so the clock for the next one starts.
    pub fn save_due(&mut self) -> bool {
        let due = self.save_every_s.is_some_and(|e| self.last_save.elapsed().as_secs_f64() >= e);
        if due {
            self.last_save = web_time::Instant::now();
        }
        due
    }

    /// Whether a loop that stops when the budget is spent should save now: a timed
    /// checkpoint is due, or this is its last step.
    pub fn checkpoint_due(&mut self) -> bool {
        self.save_due() || self.spent()
    }
}

/// Settings of one training run.
#[derive(Clone, Debug)]
pub struct TrainConfig {
    /// Chained optimiser steps.
    pub steps: usize,
    /// Single-level fine-tuning steps after the chained ones, on real data wherever a DEM is
    /// fine enough for the level (levels cycle 0..5).
    pub finetune_steps: usize,
    /// Chains per step.
    pub batch: usize,
    /// Consecutive levels per chain (1..=5).
    pub chain_levels: usize,
    /// Adam learning rate (the last quarter of the chained steps and the fine-tuning use a
    /// third of it).
    pub lr: f64,
    /// Seed of the sampler.
    pub seed: u64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self { steps: 600, finetune_steps: 0, batch: 12, chain_levels: 3, lr: 1e-3, seed: 1 }
    }
}

/// Mean L1 loss per level (units of the level's height scale) over the last steps that
/// trained it.
pub type LevelLosses = [f64; LEVELS];

fn tensor(data: Vec<f32>, n: usize, side: usize, device: &Device) -> Tensor<4> {
    Tensor::<4>::from_data(TensorData::new(data, [n, 1, side, side]), device)
}

/// The core (PATCH², at offset 2·MARGIN) of a model's raw output [B, 1, 2·WINDOW, 2·WINDOW].
pub fn core(raw: Tensor<4>) -> Tensor<4> {
    raw.narrow(3, 2 * MARGIN, PATCH).narrow(2, 2 * MARGIN, PATCH)
}

/// Trains five models from `dems` (train split) on `device` (an autodiff device), starting
/// from `init` (e.g. the shipped weights, loaded onto `device`) or from random weights. `log`
/// gets (step, total loss, seconds so far, the models) and returns whether to go on. Returns
/// the models and the running loss per level.
pub fn train_tem(
    dems: &[Dem],
    cfg: &TrainConfig,
    device: &Device,
    init: Option<Vec<Tem>>,
    mut log: impl FnMut(usize, f64, f64, &[Tem]) -> bool,
) -> Result<(Vec<Tem>, LevelLosses), String> {
    let mut models: Vec<Tem> = match init {
        Some(m) if m.len() == LEVELS => m,
        Some(m) => return Err(format!("the TEM has {LEVELS} levels, not {}", m.len())),
        None => (0..LEVELS).map(|_| Tem::new(device)).collect(),
    };
    let mut optims: Vec<ModuleOptimizer> = (0..LEVELS).map(|_| AdamConfig::new().init()).collect();
    let mut cache = WorkingCache::default();
    let mut rng = Rng(cfg.seed);
    let chain = cfg.chain_levels.clamp(1, LEVELS);
    let mut running = [f64::NAN; LEVELS];
    let start = web_time::Instant::now();
    let (mut trained, mut skipped) = (0usize, 0usize);
    for step in 0..cfg.steps + cfg.finetune_steps {
        let finetune = step >= cfg.steps;
        let levels = if finetune { 1 } else { chain };
        let first = if finetune { (step - cfg.steps) % LEVELS } else { rng.below(LEVELS - levels + 1) };
        let quads: Vec<usize> = (1..levels).map(|_| rng.below(4)).collect();
        let spacing = finest_spacing(first, levels);
        // Candidate DEMs with room for the chain: real data four times as likely while
        // chained, only real data (where any fits) while fine-tuning.
        let mut candidates = Vec::new();
        for k in 0..dems.len() {
            let w = cache.get(dems, k, spacing);
            if pairs::fits(&w.hf, Split::Train, levels) {
                candidates.extend(std::iter::repeat_n((k, w.real), if w.real { 4 } else { 1 }));
            }
        }
        if finetune && candidates.iter().any(|c| c.1) {
            candidates.retain(|c| c.1);
        }
        if candidates.is_empty() {
            return Err(format!("no DEM is large enough for a {levels}-level chain at {spacing} m"));
        }
        let mut inputs = Vec::new();
        let mut truths: Vec<Vec<f32>> = vec![Vec::new(); levels];
        let mut got = 0;
        let mut tries = 0;
        while got < cfg.batch && tries < cfg.batch * 10 {
            tries += 1;
            let k = candidates[rng.below(candidates.len())].0;
            let w = cache.get(dems, k, spacing);
            if let Some(c) = chain_sample(&w.hf, Split::Train, levels, &quads, &mut rng) {
                inputs.extend(c.input);
                for (t, ct) in truths.iter_mut().zip(c.truth) {
                    t.extend(ct);
                }
                got += 1;
            }
        }
        if got == 0 {
            // Only no-data where this step's level looked (a real DEM that is NaN outside a
            // hull): the next step looks again, at its own level; a run that trains nothing fails.
            eprintln!("step {step}: no NaN-free window at {spacing} m in {tries} tries; skipped");
            skipped += 1;
            continue;
        }
        trained += 1;
        let batch = TemBatch { first, quads, n: got, inputs, truths };
        let lr = if finetune || step >= cfg.steps * 3 / 4 { cfg.lr / 3.0 } else { cfg.lr };
        let (total, per_level) = fit_tem(&mut models, &mut optims, &batch, lr, device);
        for (j, v) in per_level.into_iter().enumerate() {
            let r = &mut running[first + j];
            *r = if r.is_nan() { v } else { 0.95 * *r + 0.05 * v };
        }
        if !log(step, total, start.elapsed().as_secs_f64(), &models) {
            break;
        }
    }
    if trained == 0 && skipped > 0 {
        return Err(format!("could not cut any NaN-free training window in {skipped} steps"));
    }
    Ok((models, running))
}

/// The windows of one chained TEM step ([`train_tem`]): models `first`.. on `n` samples, each
/// later model on quadrant `quads[j]` of the previous one's output.
#[derive(Clone, Debug)]
pub struct TemBatch {
    /// The first model (level) of the chain.
    pub first: usize,
    /// The quadrant (0–3) each later level reads.
    pub quads: Vec<usize>,
    /// Samples in the batch.
    pub n: usize,
    /// The first level's inputs, [n, 1, WINDOW, WINDOW] (metres).
    pub inputs: Vec<f32>,
    /// Each level's true core, [n, 1, PATCH, PATCH] (metres).
    pub truths: Vec<Vec<f32>>,
}

/// One optimiser step at learning rate `lr` of the chained models that `batch` trains (the
/// sum of their L1 losses, heights in units of each level's scale, one backward pass).
/// Returns that sum and each level's term, before the step.
pub fn fit_tem(models: &mut [Tem], optims: &mut [ModuleOptimizer], batch: &TemBatch, lr: f64, device: &Device) -> (f64, Vec<f64>) {
    let (first, levels, n) = (batch.first, batch.truths.len(), batch.n);
    let mut x = tensor(batch.inputs.clone(), n, WINDOW, device);
    let mut loss: Option<Tensor<1>> = None;
    let mut per_level = Vec::new();
    for (j, truth) in batch.truths.iter().enumerate() {
        let level = first + j;
        let raw = models[level].forward(x, level_scale_m(level));
        let gt = tensor(truth.clone(), n, PATCH, device);
        let l = (core(raw.clone()) - gt).abs().mean() / level_scale_m(level);
        per_level.push(l.clone());
        loss = Some(match loss {
            Some(acc) => acc + l,
            None => l,
        });
        // The next level reads its quadrant of this core with the margin around it.
        if j + 1 < levels {
            let q = batch.quads[j];
            x = raw.narrow(3, MARGIN + (q % 2) * QUAD, WINDOW).narrow(2, MARGIN + (q / 2) * QUAD, WINDOW);
        } else {
            x = raw;
        }
    }
    drop(x);
    let loss = loss.expect("at least one level");
    let total = loss.clone().into_scalar::<f32>() as f64;
    let per_level = per_level.into_iter().map(|l| l.into_scalar::<f32>() as f64).collect();
    let mut grads = loss.backward();
    for j in first..first + levels {
        let gp = GradientsParams::from_module(&mut grads, &models[j]);
        models[j] = optims[j].step(lr, models[j].clone(), gp);
    }
    (total, per_level)
}

pub use crate::models::tem::weight_file;

/// Saves the five models as burnpack files in `dir`.
pub fn save_models(models: &[Tem], dir: &Path) -> Result<(), String> {
    std::fs::create_dir_all(dir).map_err(|e| e.to_string())?;
    for (k, m) in models.iter().enumerate() {
        let mut store = BurnpackStore::from_file(dir.join(weight_file(k))).overwrite(true);
        m.save_into(&mut store).map_err(|e| format!("saving {}: {e:?}", weight_file(k)))?;
    }
    Ok(())
}

/// Loads the five models from burnpack files in `dir` onto `device`.
pub fn load_models(dir: &Path, device: &Device) -> Result<Vec<Tem>, String> {
    Ok(crate::models::tem::load_models(dir, device)?)
}

/// Accuracy of one level on held-out windows.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct LevelEval {
    /// Level (0 = 32 → 16 m).
    pub level: usize,
    /// Output spacing (metres).
    pub spacing_m: f64,
    /// Whether the windows are real data at this spacing (else self-similar coarse data).
    pub real: bool,
    /// Windows evaluated.
    pub windows: usize,
    /// RMSE of bicubic upsampling (metres).
    pub rmse_bicubic: f64,
    /// RMSE of the TEM (metres).
    pub rmse_tem: f64,
    /// PSNR of bicubic (dB; peak = the window's height range).
    pub psnr_bicubic: f64,
    /// PSNR of the TEM (dB).
    pub psnr_tem: f64,
    /// TEM RMSE (metres) by distance to the edge of the refined quad: [0,1), [1,2), [2,4), [4,8), [8,16), [16,64) px.
    pub rmse_by_edge_distance: [f64; 6],
}

fn edge_bucket(x: usize, y: usize, n: usize) -> usize {
    edge_bucket_distance(x.min(y).min(n - 1 - x).min(n - 1 - y))
}

/// Evaluates every level one at a time on the validation split: up to `max_windows` windows
/// per level, real data where any DEM is fine enough for that level, else self-similar.
pub fn eval_levels(models: &[Tem], dems: &[Dem], device: &Device, max_windows: usize) -> Vec<LevelEval> {
    let mut cache = WorkingCache::default();
    let mut out = Vec::new();
    for level in 0..LEVELS {
        let spacing = LEVEL_SPACING_M[level];
        let any_real = (0..dems.len()).any(|k| {
            let w = cache.get(dems, k, spacing);
            w.real && pairs::fits(&w.hf, Split::Validation, 1)
        });
        let mut rng = Rng(1000 + level as u64);
        let mut inputs = Vec::new();
        let mut truths = Vec::new();
        'dems: for k in 0..dems.len() {
            let w = cache.get(dems, k, spacing);
            if w.real != any_real || !pairs::fits(&w.hf, Split::Validation, 1) {
                continue;
            }
            for _ in 0..(max_windows / 4).max(1) {
                if truths.len() >= max_windows {
                    break 'dems;
                }
                if let Some(c) = chain_sample(&w.hf, Split::Validation, 1, &[], &mut rng) {
                    inputs.push(c.input);
                    truths.push(c.truth.into_iter().next().expect("one level"));
                }
            }
        }
        let mut e = LevelEval { level, spacing_m: spacing, real: any_real, windows: truths.len(), ..Default::default() };
        if truths.is_empty() {
            out.push(e);
            continue;
        }
        let n = truths.len();
        let y = core(models[level].forward(tensor(inputs.concat(), n, WINDOW, device), level_scale_m(level)));
        let y: Vec<f32> = y.into_data().try_to_vec::<f32>().expect("f32 output");
        let (mut se_t, mut se_b, mut psnr_t, mut psnr_b) = (0f64, 0f64, 0f64, 0f64);
        let mut edge = [(0f64, 0usize); 6];
        for (i, (inp, gt)) in inputs.iter().zip(&truths).enumerate() {
            let bic = crate::dem::Heightfield::new(WINDOW, WINDOW, spacing * 2.0, inp.clone()).upsample_bicubic2().window(2 * MARGIN, 2 * MARGIN, PATCH, PATCH);
            let tem = &y[i * PATCH * PATCH..(i + 1) * PATCH * PATCH];
            let (mut st, mut sb) = (0f64, 0f64);
            for (p, g) in gt.iter().enumerate() {
                let dt = (tem[p] - g) as f64;
                st += dt * dt;
                sb += ((bic.data[p] - g) as f64).powi(2);
                let b = edge_bucket(p % PATCH, p / PATCH, PATCH);
                edge[b].0 += dt * dt;
                edge[b].1 += 1;
            }
            let range = gt.iter().fold(f32::MIN, |a, &b| a.max(b)) - gt.iter().fold(f32::MAX, |a, &b| a.min(b));
            let np = (PATCH * PATCH) as f64;
            psnr_t += 20.0 * (range.max(1e-3) as f64 / (st / np).sqrt().max(1e-9)).log10();
            psnr_b += 20.0 * (range.max(1e-3) as f64 / (sb / np).sqrt().max(1e-9)).log10();
            se_t += st;
            se_b += sb;
        }
        let total = (n * PATCH * PATCH) as f64;
        e.rmse_tem = (se_t / total).sqrt();
        e.rmse_bicubic = (se_b / total).sqrt();
        e.psnr_tem = psnr_t / n as f64;
        e.psnr_bicubic = psnr_b / n as f64;
        for (slot, (s, c)) in e.rmse_by_edge_distance.iter_mut().zip(edge) {
            *slot = (s / c.max(1) as f64).sqrt();
        }
        out.push(e);
    }
    out
}

/// Accuracy of the chained ladder (the `terrain enhance` path) at one output level.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct ChainEval {
    /// Which data: "real" or "self-similar" and where from.
    pub data: String,
    /// Input spacing (metres).
    pub input_m: f64,
    /// Output spacing (metres).
    pub output_m: f64,
    /// Windows evaluated.
    pub windows: usize,
    /// RMSE of direct bicubic upsampling of the input by the same factor (metres).
    pub rmse_bicubic: f64,
    /// RMSE of the chained TEM (metres).
    pub rmse_tem: f64,
    /// PSNR of bicubic (dB; peak = the window's height range).
    pub psnr_bicubic: f64,
    /// PSNR of the chained TEM (dB).
    pub psnr_tem: f64,
    /// TEM RMSE (metres) by distance (output px) to the nearest refined-quad edge: [0,1),
    /// [1,2), [2,4), [4,8), [8,16), [16,64); pixels within 16 px of the window border left out.
    pub rmse_by_quad_edge_distance: [f64; 6],
    /// Seam ratio: mean |height step| between neighbouring pixels across quad edges divided by
    /// the mean step elsewhere (1 = the edges are invisible).
    pub seam_ratio: f64,
    /// The same ratio for direct bicubic upsampling of the same input (its baseline).
    pub seam_ratio_bicubic: f64,
    /// The same ratio for the ground truth (what real terrain gives on those pixel columns).
    pub seam_ratio_truth: f64,
}

/// Sums of |height step| between horizontal neighbours of `hf` across quad edges (x + 1 a
/// multiple of PATCH) and elsewhere: ((sum, count) across, (sum, count) elsewhere).
fn seam_steps(hf: &crate::dem::Heightfield, acc: &mut [(f64, usize); 2]) {
    for y in 0..hf.height {
        for x in 0..hf.width.saturating_sub(1) {
            let step = (hf.at(x + 1, y) - hf.at(x, y)).abs() as f64;
            let slot = &mut acc[if (x + 1) % PATCH == 0 { 0 } else { 1 }];
            slot.0 += step;
            slot.1 += 1;
        }
    }
}

/// Mean step across quad edges over the mean step elsewhere.
fn seam_ratio(acc: &[(f64, usize); 2]) -> f64 {
    if acc[0].1 == 0 { f64::NAN } else { (acc[0].0 / acc[0].1 as f64) / (acc[1].0 / acc[1].1.max(1) as f64).max(1e-12) }
}

/// Evaluates the chained TEM through [`crate::enhance::enhance`] on square `windows` (metres at
/// the finest spacing `finest_m`; no NaN): each window is box-averaged to `input_m`, enhanced
/// level by level, and compared at every output spacing with the window box-averaged to it.
pub fn eval_chained(tem: &crate::models::tem::TemSet, windows: &[crate::dem::Heightfield], input_m: f64, data: &str) -> Result<Vec<ChainEval>, String> {
    use crate::dem::Heightfield;
    let Some(first_window) = windows.first() else { return Ok(Vec::new()) };
    let finest_m = first_window.spacing_m;
    let levels = (input_m / finest_m).log2().round() as usize;
    let mut rows = Vec::new();
    for n in 1..=levels {
        let output_m = input_m / (1u64 << n) as f64;
        let mut e = ChainEval { data: data.into(), input_m, output_m, windows: windows.len(), ..Default::default() };
        let (mut se_t, mut se_b, mut count) = (0f64, 0f64, 0usize);
        let mut edge = [(0f64, 0usize); 6];
        let mut seams = [[(0f64, 0usize); 2]; 3];
        for w in windows {
            let down = |hf: &Heightfield, times: usize| (0..times).fold(hf.clone(), |a, _| a.downsample2());
            let input = down(w, levels);
            let truth = down(w, levels - n);
            let (out, _) = crate::enhance::enhance(&input, input_m, output_m, tem, 8, &mut |_, _, _| ()).map_err(|e| e.to_string())?;
            let bic = input.upsample_bicubic(1 << n);
            let side = truth.width;
            let (mut st, mut sb) = (0f64, 0f64);
            for y in 0..side {
                for x in 0..side {
                    let g = truth.at(x, y) as f64;
                    let dt = out.at(x, y) as f64 - g;
                    st += dt * dt;
                    sb += (bic.at(x, y) as f64 - g).powi(2);
                    // Distance to the nearest quad edge inside the window; pixels near the
                    // window's own border (replicated context) are left out.
                    let border = x.min(y).min(side - 1 - x).min(side - 1 - y);
                    if border >= 16 {
                        let d = |v: usize| (v % PATCH).min(PATCH - 1 - v % PATCH);
                        let b = edge_bucket_distance(d(x).min(d(y)));
                        edge[b].0 += dt * dt;
                        edge[b].1 += 1;
                    }
                }
            }
            seam_steps(&out, &mut seams[0]);
            seam_steps(&bic, &mut seams[1]);
            seam_steps(&truth, &mut seams[2]);
            let range = truth.data.iter().fold(f32::MIN, |a, &b| a.max(b)) - truth.data.iter().fold(f32::MAX, |a, &b| a.min(b));
            let np = (side * side) as f64;
            e.psnr_tem += 20.0 * (range.max(1e-3) as f64 / (st / np).sqrt().max(1e-9)).log10() / windows.len() as f64;
            e.psnr_bicubic += 20.0 * (range.max(1e-3) as f64 / (sb / np).sqrt().max(1e-9)).log10() / windows.len() as f64;
            se_t += st;
            se_b += sb;
            count += side * side;
        }
        e.rmse_tem = (se_t / count as f64).sqrt();
        e.rmse_bicubic = (se_b / count as f64).sqrt();
        for (slot, (s, c)) in e.rmse_by_quad_edge_distance.iter_mut().zip(edge) {
            *slot = if c == 0 { f64::NAN } else { (s / c as f64).sqrt() };
        }
        e.seam_ratio = seam_ratio(&seams[0]);
        e.seam_ratio_bicubic = seam_ratio(&seams[1]);
        e.seam_ratio_truth = seam_ratio(&seams[2]);
        rows.push(e);
    }
    Ok(rows)
}

fn edge_bucket_distance(d: usize) -> usize {
    match d {
        0 => 0,
        1 => 1,
        2..=3 => 2,
        4..=7 => 3,
        8..=15 => 4,
        _ => 5,
    }
}

/// Up to `per_dem` NaN-free square windows of side `side` from the validation split of every
/// grid in `grids` (stacked down the rows).
pub fn validation_windows(grids: &[&crate::dem::Heightfield], side: usize, per_dem: usize) -> Vec<crate::dem::Heightfield> {
    let mut out = Vec::new();
    for g in grids {
        let (c0, c1) = pairs::split_columns(g.width, Split::Validation);
        if c1 < c0 + side || g.height < side {
            continue;
        }
        let mut got = 0;
        let mut y = 0;
        while y + side <= g.height && got < per_dem {
            let w = g.window(c0, y, side, side);
            if w.data.iter().all(|v| !v.is_nan()) {
                out.push(w);
                got += 1;
            }
            y += side;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dem::Heightfield;

    /// The GPU path trains the TEM like the CPU path: the same random start (saved, then
    /// loaded onto each backend), two chained steps on burn's wgpu backend (lavapipe here)
    /// and on its CPU backend. The first step's loss (the same weights on the same windows)
    /// agrees to 1e-5 of itself, the second's (after one Adam update) to 1e-4 (1e-7 was
    /// measured), and the two steps' losses differ by more than 1 % (2 % measured). Only two
    /// steps: from the third on, this random start's losses vary by ~20 % from run to run
    /// even on the CPU backend alone (Adam moves weights with near-zero gradients by about
    /// the learning rate, whatever their sign, and the CPU backend's parallel sums are not
    /// bit-reproducible), so later steps cannot be compared.
    #[test]
    fn gpu_and_cpu_backends_train_the_same_two_tem_steps() {
        let (w, h) = (900, 400);
        let field = |x: f32, y: f32| (x * 0.031).sin() * 40.0 + (y * 0.047 + x * 0.011).cos() * 25.0 + ((x * 0.17).sin() * (y * 0.13).cos()) * 6.0;
        let dems = vec![Dem { id: "synthetic".into(), hf: crate::dem::Heightfield::new(w, h, 100.0, (0..w * h).map(|k| field((k % w) as f32, (k / w) as f32)).collect()) }];
        let cfg = TrainConfig { steps: 2, finetune_steps: 0, batch: 2, chain_levels: 2, lr: 1e-3, seed: 5 };
        let dir = std::env::temp_dir().join(format!("terrain-tem-backends-{}", std::process::id()));
        save_models(&(0..LEVELS).map(|_| Tem::new(&Device::flex())).collect::<Vec<_>>(), &dir).unwrap();
        let train = |backend: Backend| {
            let device = backend.device().unwrap();
            let mut losses = Vec::new();
            train_tem(&dems, &cfg, &device, Some(load_models(&dir, &device).unwrap()), |_, loss, _, _| {
                losses.push(loss);
                true
            })
            .unwrap();
            losses
        };
        let (gpu, cpu) = (train(Backend::Gpu), train(Backend::Cpu));
        let rel = |a: f64, b: f64| (a - b).abs() / b.abs();
        eprintln!("TEM losses: gpu {gpu:?}, cpu {cpu:?}");
        assert_eq!(gpu.len(), 2);
        assert!(rel(gpu[0], cpu[0]) < 1e-5, "first step: {} vs {}", gpu[0], cpu[0]);
        assert!(rel(gpu[1], cpu[1]) < 1e-4, "second step: {} vs {}", gpu[1], cpu[1]);
        assert!(rel(cpu[1], cpu[0]) > 0.01, "the steps did not change the loss: {cpu:?}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A real DEM that is no data everywhere (as the North Tyrol DEMs are outside their
    /// hulls, at some level) no longer stops a run: with a good coarse DEM beside it, the
    /// steps where the only candidate is the empty DEM are skipped and the others train (1
    /// chained + some of the 5 fine-tuning steps); with the empty DEM alone, the run fails
    /// with the reason.
    #[test]
    fn steps_with_no_clean_window_are_skipped_and_a_run_that_trains_nothing_fails() {
        let (w, h) = (900, 400);
        let field = |x: f32, y: f32| (x * 0.031).sin() * 40.0 + (y * 0.047 + x * 0.011).cos() * 25.0;
        let good = Dem { id: "synthetic".into(), hf: Heightfield::new(w, h, 100.0, (0..w * h).map(|k| field((k % w) as f32, (k / w) as f32)).collect()) };
        let empty = || Dem { id: "no data".into(), hf: Heightfield::new(700, 700, 1.0, vec![f32::NAN; 700 * 700]) };
        let cfg = TrainConfig { steps: 1, finetune_steps: 5, batch: 1, chain_levels: 2, lr: 1e-3, seed: 5 };
        let device = Device::flex().autodiff();
        let mut logged = 0;
        let run = train_tem(&[good, empty()], &cfg, &device, None, |_, _, _, _| {
            logged += 1;
            true
        });
        assert!(run.is_ok(), "{:?}", run.err());
        assert!((2..6).contains(&logged), "{logged} steps trained");
        let large_empty = Dem { id: "no data".into(), hf: Heightfield::new(1400, 1000, 5.0, vec![f32::NAN; 1400 * 1000]) };
        let err = train_tem(&[large_empty], &TrainConfig { steps: 0, finetune_steps: 2, ..cfg }, &device, None, |_, _, _, _| true).map(|_| ()).unwrap_err();
        assert_eq!(err, "could not cut any NaN-free training window in 2 steps");
    }

    /// A short real run of the whole training path on synthetic terrain: losses are finite,
    /// the saved weights load back to a model whose outputs are the trained model's (within
    /// 1e-5 m) and not a fresh one's.
    #[test]
    fn smoke_training_runs_saves_and_reloads() {
        // 900×400 at 100 m: coarser than every level, so used self-similarly at native size.
        let (w, h) = (900, 400);
        let field = |x: f32, y: f32| (x * 0.031).sin() * 40.0 + (y * 0.047 + x * 0.011).cos() * 25.0 + ((x * 0.17).sin() * (y * 0.13).cos()) * 6.0;
        let hf = Heightfield::new(w, h, 100.0, (0..w * h).map(|k| field((k % w) as f32, (k / w) as f32)).collect());
        let dems = vec![Dem { id: "synthetic".into(), hf }];
        let cfg = TrainConfig { steps: 1, finetune_steps: 1, batch: 1, chain_levels: 2, lr: 1e-3, seed: 5 };
        let device = Device::flex().autodiff();
        let mut steps = 0;
        let (models, losses) = train_tem(&dems, &cfg, &device, None, |_, loss, _, _| {
            assert!(loss.is_finite());
            steps += 1;
            true
        })
        .unwrap();
        assert_eq!(steps, 2);
        assert!(losses.iter().any(|l| l.is_finite()));
        let dir = std::env::temp_dir().join(format!("terrain-tem-smoke-{}", std::process::id()));
        save_models(&models, &dir).unwrap();
        let plain = Device::flex();
        let back = load_models(&dir, &plain).unwrap();
        let data = || (0..64 * 64).map(|k| ((k % 64) as f32 * 0.3).sin() * 5.0 + (k / 64) as f32 * 0.2).collect::<Vec<f32>>();
        let input = || tensor(data(), 1, 64, &plain);
        let a: Vec<f32> = back[1].forward(input(), 20.0).into_data().try_to_vec::<f32>().unwrap();
        let trained: Vec<f32> = models[1].forward(tensor(data(), 1, 64, &device), 20.0).into_data().try_to_vec::<f32>().unwrap();
        let worst = a.iter().zip(&trained).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
        assert!(worst <= 1e-5, "the reloaded model differs from the trained one by up to {worst} m");
        let fresh: Vec<f32> = Tem::new(&plain).forward(input(), 20.0).into_data().try_to_vec::<f32>().unwrap();
        assert_ne!(a, fresh, "loaded weights must differ from a fresh initialisation");
    }

    /// The TEM trainer learns: on one fixed batch (two 2-level chain samples of a synthetic
    /// DEM, a seeded start), twelve steps at learning rate 1e-3 lower the chain's L1 sum to
    /// under 70 % of the first step's.
    #[test]
    fn twelve_steps_on_one_fixed_batch_lower_the_tem_loss_below_70_percent() {
        let (w, h) = (900, 400);
        let field = |x: f32, y: f32| (x * 0.031).sin() * 40.0 + (y * 0.047 + x * 0.011).cos() * 25.0 + ((x * 0.17).sin() * (y * 0.13).cos()) * 6.0;
        let hf = Heightfield::new(w, h, 100.0, (0..w * h).map(|k| field((k % w) as f32, (k / w) as f32)).collect());
        let device = Device::flex().autodiff();
        let mut models: Vec<Tem> = (0..LEVELS).map(|k| Tem::seeded(&device, 10 + k as u64, 0.05)).collect();
        let mut optims: Vec<ModuleOptimizer> = (0..LEVELS).map(|_| AdamConfig::new().init()).collect();
        let (mut rng, quads) = (Rng(5), vec![1]);
        let (mut inputs, mut truths) = (Vec::new(), vec![Vec::new(); 2]);
        for _ in 0..2 {
            let c = chain_sample(&hf, Split::Train, 2, &quads, &mut rng).expect("a window");
            inputs.extend(c.input);
            for (t, ct) in truths.iter_mut().zip(c.truth) {
                t.extend(ct);
            }
        }
        let batch = TemBatch { first: 0, quads, n: 2, inputs, truths };
        let losses: Vec<f64> = (0..12).map(|_| fit_tem(&mut models, &mut optims, &batch, 1e-3, &device).0).collect();
        eprintln!("fixed-batch TEM loss {losses:.5?}");
        assert!(losses[11] < 0.7 * losses[0], "TEM loss {losses:?}");
    }

    /// The shipped TEM beats bicubic at every output spacing on DEMs it was never trained
    /// on (the North Tyrol DEMs arrived after its training): the 1 m lidar tile refined from
    /// 8 m to 4, 2 and 1 m, and the 5 m DEMs area-averaged to 8 m, refined from 32 m to 16
    /// and 8 m (NaN-free windows, through the `enhance` path).
    #[test]
    fn the_shipped_tem_beats_bicubic_on_dems_it_never_saw() {
        let root = crate::repo_root();
        let tem = crate::models::tem::TemSet::load_dir(&root.join("weights"), &crate::models::tem::Exec::cpu()).unwrap();
        let dem = |id: &str| Heightfield::read_path(&root.join(format!("../shared/dem/{id}.tif")), None, crate::dem::PngScale::default()).unwrap();
        let lidar = dem("avaframe_pfa_1m");
        let five: Vec<Heightfield> = ["avaframe_alr_5m", "avaframe_gar_5m", "avaframe_hit_5m", "avaframe_kot_5m", "avaframe_mal_5m", "avaframe_wog_5m"]
            .iter()
            .map(|id| dem(id).resample_area(8.0).unwrap())
            .collect();
        // Every DEM here is held out whole: NaN-free windows from anywhere in it.
        let windows = |grids: &[&Heightfield], side: usize, per: usize| -> Vec<Heightfield> {
            let mut out = Vec::new();
            for g in grids {
                let all = (0..g.height / side).flat_map(|j| (0..g.width / side).map(move |i| (i * side, j * side)));
                out.extend(all.map(|(x, y)| g.window(x, y, side, side)).filter(|w| w.data.iter().all(|v| !v.is_nan())).take(per));
            }
            out
        };
        let mut rows = eval_chained(&tem, &windows(&[&lidar], 128, 4), 8.0, "1 m lidar").unwrap();
        rows.extend(eval_chained(&tem, &windows(&five.iter().collect::<Vec<_>>(), 64, 2), 32.0, "5 m as 8 m").unwrap());
        for r in &rows {
            eprintln!("{} {} → {} m, {} windows: RMSE TEM {:.3} m, bicubic {:.3} m", r.data, r.input_m, r.output_m, r.windows, r.rmse_tem, r.rmse_bicubic);
        }
        assert_eq!(rows.len(), 5, "three output spacings of the lidar, two of the 5 m DEMs");
        assert!(rows.iter().all(|r| r.windows >= 1 && r.rmse_tem < r.rmse_bicubic), "the TEM is not better than bicubic everywhere");
    }
}
