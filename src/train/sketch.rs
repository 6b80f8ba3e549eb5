//! Training the sketch generator ([`crate::models::sketch`]) on the CPU: sketch/terrain pairs
//! made by the project's extractor ([`crate::sketch::extract`]) from windows of real DEMs at
//! several scales (32 to 512 samples, brought to 256² by bicubic upsampling or area
//! averaging; optionally only windows up to a ground extent, e.g. near the sketch format's
//! 512 m tiles), the 8 rotations/flips, random crops; loss L1 + a small PatchGAN (least squares)
//! that sees the heights beside the sketch, as pix2pix. Checkpoints let a run resume in a later
//! session; the validation set is the held-out east third of every DEM.

use std::path::Path;

use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::tensor::{Device, Tensor, TensorData};

use super::gan::{self, Disc};
use super::pairs::{Dem, Rng, Split, fits_square, random_window};
use super::tcm::TcmProgress as Progress;
use crate::dem::{Heightfield, dihedral, dihedral_channels};
use crate::models::sketch::{IN_CHANNELS, SketchGen, SketchGenCpu, SketchScratch, WEIGHT_FILE, assemble_input};
use crate::sketch::{SKETCH_PX, Sketch, calibrate, extract, score};

/// Source window sides (samples) a pair is cut at, before they are brought to [`SKETCH_PX`].
pub const WINDOW_SIDES: [usize; 5] = [32, 64, 128, 256, 512];
/// Least height range (metres) of a window to make a pair from (flatter ones are mostly
/// quantisation steps once stretched to 0–255).
pub const MIN_RELIEF_M: f32 = 20.0;

/// One training pair: the generator's input and the target heights / 255.
#[derive(Clone)]
pub struct Pair {
    /// [`IN_CHANNELS`] × [`SKETCH_PX`]², channel-first.
    pub input: Vec<f32>,
    /// Target heights / 255 ([`SKETCH_PX`]²).
    pub target: Vec<f32>,
}

/// Which windows pairs are cut from: the DEMs (by manifest id; every DEM if empty) and the
/// range of a window's ground extent (metres; unbounded where `None`); and the share of
/// training pairs whose sketch is redrawn as a person would draw it ([`HAND_DRAWN_RANGE`]).
/// A run's checkpoint stores its fields beside the other settings ([`SketchConfig::windows`]).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct WindowChoice {
    /// Manifest ids of the DEMs drawn from; empty: all.
    #[serde(default)]
    pub dems: Vec<String>,
    /// Least ground extent of a window (metres).
    #[serde(default)]
    pub min_extent_m: Option<f64>,
    /// Largest ground extent of a window (metres).
    #[serde(default)]
    pub max_extent_m: Option<f64>,
    /// Share (0–1) of the training split's pairs whose sketch is redrawn by
    /// [`extract::hand_drawn`] with a random style from [`HAND_DRAWN_RANGE`] (validation
    /// pairs never are).
    #[serde(default)]
    pub hand_drawn: f32,
}

/// The ranges a redrawn training sketch's style is drawn from, uniformly
/// ([`extract::HandDrawn`]; each field a (low, high) pair): band borders smoothed by 3–12 px
/// (the authors' and the page's sketches have borders smoother than the terrain's contours),
/// strokes by 0–2 px, and 40–100 % of the ridge and valley pieces kept.
pub const HAND_DRAWN_RANGE: [(f32, f32); 3] = [(3.0, 12.0), (0.0, 2.0), (0.4, 1.0)];

impl WindowChoice {
    /// Every window of every DEM.
    pub const ALL: Self = Self { dems: Vec::new(), min_extent_m: None, max_extent_m: None, hand_drawn: 0.0 };

    /// Whether a window `side` samples wide at `spacing_m` has an extent in range.
    fn extent_fits(&self, side: usize, spacing_m: f64) -> bool {
        let e = side as f64 * spacing_m;
        self.min_extent_m.is_none_or(|m| e >= m) && self.max_extent_m.is_none_or(|m| e <= m)
    }
}

