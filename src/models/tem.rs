//! The terrain enhancement module (TEM): a ×2 super-resolution CNN of 47,497 parameters. It
//! takes one quadrant of a patch (with a context margin, heights in metres) and returns the
//! quadrant at half the spacing: a learned residual added to the bicubic upsampling of its
//! input. Five of them make the 32 → 16 → 8 → 4 → 2 → 1 m ladder.
//!
//! Architecture (SPEC.md): head conv3×3 4→32; body 4 × (conv3×3 32→32 + ReLU) + conv3×3 32→32
//! with a skip from the head; tail PixelShuffle(2) then conv3×3 8→1 (initialised to zero, so an
//! untrained model is exactly bicubic).
//!
//! Two choices differ from the reference and make the refined world seamless by construction:
//! - Every input feature is local and invariant to adding a constant height: the height minus
//!   its 3×3 mean, ∂x, ∂z and |∂x| + |∂z| (no patch mean). An output pixel therefore depends only
//!   on input pixels within [`RECEPTIVE_OUT_PX`], so two overlapping patches computed with enough
//!   margin agree on their overlap (up to float rounding) and refined edges of neighbouring
//!   quads match.
//! - Heights are divided by a per-level scale proportional to the input spacing
//!   ([`level_scale_m`]: 40 m at 32 m input, as the reference, 2.5 m at 2 m input), so every
//!   level sees slopes of the same order and self-similar pretraining transfers across levels.

use burn::module::Module;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{Initializer, PaddingConfig2d};
use burn::nn::{PixelShuffle, PixelShuffleConfig};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};

use crate::models::cpu::{self, Conv3, Map, Post};

/// Gain applied to the normalised local features.
pub const FEATURE_GAIN: f32 = 10.0;
/// Number of TEM levels.
pub const LEVELS: usize = 5;
/// Output spacing of each level (metres per pixel): level k turns 2·s into s.
pub const LEVEL_SPACING_M: [f64; LEVELS] = [16.0, 8.0, 4.0, 2.0, 1.0];
/// Side (output pixels) of the core of a refined patch; the input quadrant is half of it.
pub const PATCH: usize = 128;
/// Side (input pixels) of the quadrant a model refines.
pub const QUAD: usize = PATCH / 2;
/// Context margin (pixels, on every side): a model reads QUAD + 2·MARGIN input pixels and a
/// stored patch keeps PATCH + 2·MARGIN output pixels. It must be at least
/// [`RECEPTIVE_OUT_PX`] so that stored pixels never see the input's border.
pub const MARGIN: usize = 16;
/// Side of a model's input window (pixels).
pub const WINDOW: usize = QUAD + 2 * MARGIN;
/// Side of a stored refined patch (pixels): core plus margin.
pub const STORED: usize = PATCH + 2 * MARGIN;
/// Output pixels within this distance of the input window's border are affected by padding
/// (features: 1 input px, 6 convolutions at input resolution, the tail at output resolution).
pub const RECEPTIVE_OUT_PX: usize = 15;
/// Channels of the body.
const WIDTH: usize = 32;

/// Height scale of level `k` (metres): 1.25 × its input spacing.
pub fn level_scale_m(level: usize) -> f32 {
    (2.5 * LEVEL_SPACING_M[level]) as f32
}

/// One TEM model (one level of the ladder).
#[derive(Module, Debug)]
pub struct Tem {
    head: Conv2d,
    body: Vec<Conv2d>,
    merge: Conv2d,
    shuffle: PixelShuffle,
    tail: Conv2d,
}

fn conv(cin: usize, cout: usize, device: &Device) -> Conv2d {
    Conv2dConfig::new([cin, cout], [3, 3]).with_padding(PaddingConfig2d::Same).init(device)
}

impl Tem {
    /// A freshly initialised model on `device` (its output is exactly bicubic).
    pub fn new(device: &Device) -> Self {
        Self {
            head: conv(4, WIDTH, device),
            body: (0..4).map(|_| conv(WIDTH, WIDTH, device)).collect(),
            merge: conv(WIDTH, WIDTH, device),
            shuffle: PixelShuffleConfig::new(2).init(),
            tail: Conv2dConfig::new([WIDTH / 4, 1], [3, 3]).with_padding(PaddingConfig2d::Same).with_initializer(Initializer::Zeros).init(device),
        }
    }

    /// A model on `device` with the weights of [`TemCpu::randomized`]`(seed, amplitude)`: a
    /// training run that starts the same every time (burn's own initialisation is seeded
    /// from the system's entropy).
    #[cfg(feature = "train")]
    pub fn seeded(device: &Device, seed: u64, amplitude: f32) -> Self {
        let w = TemCpu::randomized(seed, amplitude);
        let mut m = Self::new(device);
        cpu::conv_into_burn(&w.head, &mut m.head);
        for (src, c) in w.body.iter().zip(&mut m.body) {
            cpu::conv_into_burn(src, c);
        }
        cpu::conv_into_burn(&w.merge, &mut m.merge);
        cpu::conv_into_burn(&w.tail, &mut m.tail);
        m
    }

