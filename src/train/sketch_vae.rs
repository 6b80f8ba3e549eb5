//! Training the sketch VAE ([`crate::models::sketch_vae`]) on the CPU: the extracted sketches
//! of [`super::sketch`] (train split, 8 rotations/flips), loss = the bands' cross-entropy + the
//! strokes' binary cross-entropy weighted [`STROKE_WEIGHT`]× (they are thin and rare) summed over
//! pixels, + [`KL_WEIGHT`] × the KL divergence of the code (the sketch paper's 0.65); all
//! divided by the pixel count. Resumable checkpoints.

use std::path::Path;

use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::tensor::activation::{log_sigmoid, log_softmax};
use burn::tensor::{Device, Tensor, TensorData};

use super::gan;
use super::pairs::{Dem, Rng, Split};
use super::sketch::{Pair, WindowChoice, pairs, random_pair};
use super::tcm::TcmProgress as Progress;
use crate::models::sketch_vae::{CODE_PX, LATENT_CHANNELS, SketchVae, SketchVaeCpu, VaeScratch, WEIGHT_FILE};
use crate::sketch::{BANDS, INPUT_CHANNELS, SKETCH_PX, Sketch, score};

/// Extra weight of the ridge and valley layers' cross-entropy.
pub const STROKE_WEIGHT: f32 = 5.0;
/// Weight of the code's KL divergence.
pub const KL_WEIGHT: f32 = 0.65;
/// Pairs replaced in the pool per step.
const REFRESH_PER_STEP: usize = 1;

/// Settings of a VAE training run.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct VaeConfig {
    /// Sketches per step.
    pub batch: usize,
    /// Sketches kept in memory.
    pub pool: usize,
    /// Side of the square crops trained on (a multiple of 64; the whole sketch, 256, unless
    /// a smoke test needs speed).
    #[serde(default = "whole_sketch")]
    pub crop: usize,
    /// Adam learning rate.
    pub lr: f64,
    /// Seed of the sampler and the codes' noise.
    pub seed: u64,
}

fn whole_sketch() -> usize {
    SKETCH_PX
}

impl Default for VaeConfig {
    fn default() -> Self {
        Self { batch: 8, pool: 256, crop: SKETCH_PX, lr: 5e-4, seed: 2 }
    }
}

/// The sketches of one VAE training step ([`VaeRun::batch`]).
#[derive(Clone, Debug)]
pub struct VaeBatch {
    /// The crops' input channels, [batch, INPUT_CHANNELS, crop, crop].
    xs: Vec<f32>,
    /// Their bands one-hot, [batch, BANDS, crop, crop].
    onehot: Vec<f32>,
    /// The codes' standard normal noise, [batch, LATENT_CHANNELS, code, code].
    eps: Vec<f32>,
    /// The sampler's state after the batch was drawn.
    sampler: u64,
}

/// A VAE run in progress.
pub struct VaeRun {
    /// The VAE.
    pub m: SketchVae,
    opt: ModuleOptimizer,
    /// Settings.
    pub cfg: VaeConfig,
    /// Progress (`l1` holds the reconstruction term, `adv` the KL term per pixel, `disc` 0).
    pub progress: Progress,
    pool: Vec<Pair>,
    device: Device,
}

impl VaeRun {
    /// Starts a run on `device` (an autodiff device), or resumes the one saved in
    /// `resume_from`.
    pub fn start(cfg: VaeConfig, dems: &[Dem], device: &Device, resume_from: Option<&Path>) -> Result<Self, String> {
        let mut m = SketchVae::new(device);
        let mut opt = gan::adam();
        if cfg.crop == 0 || !cfg.crop.is_multiple_of(64) || cfg.crop > SKETCH_PX {
            return Err(format!("the VAE's crop side must be a multiple of 64 up to {SKETCH_PX}, not {}", cfg.crop));
        }
        let mut cfg = cfg;
        let mut progress = Progress::default();
        if let Some(dir) = resume_from {
            gan::load_into(&mut m, &dir.join(WEIGHT_FILE))?;
            opt = gan::adam().load(dir.join("sketch_vae_adam.bin")).map_err(|e| format!("sketch_vae_adam.bin: {e:?}"))?;
            let text = std::fs::read_to_string(dir.join("sketch_vae_state.json")).map_err(|e| format!("sketch_vae_state.json: {e}"))?;
            let state: serde_json::Value = serde_json::from_str(&text).map_err(|e| format!("sketch_vae_state.json: {e}"))?;
            progress = serde_json::from_value(state["progress"].clone()).map_err(|e| format!("sketch_vae_state.json: {e}"))?;
            cfg = serde_json::from_value(state["config"].clone()).map_err(|e| format!("sketch_vae_state.json: {e}"))?;
        }
        let pool = pairs(dems, Split::Train, cfg.pool, &WindowChoice::ALL, cfg.seed ^ progress.step as u64);
        if pool.is_empty() {
            return Err("no DEM gives a NaN-free training window with relief".into());
        }
        Ok(Self { m, opt, cfg, progress, pool, device: device.clone() })
    }