/// A pair cut from a random window of one of `dems` in `split` that `choice` allows; `None` if
/// the drawn window did not fit, had no-data or was too flat, or the DEM drawn has no window
/// of an allowed extent (or none of `dems` is allowed).
pub fn random_pair(dems: &[Dem], split: Split, choice: &WindowChoice, rng: &mut Rng) -> Option<Pair> {
    let allowed: Vec<&Dem> = dems.iter().filter(|d| choice.dems.is_empty() || choice.dems.contains(&d.id)).collect();
    if allowed.is_empty() {
        return None;
    }
    let hf = &allowed[rng.below(allowed.len())].hf;
    let sides: Vec<usize> = WINDOW_SIDES.iter().copied().filter(|&s| choice.extent_fits(s, hf.spacing_m) && fits_square(hf, split, s)).collect();
    if sides.is_empty() {
        return None;
    }
    let side = sides[rng.below(sides.len())];
    let win = random_window(hf, split, side, rng)?;
    let (lo, hi) = win.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    if hi - lo < MIN_RELIEF_M {
        return None;
    }
    let grid = Heightfield::new(side, side, hf.spacing_m, win);
    let heights = match side {
        s if s < SKETCH_PX => grid.upsample_bicubic(SKETCH_PX / s).data,
        s if s > SKETCH_PX => grid.resample_area(hf.spacing_m * (s / SKETCH_PX) as f64).ok()?.data,
        _ => grid.data,
    };
    let e = extract::extract(&heights)?;
    let per_mille = (choice.hand_drawn.clamp(0.0, 1.0) * 1000.0).round() as usize;
    let sketch = if split == Split::Train && rng.below(1000) < per_mille {
        let mut uniform = |(lo, hi): (f32, f32)| lo + (hi - lo) * rng.below(1001) as f32 / 1000.0;
        let [b, s, k] = HAND_DRAWN_RANGE;
        let style = extract::HandDrawn { band_sigma_px: uniform(b), stroke_sigma_px: uniform(s), keep_strokes: uniform(k) };
        extract::hand_drawn(&e, &style, |_| rng.below(1000) as f32 / 1000.0)
    } else {
        e.sketch
    };
    let (input, _) = assemble_input(&sketch, side as f64 * hf.spacing_m);
    Some(Pair { input, target: e.target.iter().map(|v| v / 255.0).collect() })
}

/// Pairs in the sketch format's own files (512×256 PNG: sketch | 8-bit DEM, e.g. the sketch
/// authors' pairs) in `dir`, skipping files whose name contains any of `exclude` (a held-out
/// area); each in all 8 rotations/flips when `augment`. Returns the pairs and the file names
/// read.
pub fn format_pairs(dir: &Path, exclude: &[String], augment: bool) -> Result<(Vec<Pair>, Vec<String>), String> {
    let mut files: Vec<std::path::PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x.eq_ignore_ascii_case("png")))
        .collect();
    files.sort();
    let (mut out, mut names) = (Vec::new(), Vec::new());
    let n = SKETCH_PX;
    for f in files {
        let name = f.file_name().map(|s| s.to_string_lossy().to_string()).unwrap_or_default();
        if exclude.iter().any(|x| name.contains(x.as_str())) {
            continue;
        }
        let file = std::fs::File::open(&f).map_err(|e| format!("{}: {e}", f.display()))?;
        let (sketch, dem) = crate::sketch::read_pair(std::io::BufReader::new(file)).map_err(|e| format!("{}: {e}", f.display()))?;
        let (input, _) = assemble_input(&sketch, crate::models::sketch::FORMAT_EXTENT_M);
        let target: Vec<f32> = dem.iter().map(|v| v / 255.0).collect();
        for t in 0..if augment { 8 } else { 1 } {
            let input = dihedral_channels(&input, n, t);
            out.push(Pair { input, target: dihedral(&target, n, t) });
        }
        names.push(name);
    }
    Ok((out, names))
}

/// `n` pairs from `split` (windows `choice` allows, see [`random_pair`]), drawn with a
/// sampler seeded by `seed`, made on every core.
pub fn pairs(dems: &[Dem], split: Split, n: usize, choice: &WindowChoice, seed: u64) -> Vec<Pair> {
    let threads = crate::models::cpu::default_threads().max(1);
    let per = n.div_ceil(threads);
    let mut out: Vec<Pair> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|t| {
                s.spawn(move || {
                    let mut rng = Rng(seed ^ (t as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
                    let mut v = Vec::new();
                    let mut tries = 0;
                    while v.len() < per && tries < per * 50 {
                        tries += 1;
                        if let Some(p) = random_pair(dems, split, choice, &mut rng) {
                            v.push(p);
                        }
                    }
                    v
                })
            })
            .collect();
        handles.into_iter().flat_map(|h| h.join().unwrap_or_default()).collect()
    });
    out.truncate(n);
    out
}

/// Settings of a sketch training run.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct SketchConfig {
    /// Crops per step.
    pub batch: usize,
    /// Side of the square crops trained on (divisible by 16).
    pub crop: usize,
    /// Pairs kept in memory; a few are replaced by fresh ones every step.
    pub pool: usize,
    /// Adam learning rate of the generator (the discriminator's is half).
    pub lr: f64,
    /// Weight of the adversarial term against L1 (pix2pix: 1/100).
    pub adversarial: f32,
    /// Seed of the sampler.
    pub seed: u64,
    /// The DEMs and window extents trained (and validated) on.
    #[serde(flatten)]
    pub windows: WindowChoice,
    /// Folder of pairs in the format's own files trained on beside the extracted ones (see
    /// [`format_pairs`]); `None`: extracted pairs only.
    #[serde(default)]
    pub format_pairs: Option<std::path::PathBuf>,
    /// Files of [`Self::format_pairs`] whose name contains one of these are held out.
    #[serde(default)]
    pub format_exclude: Vec<String>,
    /// Share (0–1) of each batch's crops taken from [`Self::format_pairs`].
    #[serde(default)]
    pub format_share: f32,
    /// The per-pixel term the generator minimises beside the adversarial one.
    #[serde(default)]
    pub loss: PixelLoss,
}