    /// Enhances a batch: `x` is [B, 1, h, w] heights in metres, `scale_m` the level's height
    /// scale ([`level_scale_m`]); the result is [B, 1, 2h, 2w] heights in metres at half the
    /// spacing. Pixels within [`RECEPTIVE_OUT_PX`] of the border see the padding.
    pub fn forward(&self, x: Tensor<4>, scale_m: f32) -> Tensor<4> {
        let base = self.bicubic2(x.clone());
        let head = self.head.forward(features(x / scale_m));
        let mut b = head.clone();
        for c in &self.body {
            b = relu(c.forward(b));
        }
        let b = self.merge.forward(b) + head;
        let residual = self.tail.forward(self.shuffle.forward(b));
        base + residual * scale_m
    }
}

/// File name of level `k`'s weights (burnpack) in `weights/`.
pub fn weight_file(k: usize) -> String {
    format!("tem_{k}_{}m.bpk", LEVEL_SPACING_M[k])
}

/// Loads the five burn models of the ladder from `dir` onto `device` (training, fine-tuning,
/// WebGPU/Vulkan inference).
#[cfg(not(target_arch = "wasm32"))]
pub fn load_models(dir: &std::path::Path, device: &Device) -> Result<Vec<Tem>, super::WeightError> {
    (0..LEVELS).map(|k| load_model(&read_weight_file(dir, k)?, k, device)).collect()
}

#[cfg(not(target_arch = "wasm32"))]
fn read_weight_file(dir: &std::path::Path, k: usize) -> Result<Vec<u8>, super::WeightError> {
    super::read_weight_file(&dir.join(weight_file(k)))
}

/// One burn model from burnpack bytes (level `k`, for the error message).
fn load_model(bytes: &[u8], k: usize, device: &Device) -> Result<Tem, super::WeightError> {
    super::load_burnpack(Tem::new(device), bytes).map_err(|e| e.in_file(weight_file(k)))
}

/// Where a [`TemSet`] runs.
#[derive(Clone, Debug)]
pub enum Exec {
    /// The project's own CPU kernels ([`crate::models::cpu`]) on this many threads.
    Cpu {
        /// Threads (1 = the calling thread only).
        threads: usize,
    },
    /// burn on a device (WebGPU in the page, Vulkan natively).
    Burn(Device),
}

impl Exec {
    /// The CPU on every core natively, one thread in the page.
    pub fn cpu() -> Self {
        Exec::Cpu { threads: crate::models::cpu::default_threads() }
    }
}

enum Engine {
    Burn { models: Vec<Tem>, device: Device },
    Cpu { models: Vec<TemCpu>, threads: usize, scratch: std::sync::Mutex<Vec<Scratch>> },
}

/// The five TEM models of the ladder, ready for inference on the CPU or a burn device.
pub struct TemSet {
    engine: Engine,
}

impl TemSet {
    fn cpu(models: Vec<TemCpu>, threads: usize) -> Self {
        Self { engine: Engine::Cpu { models, threads, scratch: Default::default() } }
    }

    /// Untrained models (each exactly bicubic).
    pub fn untrained(exec: &Exec) -> Self {
        match exec {
            Exec::Cpu { threads } => Self::cpu((0..LEVELS).map(|_| TemCpu::untrained()).collect(), *threads),
            Exec::Burn(device) => Self { engine: Engine::Burn { models: (0..LEVELS).map(|_| Tem::new(device)).collect(), device: device.clone() } },
        }
    }

    /// Wraps trained burn models (on the CPU their weights are copied into its kernels).
    pub fn from_models(models: Vec<Tem>, exec: &Exec) -> Result<Self, super::WeightError> {
        if models.len() != LEVELS {
            return Err(super::WeightError::Count { what: "TEM models", given: models.len(), needed: LEVELS });
        }
        Ok(match exec {
            Exec::Cpu { threads } => Self::cpu(models.iter().map(TemCpu::from_model).collect::<Result<_, _>>().map_err(super::WeightError::Unreadable)?, *threads),
            Exec::Burn(device) => Self { engine: Engine::Burn { models: models.into_iter().map(|m| m.to_device(device)).collect(), device: device.clone() } },
        })
    }

    /// Wraps CPU models on `threads` threads.
    pub fn from_cpu(models: Vec<TemCpu>, threads: usize) -> Result<Self, super::WeightError> {
        if models.len() != LEVELS {
            return Err(super::WeightError::Count { what: "TEM models", given: models.len(), needed: LEVELS });
        }
        Ok(Self::cpu(models, threads.max(1)))
    }