    /// One optimiser step on a batch of pool sketches ([`Self::batch`], [`Self::fit`]), then
    /// a pool sketch replaced by a new one from `dems`.
    pub fn step(&mut self, dems: &[Dem]) -> Result<(), String> {
        let batch = self.batch();
        self.fit(&batch);
        // The sampler goes on where the batch's left it (as before the batch was its own step).
        let mut rng = Rng(batch.sampler);
        for k in 0..REFRESH_PER_STEP {
            if let Some(p) = random_pair(dems, Split::Train, &WindowChoice::ALL, &mut rng) {
                let slot = ((self.progress.step - 1) * REFRESH_PER_STEP + k) % self.pool.len();
                self.pool[slot] = p;
            }
        }
        Ok(())
    }

    /// The batch this step trains on: [`VaeConfig::batch`] crops of pool sketches and the
    /// codes' noise, seeded by the run's seed and step count.
    pub fn batch(&self) -> VaeBatch {
        let mut rng = Rng(self.cfg.seed.wrapping_mul(0x1_0000_0001) ^ self.progress.step as u64);
        let (b, s, full) = (self.cfg.batch, self.cfg.crop, SKETCH_PX);
        let n = s * s;
        let (mut xs, mut onehot) = (Vec::with_capacity(b * INPUT_CHANNELS * n), vec![0f32; b * BANDS * n]);
        for i in 0..b {
            let p = &self.pool[rng.below(self.pool.len())];
            let (x0, y0) = (rng.below(full - s + 1), rng.below(full - s + 1));
            for ch in 0..INPUT_CHANNELS {
                for y in y0..y0 + s {
                    xs.extend_from_slice(&p.input[ch * full * full + y * full + x0..ch * full * full + y * full + x0 + s]);
                }
            }
            for q in 0..n {
                let band = ((xs[i * INPUT_CHANNELS * n + q] * 3.0).round() as usize).min(BANDS - 1);
                onehot[(i * BANDS + band) * n + q] = 1.0;
            }
        }
        let code = s / (SKETCH_PX / CODE_PX);
        let eps: Vec<f32> = (0..b * LATENT_CHANNELS * code * code).map(|_| crate::models::tcm::gauss(rng.next_u64())).collect();
        VaeBatch { xs, onehot, eps, sampler: rng.0 }
    }

    /// One optimiser step on `batch`. Returns its reconstruction term before the step (nats
    /// per pixel).
    pub fn fit(&mut self, batch: &VaeBatch) -> f64 {
        let t0 = web_time::Instant::now();
        let (b, s) = (self.cfg.batch, self.cfg.crop);
        let n = s * s;
        let code = s / (SKETCH_PX / CODE_PX);
        let dev = &self.device;
        let x = Tensor::<4>::from_data(TensorData::new(batch.xs.clone(), [b, INPUT_CHANNELS, s, s]), dev);
        let onehot = Tensor::<4>::from_data(TensorData::new(batch.onehot.clone(), [b, BANDS, s, s]), dev);
        let strokes = x.clone().narrow(1, 1, 2);
        let (mu, logvar) = self.m.encode(x);
        let eps = Tensor::<4>::from_data(TensorData::new(batch.eps.clone(), [b, LATENT_CHANNELS, code, code]), dev);
        let z = mu.clone() + (logvar.clone() * 0.5).exp() * eps;
        let logits = self.m.decode(z);
        let band_ce = -(log_softmax(logits.clone().narrow(1, 0, BANDS), 1) * onehot).sum() / (b * n) as f32;
        let l = logits.narrow(1, BANDS, 2);
        let bce = -(strokes.clone() * log_sigmoid(l.clone()) + (strokes.neg() + 1.0) * log_sigmoid(l.neg())).sum() / (b * n) as f32;
        let recon = band_ce + bce * STROKE_WEIGHT;
        let kl = ((logvar.clone().exp() + mu.powf_scalar(2.0) - logvar - 1.0) * 0.5).sum() / (b * n) as f32;
        let (recon_v, kl_v) = (recon.clone().into_scalar::<f32>() as f64, kl.clone().into_scalar::<f32>() as f64);
        let loss = recon + kl * KL_WEIGHT;
        let gp = GradientsParams::from_grads(loss.backward(), &self.m);
        self.m = self.opt.step(self.cfg.lr, self.m.clone(), gp);
        self.progress.record(recon_v, kl_v, 0.0, t0.elapsed().as_secs_f64());
        recon_v
    }