/// The per-pixel term of the generator's loss, on heights normalised to 0–1 (`terrain
/// train-sketch --loss l1|l2|band-l1`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum PixelLoss {
    /// Mean absolute error (pix2pix): its optimum is the conditional median.
    #[default]
    L1,
    /// Mean squared error: its optimum is the conditional mean, the answer of least expected
    /// RMSE (the format's score) where a sketch leaves the terrain open.
    L2,
    /// Mean absolute error of the output put on the format's scale by its bands, as the CLI
    /// and the page put it ([`calibrate::BandMap`], its knots fitted to the step's output and
    /// held fixed for the gradient); whole tiles only (crop [`SKETCH_PX`]).
    BandL1,
}

impl Default for SketchConfig {
    fn default() -> Self {
        Self {
            batch: 8,
            crop: 128,
            pool: 384,
            lr: 2e-4,
            adversarial: 0.01,
            seed: 1,
            windows: WindowChoice::ALL,
            format_pairs: None,
            format_exclude: Vec::new(),
            format_share: 0.0,
            loss: PixelLoss::L1,
        }
    }
}

/// Pairs replaced in the pool per step.
const REFRESH_PER_STEP: usize = 2;

/// A run in progress.
pub struct SketchRun {
    /// The generator.
    pub g: SketchGen,
    d: Disc,
    og: ModuleOptimizer,
    od: ModuleOptimizer,
    /// Settings.
    pub cfg: SketchConfig,
    /// Progress so far.
    pub progress: Progress,
    pool: Vec<Pair>,
    /// Pairs of the format's own files (see [`SketchConfig::format_pairs`]).
    format: Vec<Pair>,
    device: Device,
}

fn tensor(data: Vec<f32>, shape: [usize; 4], device: &Device) -> Tensor<4> {
    Tensor::<4>::from_data(TensorData::new(data, shape), device)
}

impl SketchRun {
    /// Starts a run on `device` (an autodiff device) with a pool of pairs from the training
    /// split of `dems`: resumes the checkpoint in `resume_from`, or else starts the generator
    /// from `init` (e.g. the shipped weights) or from random weights.
    pub fn start(cfg: SketchConfig, dems: &[Dem], device: &Device, resume_from: Option<&Path>, init: Option<&SketchGenCpu>) -> Result<Self, String> {
        if cfg.crop == 0 || !cfg.crop.is_multiple_of(16) || cfg.crop > SKETCH_PX {
            return Err(format!("the crop side must be a multiple of 16 up to {SKETCH_PX}, not {}", cfg.crop));
        }
        if cfg.loss == PixelLoss::BandL1 && cfg.crop != SKETCH_PX {
            return Err(format!("the band-scale loss needs whole tiles (crop {SKETCH_PX}), not {} px crops", cfg.crop));
        }
        let mut g = SketchGen::new(device);
        if let Some(w) = init {
            g = w.into_model(g);
        }
        let mut d = Disc::with_inputs(1 + crate::sketch::INPUT_CHANNELS, device);
        let (mut og, mut od) = (gan::adam(), gan::adam());
        let mut progress = Progress::default();
        let mut cfg = cfg;
        if let Some(dir) = resume_from {
            let state;
            (og, od, state) = gan::load_run(dir, "sketch", WEIGHT_FILE, &mut g, &mut d)?;
            progress = serde_json::from_value(state["progress"].clone()).map_err(|e| format!("sketch_state.json: {e}"))?;
            cfg = serde_json::from_value(state["config"].clone()).map_err(|e| format!("sketch_state.json: {e}"))?;
        }
        let pool = pairs(dems, Split::Train, cfg.pool, &cfg.windows, cfg.seed ^ progress.step as u64);
        if pool.is_empty() {
            return Err("no DEM gives a NaN-free training window with relief".into());
        }
        let format = match &cfg.format_pairs {
            Some(dir) => format_pairs(dir, &cfg.format_exclude, true)?.0,
            None => Vec::new(),
        };
        if cfg.format_share > 0.0 && format.is_empty() {
            return Err("a share of format pairs was asked for, but no such pair is left to train on".into());
        }
        Ok(Self { g, d, og, od, cfg, progress, pool, format, device: device.clone() })
    }