    /// Loads the five models from burnpack bytes (level order). A broken or mismatching file
    /// is a clear error naming it.
    pub fn from_bytes(files: Vec<Vec<u8>>, exec: &Exec) -> Result<Self, super::WeightError> {
        if files.len() != LEVELS {
            return Err(super::WeightError::Count { what: "TEM weight files", given: files.len(), needed: LEVELS });
        }
        Ok(match exec {
            Exec::Cpu { threads } => {
                let models = files.iter().enumerate().map(|(k, b)| TemCpu::from_burnpack(b).map_err(|e| e.in_file(weight_file(k)))).collect::<Result<_, _>>()?;
                Self::cpu(models, *threads)
            }
            Exec::Burn(device) => {
                let models = files.iter().enumerate().map(|(k, b)| load_model(b, k, device)).collect::<Result<_, _>>()?;
                Self { engine: Engine::Burn { models, device: device.clone() } }
            }
        })
    }

    /// Loads the five models from `dir/tem_{k}_{s}m.bpk`.
    #[cfg(not(target_arch = "wasm32"))]
    pub fn load_dir(dir: &std::path::Path, exec: &Exec) -> Result<Self, super::WeightError> {
        let files = (0..LEVELS).map(|k| read_weight_file(dir, k)).collect::<Result<Vec<_>, _>>()?;
        Self::from_bytes(files, exec)
    }

    /// Where the models run: "cpu" or burn's device name.
    pub fn backend(&self) -> String {
        match &self.engine {
            Engine::Cpu { threads, .. } => format!("cpu ({threads} thread{})", if *threads == 1 { "" } else { "s" }),
            Engine::Burn { device, .. } => format!("{device:?}"),
        }
    }

    /// Every convolution's weights and biases of level `level` as JSON (see
    /// [`TemCpu::convs_json`]); `None` for models on a burn device.
    pub fn convs_json(&self, level: usize) -> Option<serde_json::Value> {
        match &self.engine {
            Engine::Cpu { models, .. } => Some(models[level].convs_json()),
            Engine::Burn { .. } => None,
        }
    }

    /// Runs level `level` on `n` square windows of side `side` (heights in metres, row-major,
    /// concatenated) and returns the [n, 2·side, 2·side] heights at half the spacing. On the
    /// CPU this computes now; on a burn device it waits for the readback (natively; in the
    /// page, where a GPU readback cannot block, that is an error: use
    /// [`enhance_async`](Self::enhance_async)).
    pub fn enhance_blocking(&self, level: usize, inputs: Vec<f32>, n: usize, side: usize) -> Result<Vec<f32>, String> {
        match &self.engine {
            Engine::Cpu { .. } => self.enhance_cpu(level, &inputs, n, side),
            #[cfg(not(target_arch = "wasm32"))]
            Engine::Burn { models, device } => burn_enhance(&models[level], device, level, inputs, n, side).into_data().try_to_vec::<f32>().map_err(|e| format!("{e:?}")),
            #[cfg(target_arch = "wasm32")]
            Engine::Burn { .. } => Err("a GPU readback cannot block in the page".into()),
        }
    }

    /// [`enhance_blocking`](Self::enhance_blocking) with an asynchronous readback (as
    /// browsers require for GPU buffers); the CPU computes before the first await.
    pub async fn enhance_async(&self, level: usize, inputs: Vec<f32>, n: usize, side: usize) -> Result<Vec<f32>, String> {
        match &self.engine {
            Engine::Cpu { .. } => self.enhance_cpu(level, &inputs, n, side),
            Engine::Burn { models, device } => {
                let t = burn_enhance(&models[level], device, level, inputs, n, side);
                let data = t.into_data_async().await.map_err(|e| format!("GPU readback failed: {e:?}"))?;
                data.try_to_vec::<f32>().map_err(|e| format!("{e:?}"))
            }
        }
    }

    fn enhance_cpu(&self, level: usize, inputs: &[f32], n: usize, side: usize) -> Result<Vec<f32>, String> {
        let Engine::Cpu { models, threads, scratch } = &self.engine else { unreachable!("CPU engine") };
        if inputs.len() != n * side * side || side == 0 {
            return Err(format!("{} heights given for {n} windows of {side}²", inputs.len()));
        }
        let (model, scale) = (&models[level], level_scale_m(level));
        let mut pool = scratch.lock().unwrap_or_else(|p| p.into_inner());
        let groups = (*threads).min(n).max(1);
        let len = pool.len().max(groups);
        pool.resize_with(len, Scratch::default);
        if groups == 1 {
            // One window at a time, each layer's rows split between the threads.
            return Ok(inputs.chunks_exact(side * side).flat_map(|x| model.forward(x, side, scale, &mut pool[0], *threads)).collect());
        }
        // A batch: whole windows per thread, each with its own buffers.
        let per = n.div_ceil(groups);
        let mut parts: Vec<Vec<f32>> = vec![Vec::new(); groups];
        #[cfg(not(target_arch = "wasm32"))]
        {
            use rayon::prelude::*;
            parts
                .par_iter_mut()
                .zip(pool.par_iter_mut())
                .zip(inputs.par_chunks(per * side * side))
                .for_each(|((part, scratch), xs)| *part = xs.chunks_exact(side * side).flat_map(|x| model.forward(x, side, scale, scratch, 1)).collect());
        }
        #[cfg(target_arch = "wasm32")]
        for ((part, scratch), xs) in parts.iter_mut().zip(pool.iter_mut()).zip(inputs.chunks(per * side * side)) {
            *part = xs.chunks_exact(side * side).flat_map(|x| model.forward(x, side, scale, scratch, 1)).collect();
        }
        Ok(parts.concat())
    }
}