    /// The VAE on the CPU kernels.
    pub fn cpu(&self) -> Result<SketchVaeCpu, String> {
        SketchVaeCpu::from_model(&self.m)
    }

    /// Saves the checkpoint in `dir`: [`WEIGHT_FILE`], the optimiser and the state (with
    /// `validation`).
    pub fn save(&self, dir: &Path, validation: Option<&VaeValidation>) -> Result<(), String> {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        gan::save(&self.m, &dir.join(WEIGHT_FILE))?;
        self.opt.save(dir.join("sketch_vae_adam.bin")).map_err(|e| format!("sketch_vae_adam.bin: {e:?}"))?;
        let state = serde_json::json!({ "config": self.cfg, "progress": self.progress, "validation": validation });
        std::fs::write(dir.join("sketch_vae_state.json"), serde_json::to_string_pretty(&state).expect("json")).map_err(|e| format!("sketch_vae_state.json: {e}"))
    }
}

/// How well held-out sketches survive encoding and decoding (the code's mean).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct VaeValidation {
    /// Sketches scored.
    pub sketches: usize,
    /// Mean fraction of pixels whose band is kept.
    pub band_agreement: f64,
    /// Mean ridge F1 (within 3 px) of the reconstruction.
    pub ridge_f1: f64,
    /// Mean valley F1.
    pub valley_f1: f64,
    /// Mean fraction of pixels whose band differs between a sketch and its variants.
    pub variant_band_change: f64,
}