    /// One optimiser step of both networks on random crops of the pool; then a few pool pairs
    /// are replaced by fresh ones from `dems`.
    pub fn step(&mut self, dems: &[Dem]) -> Result<(), String> {
        let t0 = web_time::Instant::now();
        let mut rng = Rng(self.cfg.seed.wrapping_mul(0x1_0000_0001) ^ self.progress.step as u64);
        let (b, c, n) = (self.cfg.batch, self.cfg.crop, SKETCH_PX);
        let (mut xs, mut ys) = (Vec::with_capacity(b * IN_CHANNELS * c * c), Vec::with_capacity(b * c * c));
        let format_per_mille = (self.cfg.format_share.clamp(0.0, 1.0) * 1000.0).round() as usize;
        for _ in 0..b {
            let p = if !self.format.is_empty() && rng.below(1000) < format_per_mille { &self.format[rng.below(self.format.len())] } else { &self.pool[rng.below(self.pool.len())] };
            let (x0, y0) = (rng.below(n - c + 1), rng.below(n - c + 1));
            for ch in 0..IN_CHANNELS {
                for y in y0..y0 + c {
                    xs.extend_from_slice(&p.input[ch * n * n + y * n + x0..ch * n * n + y * n + x0 + c]);
                }
            }
            for y in y0..y0 + c {
                ys.extend_from_slice(&p.target[y * n + x0..y * n + x0 + c]);
            }
        }
        let dev = &self.device;
        // Each crop's bands, for the band-scale loss.
        let bands: Vec<Vec<u8>> =
            if self.cfg.loss == PixelLoss::BandL1 { xs.chunks_exact(IN_CHANNELS * c * c).map(|x| Sketch::from_channels(x, c).band).collect() } else { Vec::new() };
        let x = tensor(xs, [b, IN_CHANNELS, c, c], dev);
        let real = tensor(ys, [b, 1, c, c], dev);
        let cond = x.clone().narrow(1, 0, crate::sketch::INPUT_CHANNELS);
        let fake = self.g.forward(x);
        let adv_w = self.cfg.adversarial;
        let (mut adv_v, mut disc_v) = (0.0, 0.0);
        if adv_w > 0.0 {
            let real_in = Tensor::cat(vec![real.clone(), cond.clone()], 1);
            let fake_in = Tensor::cat(vec![fake.clone().detach(), cond.clone()], 1);
            disc_v = gan::disc_step(&mut self.d, &mut self.od, self.cfg.lr * 0.5, real_in, fake_in, None);
        }
        let diff = if self.cfg.loss == PixelLoss::BandL1 { band_scaled(fake.clone(), &bands, c, dev) - real } else { fake.clone() - real };
        let l1 = diff.clone().abs().mean();
        let l1_v = l1.clone().into_scalar::<f32>() as f64;
        let mut loss = match self.cfg.loss {
            PixelLoss::L1 | PixelLoss::BandL1 => l1,
            PixelLoss::L2 => (diff.clone() * diff).mean(),
        };
        if adv_w > 0.0 {
            let adv = gan::gen_adversarial(&self.d, Tensor::cat(vec![fake, cond], 1), None);
            adv_v = adv.clone().into_scalar::<f32>() as f64;
            loss = loss + adv * adv_w;
        }
        let gp = GradientsParams::from_grads(loss.backward(), &self.g);
        self.g = self.og.step(self.cfg.lr, self.g.clone(), gp);
        for k in 0..REFRESH_PER_STEP {
            if let Some(p) = random_pair(dems, Split::Train, &self.cfg.windows, &mut rng) {
                let slot = (self.progress.step * REFRESH_PER_STEP + k) % self.pool.len();
                self.pool[slot] = p;
            }
        }
        self.progress.record(l1_v, adv_v, disc_v, t0.elapsed().as_secs_f64());
        Ok(())
    }

    /// The generator on the CPU kernels.
    pub fn cpu(&self) -> Result<SketchGenCpu, String> {
        SketchGenCpu::from_model(&self.g)
    }

    /// Saves the checkpoint in `dir` (the generator as [`WEIGHT_FILE`]), with `validation`.
    pub fn save(&self, dir: &Path, validation: Option<&Validation>) -> Result<(), String> {
        let state = serde_json::json!({ "config": self.cfg, "progress": self.progress, "validation": validation });
        gan::save_run(dir, "sketch", WEIGHT_FILE, &self.g, &self.d, &self.og, &self.od, &state)
    }
}