fn burn_enhance(model: &Tem, device: &Device, level: usize, inputs: Vec<f32>, n: usize, side: usize) -> Tensor<4> {
    let x = Tensor::<4>::from_data(burn::tensor::TensorData::new(inputs, [n, 1, side, side]), device);
    model.forward(x, level_scale_m(level))
}

/// Reused activation buffers of the CPU forward pass.
#[derive(Default)]
pub struct Scratch {
    feat: Map,
    head: Map,
    a: Map,
    b: Map,
    shuffled: Map,
    tail: Map,
}

/// One TEM level on the project's own CPU kernels ([`crate::models::cpu`]): the same network
/// as [`Tem::forward`], computed without a tensor framework.
#[derive(Clone, Debug)]
pub struct TemCpu {
    head: Conv3,
    body: Vec<Conv3>,
    merge: Conv3,
    tail: Conv3,
}

/// Names of the convolutions in a weight file, in network order.
fn conv_names() -> Vec<String> {
    let mut names = vec!["head".to_string()];
    names.extend((0..4).map(|i| format!("body.{i}")));
    names.push("merge".into());
    names.push("tail".into());
    names
}

impl TemCpu {
    /// An untrained model: the tail is zero, so the output is exactly bicubic.
    pub fn untrained() -> Self {
        let mut seed = 1u64;
        let mut layer = |cout: usize, cin: usize, amplitude: f32| {
            // The same scale as burn's default (Kaiming uniform); values are irrelevant for
            // the zero tail except that the body stays finite.
            let w: Vec<f32> = (0..cout * cin * 9).map(|_| amplitude * cpu::unit(&mut seed)).collect();
            Conv3::from_oihw(cout, cin, &w, None).expect("sizes")
        };
        let bound = |cin: usize| (1.0 / (9.0 * cin as f32)).sqrt();
        Self {
            head: layer(WIDTH, 4, bound(4)),
            body: (0..4).map(|_| layer(WIDTH, WIDTH, bound(WIDTH))).collect(),
            merge: layer(WIDTH, WIDTH, bound(WIDTH)),
            tail: layer(1, WIDTH / 4, 0.0),
        }
        .fused()
    }

    /// Every layer made [`Conv3::with_fused`] (true): nothing downstream of the TEM amplifies a last-bit
    /// difference (its output is drawn, not grown from), so it takes the x86 kernels' faster
    /// fused multiply-adds (25–35 % natively).
    fn fused(self) -> Self {
        let f = |c: Conv3| c.with_fused(true);
        Self { head: f(self.head), body: self.body.into_iter().map(f).collect(), merge: f(self.merge), tail: f(self.tail) }
    }

    /// Every weight drawn uniformly from ±`amplitude` (deterministic in `seed`): tests use it
    /// because a zero tail would make every output plain bicubic and prove nothing.
    pub fn randomized(seed: u64, amplitude: f32) -> Self {
        let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let mut layer = |cout: usize, cin: usize| {
            let w: Vec<f32> = (0..cout * cin * 9).map(|_| amplitude * cpu::unit(&mut s)).collect();
            let b: Vec<f32> = (0..cout).map(|_| amplitude * cpu::unit(&mut s)).collect();
            Conv3::from_oihw(cout, cin, &w, Some(&b)).expect("sizes")
        };
        Self { head: layer(WIDTH, 4), body: (0..4).map(|_| layer(WIDTH, WIDTH)).collect(), merge: layer(WIDTH, WIDTH), tail: layer(1, WIDTH / 4) }.fused()
    }

    /// Copies a burn model's weights.
    pub fn from_model(m: &Tem) -> Result<Self, String> {
        let one = cpu::conv_from_burn;
        Ok(Self { head: one(&m.head)?, body: m.body.iter().map(one).collect::<Result<_, _>>()?, merge: one(&m.merge)?, tail: one(&m.tail)? }.fused())
    }

    /// Reads a burnpack weight file (as written by training) without a tensor framework:
    /// `{name}.weight` [cout, cin, 3, 3] and `{name}.bias` [cout], float32, for every
    /// convolution; anything missing, misshapen or non-finite is an error.
    pub fn from_burnpack(bytes: &[u8]) -> Result<Self, crate::models::WeightError> {
        let shapes = [(WIDTH, 4), (WIDTH, WIDTH), (WIDTH, WIDTH), (WIDTH, WIDTH), (WIDTH, WIDTH), (WIDTH, WIDTH), (1, WIDTH / 4)];
        let layers: Vec<(String, usize, usize)> = conv_names().into_iter().zip(shapes).map(|(n, (o, i))| (n, o, i)).collect();
        let mut convs = cpu::convs_from_burnpack(bytes, &layers)?;
        let tail = convs.pop().expect("7 convs");
        let merge = convs.pop().expect("7 convs");
        let head = convs.remove(0);
        Ok(Self { head, body: convs, merge, tail }.fused())
    }