/// Scores reconstructions and variants of held-out `pairs`' sketches.
pub fn validate(vae: &SketchVaeCpu, pairs: &[Pair]) -> VaeValidation {
    let mut s = VaeScratch::default();
    let threads = crate::models::cpu::default_threads();
    let (mut band, mut rf, mut vf, mut change) = (0.0, 0.0, 0.0, 0.0);
    for p in pairs {
        let sk = Sketch::from_channels(&p.input, SKETCH_PX);
        let (mu, _) = vae.encode(&sk, &mut s, threads);
        let rec = vae.decode(&mu, crate::models::sketch_vae::StrokeCount::of(&sk), &mut s, threads);
        let a = score::Agreement::between(&rec, &sk);
        (band, rf, vf) = (band + a.band, rf + a.ridge_f1(), vf + a.valley_f1());
        let v = vae.variants(&sk, 2, 7, &mut s, threads);
        change += v.iter().map(|x| 1.0 - score::Agreement::between(x, &sk).band).sum::<f64>() / 2.0;
    }
    let n = pairs.len().max(1) as f64;
    VaeValidation { sketches: pairs.len(), band_agreement: band / n, ridge_f1: rf / n, valley_f1: vf / n, variant_band_change: change / n }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dem::Heightfield;

    /// One synthetic 30 m DEM (420 × 200 samples of crossing waves, 900 ± 235 m).
    fn synthetic_dems() -> Vec<Dem> {
        let f = |x: f32, y: f32| (x * 0.031).sin() * 140.0 + (y * 0.047 + x * 0.011).cos() * 95.0 + 900.0;
        let (w, h) = (420, 200);
        vec![Dem { id: "synthetic".into(), hf: Heightfield::new(w, h, 30.0, (0..w * h).map(|k| f((k % w) as f32, (k / w) as f32)).collect()) }]
    }

    /// The GPU path trains the VAE like the CPU path: from one saved start (a fresh CPU run's
    /// checkpoint), three steps on burn's wgpu backend (lavapipe here) and on its CPU
    /// backend give the same reconstruction losses to 1e-4 (nats per pixel; both backends
    /// compute in f32 with other summation orders, and the noise is drawn on the CPU from
    /// the step's seed), and the steps change the loss by more than that.
    #[test]
    fn gpu_and_cpu_backends_train_the_same_three_vae_steps() {
        use crate::train::Backend;
        let dems = synthetic_dems();
        let cfg = VaeConfig { batch: 2, pool: 2, crop: 64, ..Default::default() };
        let dir = std::env::temp_dir().join(format!("terrain-vae-backends-{}", std::process::id()));
        VaeRun::start(cfg.clone(), &dems, &Backend::Cpu.device().unwrap(), None).unwrap().save(&dir, None).unwrap();
        let train = |backend: Backend| {
            let mut run = VaeRun::start(cfg.clone(), &dems, &backend.device().unwrap(), Some(&dir)).unwrap();
            (0..3)
                .map(|_| {
                    run.step(&dems).unwrap();
                    run.progress.l1
                })
                .collect::<Vec<f64>>()
        };
        let (gpu, cpu) = (train(Backend::Gpu), train(Backend::Cpu));
        let gap = gpu.iter().zip(&cpu).map(|(a, b)| (a - b).abs()).fold(0f64, f64::max);
        eprintln!("VAE losses: gpu {gpu:?}, cpu {cpu:?}, largest gap {gap:.2e}");
        assert!(gap < 1e-4, "losses differ by {gap}");
        assert!((cpu[2] - cpu[0]).abs() > 10.0 * gap.max(1e-6), "the steps did not change the loss: {cpu:?}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The VAE trainer learns: on one fixed batch (one 64 px crop and its noise, a seeded
    /// start), twelve steps at learning rate 1e-3 lower its reconstruction term to under 70 %
    /// of the first step's.
    #[test]
    fn twelve_steps_on_one_fixed_batch_lower_the_vae_reconstruction_below_70_percent() {
        let dems = synthetic_dems();
        let device = Device::flex().autodiff();
        let mut run = VaeRun::start(VaeConfig { batch: 1, pool: 1, crop: 64, lr: 1e-3, ..Default::default() }, &dems, &device, None).unwrap();
        run.m = SketchVae::seeded(&device, 4, 0.05);
        let batch = run.batch();
        let losses: Vec<f64> = (0..12).map(|_| run.fit(&batch)).collect();
        eprintln!("fixed-batch VAE reconstruction {losses:.4?}");
        assert!(losses[11] < 0.7 * losses[0], "VAE reconstruction {losses:?}");
    }

    /// Two steps, a checkpoint, a resumed third step: finite losses, the step count carried
    /// over, the saved weights read by the CPU kernels, and a validation that scores them.
    #[test]
    fn vae_smoke_training_resumes_from_its_checkpoint() {
        let dems = synthetic_dems();
        let device = Device::flex().autodiff();
        let cfg = VaeConfig { batch: 1, pool: 2, crop: 64, ..Default::default() };
        let dir = std::env::temp_dir().join(format!("terrain-vae-smoke-{}", std::process::id()));
        let mut run = VaeRun::start(cfg.clone(), &dems, &device, None).unwrap();
        run.step(&dems).unwrap();
        run.step(&dems).unwrap();
        run.save(&dir, None).unwrap();
        let trained = run.cpu().unwrap();
        let mut run = VaeRun::start(cfg, &dems, &device, Some(&dir)).unwrap();
        assert_eq!(run.progress.step, 2);
        run.step(&dems).unwrap();
        let p = &run.progress;
        assert!(p.l1.is_finite() && p.l1 > 0.0 && p.adv.is_finite() && p.adv >= 0.0, "{p:?}");
        let vae = SketchVaeCpu::from_burnpack(&std::fs::read(dir.join(WEIGHT_FILE)).unwrap()).unwrap();
        // The saved VAE is the trained one (after its two steps): the same code to the bit for
        // a sketch, and not a fresh VAE's.
        let sketch = Sketch::from_channels(&run.pool[0].input, SKETCH_PX);
        let code = |v: &SketchVaeCpu| v.encode(&sketch, &mut VaeScratch::default(), 1);
        assert_eq!(code(&vae), code(&trained), "the saved VAE is not the trained one");
        assert_ne!(code(&vae), code(&VaeRun::start(VaeConfig::default(), &dems, &device, None).unwrap().cpu().unwrap()));
        let v = validate(&vae, &pairs(&dems, Split::Validation, 1, &WindowChoice::ALL, 3));
        assert_eq!(v.sketches, 1);
        assert!((0.0..=1.0).contains(&v.band_agreement), "{v:?}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