/// The generator's output `fake` ([b, 1, c, c], heights / 255) put on the format's scale by
/// each tile's bands (`bands`, one c² list per tile) and divided by 255 again: each pixel
/// through its [`calibrate::Segment`], whose knots are constants of the step, so the gradient
/// flows through the cubic only.
fn band_scaled(fake: Tensor<4>, bands: &[Vec<u8>], c: usize, dev: &Device) -> Tensor<4> {
    let out = fake.clone().detach().into_data().try_to_vec::<f32>().expect("float output");
    let (b, n) = (bands.len(), c * c);
    let mut parts: [Vec<f32>; 6] = std::array::from_fn(|_| Vec::with_capacity(b * n));
    for (s, band) in bands.iter().enumerate() {
        let h: Vec<f32> = out[s * n..(s + 1) * n].iter().map(|v| v * 255.0).collect();
        let map = calibrate::BandMap::fit(&h, band, c);
        for &x in &h {
            // Flat output: the identity (slope 1 from 0 to 255).
            let g = map.as_ref().map_or(calibrate::Segment { x0: 0.0, width: 255.0, y0: 0.0, y1: 255.0, m0: 1.0, m1: 1.0 }, |m| m.segment(x));
            for (part, v) in parts.iter_mut().zip([g.x0, g.width, g.y0, g.y1, g.m0, g.m1]) {
                part.push(v);
            }
        }
    }
    let [x0, width, y0, y1, m0, m1] = parts.map(|v| tensor(v, [b, 1, c, c], dev));
    let t = (fake * 255.0 - x0) / width.clone();
    let t2 = t.clone() * t.clone();
    let t3 = t2.clone() * t.clone();
    let h00 = t3.clone() * 2.0 - t2.clone() * 3.0 + 1.0;
    let h10 = t3.clone() - t2.clone() * 2.0 + t;
    let h01 = t2.clone() * 3.0 - t3.clone() * 2.0;
    let h11 = t3 - t2;
    (h00 * y0 + h10 * width.clone() * m0 + h01 * y1 + h11 * width * m1) / 255.0
}

/// Scores on held-out pairs, on the format's 0–255 scale.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Validation {
    /// Pairs scored.
    pub pairs: usize,
    /// Mean RMSE of the generator (output put on the 0–255 scale by its bands, as the CLI does).
    pub rmse: f64,
    /// Mean PSNR (dB) of the generator.
    pub psnr: f64,
    /// Mean RMSE of the non-learned baseline.
    pub rmse_baseline: f64,
    /// Mean PSNR (dB) of the baseline.
    pub psnr_baseline: f64,
}