    /// Every convolution's weights ([cout, cin, 3, 3], row-major) and bias as JSON
    /// (`{"head": {"shape", "w", "b"}, "body.0": …, "merge": …, "tail": …}`), for reference
    /// runtimes that rebuild the network (tools/tem_vs_onnx.py).
    pub fn convs_json(&self) -> serde_json::Value {
        let layers = std::iter::once(&self.head).chain(&self.body).chain([&self.merge, &self.tail]);
        cpu::convs_json(conv_names().into_iter().zip(layers))
    }

    /// One window: `x` is `side`² heights in metres (row-major), `scale_m` the level's height
    /// scale; returns (2·side)² heights in metres. `threads` splits each layer's rows.
    pub fn forward(&self, x: &[f32], side: usize, scale_m: f32, s: &mut Scratch, threads: usize) -> Vec<f32> {
        // The bicubic base is computed beside the network (on a second thread when there is
        // one): it needs only the input.
        let ((), base) = cpu::join(
            threads > 1,
            || {
                features_into(x, side, scale_m, &mut s.feat);
                cpu::conv(&self.head, &s.feat, &mut s.head, Post::None, threads);
                cpu::conv(&self.body[0], &s.head, &mut s.a, Post::Relu, threads);
                for c in &self.body[1..] {
                    cpu::conv(c, &s.a, &mut s.b, Post::Relu, threads);
                    std::mem::swap(&mut s.a, &mut s.b);
                }
                cpu::conv(&self.merge, &s.a, &mut s.b, Post::Add(&s.head), threads);
                cpu::pixel_shuffle2(&s.b, &mut s.shuffled);
                cpu::conv(&self.tail, &s.shuffled, &mut s.tail, Post::None, threads);
            },
            || crate::dem::Heightfield::new(side, side, 1.0, x.to_vec()).upsample_bicubic2(),
        );
        let o = 2 * side;
        let mut out = base.data;
        for y in 0..o {
            for (xx, v) in out[y * o..(y + 1) * o].iter_mut().enumerate() {
                *v += s.tail.pixel(y, xx)[0] * scale_m;
            }
        }
        out
    }
}

/// [`features`] on the CPU as a channel-first array (4 × `side`²).
pub fn features_cpu(x: &[f32], side: usize, scale_m: f32) -> Vec<f32> {
    let mut m = Map::default();
    features_into(x, side, scale_m, &mut m);
    m.to_chw()
}

/// [`features`] on the CPU: the four feature channels of `x` (`side`² heights in metres,
/// divided by `scale_m`) into `dst`.
fn features_into(x: &[f32], side: usize, scale_m: f32, dst: &mut Map) {
    let n = side;
    let at = |r: usize, c: usize| x[r * n + c] / scale_m;
    // Row means (l + r + x) / 3 with replicated edges, then the vertical mean of those.
    let mut row = vec![0f32; n * n];
    for r in 0..n {
        for c in 0..n {
            let (l, rr) = (at(r, c.saturating_sub(1)), at(r, (c + 1).min(n - 1)));
            row[r * n + c] = (l + rr + at(r, c)) / 3.0;
        }
    }
    dst.reset(n, n, 4);
    for r in 0..n {
        let (up, down) = (r.saturating_sub(1), (r + 1).min(n - 1));
        for c in 0..n {
            let (l, rr) = (at(r, c.saturating_sub(1)), at(r, (c + 1).min(n - 1)));
            let gx = (rr - l) * (0.5 * FEATURE_GAIN);
            let gz = (at(down, c) - at(up, c)) * (0.5 * FEATURE_GAIN);
            let mean = (row[up * n + c] + row[down * n + c] + row[r * n + c]) / 3.0;
            let detail = (at(r, c) - mean) * FEATURE_GAIN;
            dst.pixel_mut(r, c).copy_from_slice(&[detail, gx, gz, gx.abs() + gz.abs()]);
        }
    }
}

/// Side of the fixed probe input (pixels) used to compare backends.
pub const PROBE_SIDE: usize = 100;

/// The fixed probe input of level `level`: smooth hills plus fine ripples (metres), scaled to
/// the level's spacing. The page and the CLI run it to show that WebGPU and CPU agree.
pub fn probe_input(level: usize) -> Vec<f32> {
    let s = LEVEL_SPACING_M[level] as f32;
    (0..PROBE_SIDE * PROBE_SIDE)
        .map(|k| {
            let (x, y) = ((k % PROBE_SIDE) as f32, (k / PROBE_SIDE) as f32);
            1200.0 + s * (8.0 * (x * 0.11).sin() * (y * 0.07).cos() + 3.0 * (x * 0.53 + y * 0.31).sin() + 0.05 * x)
        })
        .collect()
}