/// Scores `generator` and the baseline on `pairs` (full [`SKETCH_PX`]² inputs).
pub fn validate(generator: &SketchGenCpu, pairs: &[Pair]) -> Validation {
    let mut scratch = SketchScratch::default();
    let threads = crate::models::cpu::default_threads();
    let (mut r, mut p, mut rb, mut pb) = (0.0, 0.0, 0.0, 0.0);
    for pair in pairs {
        let target: Vec<f32> = pair.target.iter().map(|v| v * 255.0).collect();
        let mut out: Vec<f32> = generator.forward(&pair.input, SKETCH_PX, &mut scratch, threads).into_iter().map(|v| v * 255.0).collect();
        calibrate::to_band_scale(&mut out, &Sketch::from_channels(&pair.input, SKETCH_PX).band, SKETCH_PX);
        let base: Vec<f32> = pair.input[(IN_CHANNELS - 1) * SKETCH_PX * SKETCH_PX..].iter().map(|v| v * 255.0).collect();
        let (e, eb) = (score::rmse(&out, &target), score::rmse(&base, &target));
        (r, p, rb, pb) = (r + e, p + score::psnr(e), rb + eb, pb + score::psnr(eb));
    }
    let n = pairs.len().max(1) as f64;
    Validation { pairs: pairs.len(), rmse: r / n, psnr: p / n, rmse_baseline: rb / n, psnr_baseline: pb / n }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn synthetic(w: usize, h: usize, spacing: f64) -> Dem {
        let f = |x: f32, y: f32| (x * 0.031).sin() * 140.0 + (y * 0.047 + x * 0.011).cos() * 95.0 + ((x * 0.17).sin() * (y * 0.13).cos()) * 16.0 + 900.0;
        Dem { id: "synthetic".into(), hf: Heightfield::new(w, h, spacing, (0..w * h).map(|k| f((k % w) as f32, (k / w) as f32)).collect()) }
    }

    /// Two steps, a checkpoint, a resumed third step: finite losses, the step count carried
    /// over, and the saved weights read by the CPU kernels, which score the validation pairs.
    #[test]
    fn smoke_training_resumes_from_its_checkpoint() {
        let dems = vec![synthetic(420, 200, 30.0)];
        let device = Device::flex().autodiff();
        let cfg = SketchConfig { batch: 1, crop: 32, pool: 2, ..Default::default() };
        let dir = std::env::temp_dir().join(format!("terrain-sketch-smoke-{}", std::process::id()));
        let mut run = SketchRun::start(cfg.clone(), &dems, &device, None, None).unwrap();
        run.step(&dems).unwrap();
        run.step(&dems).unwrap();
        run.save(&dir, None).unwrap();
        let mut run = SketchRun::start(cfg, &dems, &device, Some(&dir), None).unwrap();
        assert_eq!(run.progress.step, 2);
        run.step(&dems).unwrap();
        let p = &run.progress;
        assert_eq!(p.step, 3);
        assert!(p.l1.is_finite() && p.l1 > 0.0 && p.disc > 0.0 && p.adv.is_finite(), "{p:?}");
        let generator = SketchGenCpu::from_burnpack(&std::fs::read(dir.join(WEIGHT_FILE)).unwrap()).unwrap();
        let val = pairs(&dems, Split::Validation, 1, &WindowChoice::ALL, 5);
        assert_eq!(val.len(), 1);
        let v = validate(&generator, &val);
        assert!(v.rmse.is_finite() && v.rmse_baseline.is_finite() && v.rmse_baseline > 0.0, "{v:?}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// From a seeded random generator, twelve L2 steps without the adversary on a pool of one
    /// pair lower that pair's mean squared error (whole 256 px input) to less than half, and
    /// never train the discriminator.
    #[test]
    fn l2_steps_on_a_pool_of_one_pair_halve_its_squared_error() {
        let dems = vec![synthetic(420, 200, 30.0)];
        let device = Device::flex().autodiff();
        let cfg = SketchConfig { batch: 1, crop: 64, pool: 1, lr: 1e-3, adversarial: 0.0, loss: PixelLoss::L2, ..Default::default() };
        // A seeded random start: the same run every time.
        let init = SketchGenCpu::randomized(7, 0.05);
        let mut run = SketchRun::start(cfg, &dems, &device, None, Some(&init)).unwrap();
        let pair = run.pool[0].clone();
        let mse = |run: &SketchRun| {
            let out = run.cpu().unwrap().forward(&pair.input, SKETCH_PX, &mut SketchScratch::default(), 1);
            out.iter().zip(&pair.target).map(|(o, t)| ((o - t) as f64).powi(2)).sum::<f64>() / out.len() as f64
        };
        let before = mse(&run);
        for _ in 0..12 {
            // No DEMs: the pool keeps its one pair.
            run.step(&[]).unwrap();
        }
        let after = mse(&run);
        assert!(after < 0.5 * before, "mean squared error {before} -> {after}");
        assert_eq!(run.progress.disc, 0.0);
    }

    /// The band-scale loss's tensor path puts a synthetic pair's generated heights (a random
    /// generator's output) on the scale exactly as the CLI does ([`calibrate::to_band_scale`]):
    /// within 1e-3 of 255 on every pixel, for two tiles in one batch.
    #[test]
    fn the_loss_band_scale_is_the_cli_band_scale() {
        let dems = vec![synthetic(420, 200, 30.0)];
        let batch = pairs(&dems, Split::Train, 2, &WindowChoice::ALL, 9);
        assert_eq!(batch.len(), 2);
        let g = SketchGenCpu::randomized(4, 0.05);
        let n = SKETCH_PX * SKETCH_PX;
        let bands: Vec<Vec<u8>> = batch.iter().map(|p| Sketch::from_channels(&p.input, SKETCH_PX).band).collect();
        let outs: Vec<f32> = batch.iter().flat_map(|p| g.forward(&p.input, SKETCH_PX, &mut SketchScratch::default(), 2)).collect();
        let dev = Device::flex();
        let got = band_scaled(tensor(outs.clone(), [2, 1, SKETCH_PX, SKETCH_PX], &dev), &bands, SKETCH_PX, &dev).into_data().try_to_vec::<f32>().unwrap();
        for (s, band) in bands.iter().enumerate() {
            let mut want: Vec<f32> = outs[s * n..(s + 1) * n].iter().map(|v| v * 255.0).collect();
            calibrate::to_band_scale(&mut want, band, SKETCH_PX);
            let worst = want.iter().zip(&got[s * n..]).map(|(w, g)| (w / 255.0 - g).abs()).fold(0f32, f32::max);
            assert!(worst * 255.0 < 1e-3, "tile {s}: differs by {} of 255", worst * 255.0);
        }
    }

    /// A pair file of the format read with augmentation gives its 8 rotations/flips (the first
    /// one the file itself, heights / 255), and none when its name is excluded.
    #[test]
    fn format_pairs_come_in_eight_orientations_and_excluded_names_are_skipped() {
        let n = SKETCH_PX;
        let mut sketch = crate::sketch::Sketch::filled(0);
        let mut rgb = vec![0u8; 2 * n * n * 3];
        for y in 0..n {
            for x in 0..n {
                let band = (x * 4 / n) as u8;
                sketch.band[y * n + x] = band;
                let px = crate::sketch::Sketch::encode_pixel(band, false, false);
                rgb[(y * 2 * n + x) * 3..][..3].copy_from_slice(&px);
                let h = (x * 255 / (n - 1)) as u8;
                rgb[(y * 2 * n + n + x) * 3..][..3].copy_from_slice(&[h, h, h]);
            }
        }
        let dir = std::env::temp_dir().join(format!("terrain-format-pairs-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        crate::sketch::write_rgb_png(std::fs::File::create(dir.join("area_000_001.png")).unwrap(), 2 * n as u32, n as u32, &rgb).unwrap();
        let (pairs, names) = format_pairs(&dir, &[], true).unwrap();
        assert_eq!((pairs.len(), names.len()), (8, 1));
        assert_eq!(pairs[0].target[n - 1], 1.0);
        assert_eq!(pairs[0].target[0], 0.0);
        assert_eq!(pairs[0].input, assemble_input(&sketch, crate::models::sketch::FORMAT_EXTENT_M).0);
        // Flipped left-right (t = 4): the high side is on the left.
        assert_eq!(pairs[4].target[0], 1.0);
        assert_eq!(format_pairs(&dir, &["area_000".to_string()], true).unwrap().0.len(), 0);
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// On a 30 m DEM the smallest window (32 samples) spans 960 m: a 900 m limit leaves no
    /// window to cut, a 1,000 m limit leaves the 32-sample one.
    #[test]
    fn no_pair_is_cut_from_a_window_wider_than_the_extent_limit() {
        let dems = vec![synthetic(420, 200, 30.0)];
        let upto = |m: f64| WindowChoice { max_extent_m: Some(m), ..WindowChoice::ALL };
        assert_eq!(pairs(&dems, Split::Train, 4, &upto(900.0), 3).len(), 0);
        assert_eq!(pairs(&dems, Split::Train, 4, &upto(1000.0), 3).len(), 4);
    }

    /// A pair tells the generator its window's ground extent: with windows of 32 samples at
    /// 30 m only, every pixel of the extent channel is the value of 960 m.
    #[test]
    fn a_pairs_extent_channel_is_its_windows_side_times_spacing() {
        let dems = vec![synthetic(420, 200, 30.0)];
        let only_32 = WindowChoice { max_extent_m: Some(960.0), ..WindowChoice::ALL };
        let made = pairs(&dems, Split::Train, 3, &only_32, 4);
        assert_eq!(made.len(), 3);
        let n = SKETCH_PX * SKETCH_PX;
        let want = crate::models::sketch::extent_value(960.0);
        assert!(want > 0.0);
        for p in &made {
            assert!(p.input[crate::models::sketch::EXTENT_CHANNEL * n..][..n].iter().all(|&v| v == want));
        }
    }

    /// A checkpoint keeps the window choice and the pixel loss beside the other settings:
    /// written and read back they are the same, and a checkpoint from before the DEM,
    /// least-extent and loss settings (only max_extent_m) reads as every DEM with no least
    /// extent and L1.
    #[test]
    fn a_checkpoint_config_round_trips_its_window_choice_and_loss_and_older_ones_read_as_every_dem_and_l1() {
        let cfg = SketchConfig {
            windows: WindowChoice { dems: vec!["a".into(), "b".into()], min_extent_m: Some(400.0), max_extent_m: Some(3100.0), hand_drawn: 0.5 },
            loss: PixelLoss::L2,
            ..Default::default()
        };
        let json = serde_json::to_value(&cfg).unwrap();
        assert_eq!(json["min_extent_m"], 400.0);
        assert_eq!(json["loss"], "l2");
        let back: SketchConfig = serde_json::from_value(json).unwrap();
        assert_eq!(back.windows, cfg.windows);
        assert_eq!(back.loss, PixelLoss::L2);
        let old = serde_json::json!({ "batch": 8, "crop": 128, "pool": 384, "lr": 2e-4, "adversarial": 0.01, "seed": 1, "max_extent_m": 1000.0 });
        let old: SketchConfig = serde_json::from_value(old).unwrap();
        assert_eq!(old.windows, WindowChoice { max_extent_m: Some(1000.0), ..WindowChoice::ALL });
        assert_eq!(old.loss, PixelLoss::L1);
    }

    /// The window choice keeps to its DEMs and its least extent: a 30 m DEM's train split
    /// (about 400 samples wide) has windows of 32–256 samples (960–7,680 m); asking for at
    /// least 8,000 m leaves none, and naming only another DEM leaves none of this one.
    #[test]
    fn pairs_come_only_from_the_named_dems_and_windows_at_least_the_least_extent() {
        let mut dems = vec![synthetic(620, 420, 30.0)];
        dems[0].id = "a".into();
        let choice = |ids: &[&str], min: f64| WindowChoice { dems: ids.iter().map(|s| s.to_string()).collect(), min_extent_m: Some(min), max_extent_m: None, hand_drawn: 0.0 };
        assert_eq!(pairs(&dems, Split::Train, 3, &choice(&["a"], 7000.0), 3).len(), 3);
        assert_eq!(pairs(&dems, Split::Train, 3, &choice(&["a"], 8000.0), 3).len(), 0);
        assert_eq!(pairs(&dems, Split::Train, 3, &choice(&["b"], 100.0), 3).len(), 0);
        assert_eq!(pairs(&dems, Split::Train, 3, &choice(&[], 100.0), 3).len(), 3);
    }

    /// The GPU path trains like the CPU path: the same five L1 steps from the same seeded
    /// weights on the same pair, once on burn's wgpu backend (Mesa's lavapipe here) and once
    /// on its CPU backend. The per-step losses agree to 1e-4 of the 0–1 height scale and the
    /// trained generators' outputs to 1e-3, while the steps themselves change the output by
    /// far more (checked too), so a GPU path that did not train, or trained differently,
    /// fails. Why these bounds: both backends compute in f32 with other summation orders
    /// (~1e-6 apart per layer); Adam's first steps move each weight by about the learning rate
    /// whatever the gradient's size, so a near-zero gradient of opposite sign moves a weight
    /// 2·lr apart: at lr 1e-3 over five steps that stays under 1e-3 of the output.
    #[test]
    fn gpu_and_cpu_backends_train_the_same_five_steps() {
        use crate::train::Backend;
        let dems = vec![synthetic(420, 200, 30.0)];
        let cfg = SketchConfig { batch: 2, crop: 64, pool: 1, lr: 1e-3, adversarial: 0.0, loss: PixelLoss::L1, ..Default::default() };
        let init = SketchGenCpu::randomized(7, 0.05);
        let train = |backend: Backend| {
            let mut run = SketchRun::start(cfg.clone(), &dems, &backend.device().unwrap(), None, Some(&init)).unwrap();
            let pair = run.pool[0].clone();
            let mut losses = Vec::new();
            let t = web_time::Instant::now();
            for _ in 0..5 {
                // No DEMs: the pool keeps its one pair.
                run.step(&[]).unwrap();
                losses.push(run.progress.l1);
            }
            eprintln!("{backend:?}: 5 steps in {:.2} s, losses {losses:?}", t.elapsed().as_secs_f64());
            let out = run.cpu().unwrap().forward(&pair.input, SKETCH_PX, &mut SketchScratch::default(), 1);
            (losses, out, pair)
        };
        let (gpu_losses, gpu_out, pair) = train(Backend::Gpu);
        let (cpu_losses, cpu_out, _) = train(Backend::Cpu);
        let loss_gap = gpu_losses.iter().zip(&cpu_losses).map(|(a, b)| (a - b).abs()).fold(0f64, f64::max);
        assert!(loss_gap < 1e-4, "losses differ by {loss_gap}: gpu {gpu_losses:?}, cpu {cpu_losses:?}");
        let out_gap = gpu_out.iter().zip(&cpu_out).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        let start = init.forward(&pair.input, SKETCH_PX, &mut SketchScratch::default(), 1);
        let moved = start.iter().zip(&cpu_out).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        eprintln!("trained outputs differ by {out_gap:.2e}; training moved them by {moved:.2e}");
        assert!(out_gap < 1e-3, "trained generators differ by {out_gap}");
        assert!(moved > 20.0 * out_gap.max(1e-4), "five steps moved the output by only {moved}");
    }

    /// A run started from given weights generates what those weights generate on the CPU
    /// kernels (largest difference below 1e-5 of the 0–1 height scale).
    #[test]
    fn a_run_started_from_weights_generates_what_they_generate() {
        let dems = vec![synthetic(420, 200, 30.0)];
        let init = SketchGenCpu::randomized(11, 0.05);
        let cfg = SketchConfig { batch: 1, crop: 32, pool: 1, ..Default::default() };
        let run = SketchRun::start(cfg, &dems, &Device::flex().autodiff(), None, Some(&init)).unwrap();
        let x = &pairs(&dems, Split::Validation, 1, &WindowChoice::ALL, 5)[0].input;
        let mut s = SketchScratch::default();
        let (a, b) = (init.forward(x, SKETCH_PX, &mut s, 1), run.cpu().unwrap().forward(x, SKETCH_PX, &mut s, 1));
        let worst = a.iter().zip(&b).map(|(p, q)| (p - q).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-5, "largest difference {worst}");
        assert!(a.iter().any(|v| (v - a[0]).abs() > 1e-4), "the random generator's output is flat");
    }
}