/// How long a probe run took (milliseconds, all levels), where the runner measured it.
#[derive(Clone, Copy, Debug, Default)]
pub struct ProbeTimes {
    /// From the first request to the last result, as the caller waited for them (the page:
    /// messages to and from its CPU worker included, the JSON of the result not).
    pub round_trip_ms: Option<f64>,
    /// What the backend itself measured computing (the page's CPU worker, on its own clock).
    pub compute_ms: Option<f64>,
}

/// The probe output of every level as JSON: `{"backend": …, "levels": [[h, …] per level],
/// "round_trip_ms": …, "compute_ms": …}`, every one of the (2·PROBE_SIDE)² heights (metres) of
/// each level, so two backends are compared on whole outputs; the times are `null` where not
/// measured ([`ProbeTimes`]).
pub fn probe_json(backend: &str, levels: &[Vec<f32>], times: ProbeTimes) -> String {
    serde_json::json!({ "backend": backend, "levels": levels, "round_trip_ms": times.round_trip_ms, "compute_ms": times.compute_ms }).to_string()
}

impl Tem {
    /// Bicubic ×2 (Keys a = −0.75, pixel-area centres, edges clamped — the same numbers as
    /// `interpolate(Bicubic, align_corners = false)`) as one 5×5 convolution with four fixed
    /// phase kernels and a pixel shuffle. Browsers' software WebGPU (SwiftShader) stalls for
    /// minutes on burn's interpolate kernel; convolutions run in milliseconds.
    fn bicubic2(&self, x: Tensor<4>) -> Tensor<4> {
        let device = x.device();
        let [_, _, h, w] = x.dims();
        // Replicate the border twice (clamping) along both axes.
        let pad = |t: Tensor<4>, dim: usize, n: usize| {
            let first = t.clone().narrow(dim, 0, 1);
            let last = t.clone().narrow(dim, n - 1, 1);
            Tensor::cat(vec![first.clone(), first, t, last.clone(), last], dim)
        };
        let padded = pad(pad(x, 3, w), 2, h);
        let even = crate::dem::cubic_weights(0.75);
        let odd = crate::dem::cubic_weights(0.25);
        let taps = [[even[0], even[1], even[2], even[3], 0.0], [0.0, odd[0], odd[1], odd[2], odd[3]]];
        let mut kernel = Vec::with_capacity(4 * 25);
        for dy in 0..2 {
            for dx in 0..2 {
                for a in 0..5 {
                    for b in 0..5 {
                        kernel.push(taps[dy][a] * taps[dx][b]);
                    }
                }
            }
        }
        let weight = Tensor::<4>::from_data(burn::tensor::TensorData::new(kernel, [4, 1, 5, 5]), &device);
        let phases = burn::tensor::module::conv2d(padded, weight, None, burn::tensor::ops::ConvOptions::new([1, 1], [0, 0], [1, 1], 1));
        self.shuffle.forward(phases)
    }
}

/// Shifts `t` by one pixel along `dim` (size `n`) with the edge replicated: (previous, next).
fn neighbours(t: &Tensor<4>, dim: usize, n: usize) -> (Tensor<4>, Tensor<4>) {
    let prev = Tensor::cat(vec![t.clone().narrow(dim, 0, 1), t.clone().narrow(dim, 0, n - 1)], dim);
    let next = Tensor::cat(vec![t.clone().narrow(dim, 1, n - 1), t.clone().narrow(dim, n - 1, 1)], dim);
    (prev, next)
}

/// The four input channels from scaled heights [B, 1, h, w], all × [`FEATURE_GAIN`]: height
/// minus its 3×3 mean, ∂/∂x and ∂/∂z (central differences) and |∂/∂x| + |∂/∂z|; edges
/// replicated.
pub fn features(xn: Tensor<4>) -> Tensor<4> {
    let [_, _, h, w] = xn.dims();
    let (l, r) = neighbours(&xn, 3, w);
    let gx = (r.clone() - l.clone()) * (0.5 * FEATURE_GAIN);
    let row = (l + r + xn.clone()) / 3.0;
    let (u, d) = neighbours(&xn, 2, h);
    let gz = (d - u) * (0.5 * FEATURE_GAIN);
    let (ru, rd) = neighbours(&row, 2, h);
    let mean = (ru + rd + row) / 3.0;
    let detail = (xn - mean) * FEATURE_GAIN;
    let mag = gx.clone().abs() + gz.clone().abs();
    Tensor::cat(vec![detail, gx, gz, mag], 1)
}

#[cfg(all(test, feature = "train"))]
mod tests {
    use super::*;
    use burn::tensor::TensorData;

    /// Broken weight files (garbage, truncated, empty, bytes flipped) are errors that name
    /// the file, never panics, on the CPU and on burn; the intact set loads on both.
    #[test]
    fn broken_weight_files_are_errors_naming_the_file() {
        let dir = crate::repo_root().join("weights");
        let good: Vec<Vec<u8>> = (0..LEVELS).map(|k| std::fs::read(dir.join(weight_file(k))).unwrap()).collect();
        for exec in [Exec::Cpu { threads: 1 }, Exec::Burn(Device::flex())] {
            assert!(TemSet::from_bytes(good.clone(), &exec).is_ok());
            let half = good[2][..good[2].len() / 2].to_vec();
            let mut flipped = good[2].clone();
            for b in flipped.iter_mut().step_by(97) {
                *b ^= 0x5a;
            }
            for (what, bytes) in [("garbage", b"not a burnpack file at all".to_vec()), ("truncated", half), ("empty", Vec::new()), ("flipped", flipped)] {
                let mut files = good.clone();
                files[2] = bytes;
                let r = std::panic::catch_unwind(|| TemSet::from_bytes(files, &exec).map(|_| ()));
                let r = r.unwrap_or_else(|_| panic!("{what} weights panicked on {exec:?}"));
                if what != "flipped" {
                    let e = r.unwrap_err();
                    assert!(matches!(&e, crate::models::WeightError::InFile { file, .. } if *file == weight_file(2)), "{what}: {e}");
                } else if let Err(e) = r {
                    assert!(matches!(&e, crate::models::WeightError::InFile { file, .. } if *file == weight_file(2)), "{what}: {e}");
                }
            }
            let e = TemSet::from_bytes(good[..4].to_vec(), &exec).err().unwrap();
            assert!(matches!(e, crate::models::WeightError::Count { given: 4, needed: LEVELS, .. }), "{e}");
            assert!(e.to_string().contains("4 TEM weight files"));
        }
    }

    /// The CPU kernels compute the burn network: random weights (every layer non-zero, so
    /// the residual is large) and the shipped weights read straight from their files, on a
    /// batch of two windows: every output within 1 mm of burn's.
    #[test]
    fn cpu_forward_equals_burn_forward() {
        let device = Device::flex();
        let side = 37;
        let data: Vec<f32> = (0..2 * side * side).map(|k| 900.0 + ((k % side) as f32 * 0.31).sin() * 40.0 + ((k / side) as f32 * 0.17).cos() * 25.0).collect();
        let dir = crate::repo_root().join("weights");
        let burn_models = load_models(&dir, &device).unwrap();
        let mut cases: Vec<(&str, Tem, TemCpu)> = Vec::new();
        let r = crate::models::random_weights(Tem::new(&device), &device, 1, 0.05);
        let rc = TemCpu::from_model(&r).unwrap();
        cases.push(("random", r, rc));
        for k in [0, 4] {
            let cpu = TemCpu::from_burnpack(&std::fs::read(dir.join(weight_file(k))).unwrap()).unwrap();
            cases.push((if k == 0 { "shipped level 0" } else { "shipped level 4" }, burn_models[k].clone(), cpu));
        }
        for (what, burn_m, cpu_m) in cases {
            let x = Tensor::<4>::from_data(TensorData::new(data.clone(), [2, 1, side, side]), &device);
            let want: Vec<f32> = burn_m.forward(x, 40.0).into_data().try_to_vec::<f32>().unwrap();
            let mut s = Scratch::default();
            let got: Vec<f32> = data.chunks(side * side).flat_map(|w| cpu_m.forward(w, side, 40.0, &mut s, 2)).collect();
            assert_eq!(got.len(), want.len());
            let worst = got.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
            let bic = crate::dem::Heightfield::new(side, side, 1.0, data[..side * side].to_vec()).upsample_bicubic2();
            let residual = want.iter().zip(&bic.data).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
            assert!(worst < 1e-3, "{what}: CPU and burn differ by {worst} m (residual up to {residual} m)");
            assert!(residual > 0.05, "{what}: the residual ({residual} m) must be non-trivial or the test proves little");
        }
    }

    #[test]
    fn has_the_papers_parameter_count() {
        let m = Tem::new(&Device::flex());
        assert_eq!(m.num_params(), 47_497);
    }

    #[test]
    fn an_untrained_model_is_bicubic_and_offsets_pass_through() {
        let device = Device::flex();
        let m = Tem::new(&device);
        let data: Vec<f32> = (0..2 * 16 * 16).map(|k| 1500.0 + ((k % 16) as f32 * 0.7).sin() * 30.0 + (k / 256) as f32 * 200.0).collect();
        let x = Tensor::<4>::from_data(TensorData::new(data.clone(), [2, 1, 16, 16]), &device);
        let y: Vec<f32> = m.forward(x, 40.0).into_data().try_to_vec::<f32>().unwrap();
        assert_eq!(y.len(), 2 * 32 * 32);
        let bic = crate::dem::Heightfield::new(16, 16, 2.0, data[..256].to_vec()).upsample_bicubic2();
        let worst = y[..1024].iter().zip(&bic.data).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-3, "zero tail ⇒ bicubic, off by {worst} m");
        let mean0 = y[..1024].iter().sum::<f32>() / 1024.0;
        let mean1 = y[1024..].iter().sum::<f32>() / 1024.0;
        assert!((mean1 - mean0 - 200.0).abs() < 0.01, "{mean0} {mean1}");
    }

    /// The convolutional bicubic equals burn's interpolate kernel (which the weights were
    /// trained with) and the CPU reference.
    #[test]
    fn convolution_bicubic_equals_interpolate() {
        use burn::tensor::module::interpolate;
        use burn::tensor::ops::{InterpolateMode, InterpolateOptions};
        let device = Device::flex();
        let m = Tem::new(&device);
        let data: Vec<f32> = (0..2 * 13 * 17).map(|k| ((k % 17) as f32 * 0.9).sin() * 50.0 + (k / 17) as f32 * 3.0 + 800.0).collect();
        let x = Tensor::<4>::from_data(TensorData::new(data, [2, 1, 13, 17]), &device);
        let a: Vec<f32> = m.bicubic2(x.clone()).into_data().try_to_vec::<f32>().unwrap();
        let b: Vec<f32> =
            interpolate(x, InterpolateOptions::new(InterpolateMode::Bicubic).with_align_corners(false).with_output_size([26, 34])).into_data().try_to_vec::<f32>().unwrap();
        assert_eq!(a.len(), b.len());
        let worst = a.iter().zip(&b).map(|(p, q)| (p - q).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-3, "{worst} m");
    }

    #[test]
    fn features_see_a_ramp_and_ignore_constant_offsets() {
        let device = Device::flex();
        let ramp: Vec<f32> = (0..16).map(|k| (k % 4) as f32 * 0.1).collect();
        let x = Tensor::<4>::from_data(TensorData::new(ramp.clone(), [1, 1, 4, 4]), &device);
        let f: Vec<f32> = features(x).into_data().try_to_vec::<f32>().unwrap();
        // channel 1 (∂/∂x) inside: (0.2 − 0.0)/2 × 10 = 1.0; channel 2 (∂/∂z) is 0.
        assert!((f[16 + 1] - 1.0).abs() < 1e-5, "{}", f[17]);
        assert!(f[32..48].iter().all(|v| v.abs() < 1e-6));
        assert!((f[48 + 1] - 1.0).abs() < 1e-5);
        // A linear ramp has no detail inside.
        assert!(f[5].abs() < 1e-5 && f[6].abs() < 1e-5);
        let lifted = Tensor::<4>::from_data(TensorData::new(ramp.iter().map(|v| v + 1000.0).collect::<Vec<_>>(), [1, 1, 4, 4]), &device);
        let g: Vec<f32> = features(lifted).into_data().try_to_vec::<f32>().unwrap();
        let d = f.iter().zip(&g).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(d < 1e-2, "features must not depend on the absolute height: {d}");
    }

    /// The property the seamless world rests on: an output pixel further than
    /// RECEPTIVE_OUT_PX from the border does not depend on input outside its reach, so two
    /// overlapping windows agree.
    #[test]
    fn overlapping_windows_agree_away_from_the_border() {
        let device = Device::flex();
        let m = crate::models::random_weights(Tem::new(&device), &device, 2, 0.3);
        let n = 48;
        let global: Vec<f32> = (0..(n + 8) * n).map(|k| ((k % (n + 8)) as f32 * 0.37).sin() * 20.0 + ((k / (n + 8)) as f32 * 0.21).cos() * 15.0).collect();
        let cut = |x0: usize| -> Vec<f32> { (0..n).flat_map(|y| global[y * (n + 8) + x0..y * (n + 8) + x0 + n].to_vec()).collect() };
        let a = Tensor::<4>::from_data(TensorData::new(cut(0), [1, 1, n, n]), &device);
        let b = Tensor::<4>::from_data(TensorData::new(cut(8), [1, 1, n, n]), &device);
        let ya: Vec<f32> = m.forward(a, 40.0).into_data().try_to_vec::<f32>().unwrap();
        let yb: Vec<f32> = m.forward(b, 40.0).into_data().try_to_vec::<f32>().unwrap();
        let (o, r) = (2 * n, RECEPTIVE_OUT_PX);
        let mut worst = 0f32;
        let mut worst_inside_border = 0f32;
        for y in r..o - r {
            for x in 16 + r..o - r {
                // ya at output x equals yb at output x − 16.
                let d = (ya[y * o + x] - yb[y * o + x - 16]).abs();
                worst = worst.max(d);
            }
            worst_inside_border = worst_inside_border.max((ya[y * o + 16] - yb[y * o]).abs());
        }
        assert!(worst < 1e-3, "overlap differs by {worst} m");
        assert!(worst_inside_border > 1e-3, "the border pixels do see the padding ({worst_inside_border}); else the test proves nothing");
    }
}
