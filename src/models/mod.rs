//! Neural networks: the GPU runtime (burn on a wgpu device shared with the renderer — WebGPU
//! in the page, Vulkan natively — with a start-up self-check that runs a real convolution
//! kernel and compares it with a CPU reference), the project's own CPU kernels ([`cpu`]), the
//! policy that picks between them ([`runtime`]) and the models themselves ([`tem`]: learned
//! detail; [`tcm`] and [`grow`]: the learned world).

pub mod cpu;
pub mod exact;
pub mod grow;
pub mod runtime;
pub mod sketch;
pub mod sketch_vae;
pub mod tcm;
pub mod tem;

use burn::tensor::module::conv2d;
use burn::tensor::ops::ConvOptions;
use burn::tensor::{Device, Tensor, TensorData};

pub use burn::tensor::wgpu::{WgpuSetup, wgpu as burn_wgpu};

/// Short hash (8 hex digits, FNV-1a over the bytes in order) of a model's weight files: names
/// the weights in share links and the overlay.
pub fn weights_hash(files: &[&[u8]]) -> String {
    let h = files.iter().fold(crate::grid::Fnv::default(), |h, f| h.bytes(f));
    format!("{:08x}", h.0 >> 32)
}

/// Why a weight file could not be read: the page falls back (procedural world, band
/// interpolation, no learned detail) and says this; the CLI prints it.
#[derive(Debug, thiserror::Error)]
pub enum WeightError {
    /// The file cannot be read from disk.
    #[error("{file}: {reason}")]
    Read {
        /// The file's path.
        file: String,
        /// The system's reason.
        reason: String,
    },
    /// The bytes are not a burnpack file.
    #[error("not a weight file ({0})")]
    NotWeightFile(String),
    /// The file's tensors cannot be read.
    #[error("unreadable tensors ({0})")]
    Unreadable(String),
    /// Tensors the network needs are not in the file.
    #[error("missing tensors {0:?}")]
    Missing(Vec<String>),
    /// A tensor has a number type other than float32 or float16.
    #[error("tensor {name} is {dtype}, float32 or float16 expected")]
    Type {
        /// The tensor's name.
        name: String,
        /// Its number type.
        dtype: String,
    },
    /// A tensor's shape is not the layer's.
    #[error("tensor {name} has shape {got:?}, {want:?} expected")]
    Shape {
        /// The tensor's name.
        name: String,
        /// Its shape in the file.
        got: Vec<usize>,
        /// The shape the layer needs.
        want: Vec<usize>,
    },
    /// A tensor's bytes do not fill its shape.
    #[error("tensor {name} has {bytes} bytes for shape {shape:?}")]
    Size {
        /// The tensor's name.
        name: String,
        /// Bytes in the file.
        bytes: usize,
        /// Its shape.
        shape: Vec<usize>,
    },
    /// A layer cannot be built from its tensors.
    #[error("{name}: {source}")]
    Layer {
        /// The layer's name.
        name: String,
        /// Why.
        source: cpu::LayerError,
    },
    /// A set of networks was given the wrong number of models or files.
    #[error("{given} {what} given, {needed} needed")]
    Count {
        /// What was counted ("TEM models", "TEM weight files").
        what: &'static str,
        /// How many were given.
        given: usize,
        /// How many the set needs.
        needed: usize,
    },
    /// One of the above, in the named file.
    #[error("{file}: {source}")]
    InFile {
        /// The weight file's name.
        file: String,
        /// Why it could not be read.
        source: Box<WeightError>,
    },
}

impl WeightError {
    /// This error, said of the weight file `file`.
    pub fn in_file(self, file: impl std::fmt::Display) -> Self {
        Self::InFile { file: file.to_string(), source: Box::new(self) }
    }
}

/// The bytes of the weight file `path` (a [`WeightError::Read`] naming it if they cannot be
/// read).
#[cfg(not(target_arch = "wasm32"))]
pub fn read_weight_file(path: &std::path::Path) -> Result<Vec<u8>, WeightError> {
    std::fs::read(path).map_err(|e| WeightError::Read { file: path.display().to_string(), reason: e.to_string() })
}

impl From<WeightError> for String {
    fn from(e: WeightError) -> Self {
        e.to_string()
    }
}

/// `model` with the weights of a burnpack file (as training writes it, float32, or shipped as
/// float16: every float tensor becomes the model's float32); an error names missing tensors.
pub fn load_burnpack<M: burn::store::ModuleSnapshot>(model: M, bytes: &[u8]) -> Result<M, WeightError> {
    use burn::store::{BurnpackStore, FloatCastAdapter};
    let mut model = model;
    let mut store = BurnpackStore::from_bytes(Some(burn::tensor::Bytes::from_bytes_vec(bytes.to_vec()))).with_from_adapter(FloatCastAdapter::to(burn::tensor::DType::F32));
    let r = model.load_from(&mut store).map_err(|e| WeightError::NotWeightFile(format!("{e:?}")))?;
    if !r.missing.is_empty() {
        return Err(WeightError::Missing(r.missing.iter().map(|m| m.0.clone()).collect()));
    }
    Ok(model)
}

/// Side of the self-check image (pixels).
const CHECK_SIZE: usize = 32;

/// Registers an existing wgpu setup (the renderer's) with burn, so inference and rendering
/// share one device and queue.
pub fn device_from_setup(setup: WgpuSetup) -> Result<Device, String> {
    Device::wgpu_options().setup(setup).init().map_err(|e| format!("burn could not use the GPU device: {e}"))
}

/// The self-check input: a height ramp with a checker pattern (metres).
fn check_input() -> Vec<f32> {
    (0..CHECK_SIZE * CHECK_SIZE)
        .map(|k| {
            let (x, y) = (k % CHECK_SIZE, k / CHECK_SIZE);
            x as f32 * 1.5 + y as f32 * 0.25 + if (x / 4 + y / 4) % 2 == 0 { 10.0 } else { -10.0 }
        })
        .collect()
}

/// The self-check kernel: a 3×3 edge-weighted blur.
const CHECK_KERNEL: [f32; 9] = [0.0625, 0.125, 0.0625, 0.125, 0.25, 0.125, 0.0625, 0.125, 0.0625];

/// CPU reference of the self-check: 3×3 convolution with zero padding.
pub fn reference_output() -> Vec<f32> {
    let x = check_input();
    let n = CHECK_SIZE as i32;
    let mut out = vec![0f32; x.len()];
    for r in 0..n {
        for c in 0..n {
            let mut acc = 0f32;
            for kr in -1..=1 {
                for kc in -1..=1 {
                    let (rr, cc) = (r + kr, c + kc);
                    if (0..n).contains(&rr) && (0..n).contains(&cc) {
                        acc += x[(rr * n + cc) as usize] * CHECK_KERNEL[((kr + 1) * 3 + kc + 1) as usize];
                    }
                }
            }
            out[(r * n + c) as usize] = acc;
        }
    }
    out
}

/// Builds the self-check convolution on `device` (not yet read back).
fn check_tensor(device: &Device) -> Tensor<4> {
    let x = Tensor::<4>::from_data(TensorData::new(check_input(), [1, 1, CHECK_SIZE, CHECK_SIZE]), device);
    let w = Tensor::<4>::from_data(TensorData::new(CHECK_KERNEL.to_vec(), [1, 1, 3, 3]), device);
    conv2d(x, w, None, ConvOptions::new([1, 1], [1, 1], [1, 1], 1))
}

/// Largest absolute difference (metres) between a device result and the CPU reference.
fn max_error(data: TensorData) -> Result<f32, String> {
    let got: Vec<f32> = data.try_to_vec::<f32>().map_err(|e| format!("unexpected result type: {e:?}"))?;
    let want = reference_output();
    if got.len() != want.len() {
        return Err(format!("result has {} values, expected {}", got.len(), want.len()));
    }
    Ok(got.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max))
}

/// burn on an existing wgpu device (the renderer's), if its self-check passes: the device and
/// the overlay's line ("burn wgpu ready (self-check N ms, max |Δ| … m)"), or why burn cannot
/// use it.
pub async fn start_burn(setup: WgpuSetup) -> Result<(Device, String), String> {
    let t0 = web_time::Instant::now();
    let device = device_from_setup(setup)?;
    match self_check(&device).await {
        Ok(err) if err < 1e-3 => {
            let ms = t0.elapsed().as_secs_f64() * 1e3;
            Ok((device, format!("burn wgpu ready (self-check {ms:.0} ms, max |Δ| {err:.1e} m)")))
        }
        Ok(err) => Err(format!("burn wgpu gives wrong results (max |Δ| {err} m)")),
        Err(e) => Err(format!("burn wgpu failed: {e}")),
    }
}

/// Runs the self-check on `device` (async readback, as browsers require) and returns the
/// largest error against the CPU reference (metres).
pub async fn self_check(device: &Device) -> Result<f32, String> {
    let data = check_tensor(device).into_data_async().await.map_err(|e| format!("GPU readback failed: {e:?}"))?;
    max_error(data)
}

/// The native wgpu device of this process (burn's wgpu runtime on the default adapter:
/// natively Vulkan, a GPU's driver or Mesa's lavapipe). burn registers the runtime once per
/// process, so every native user (training, tests) shares this one; no adapter is an error.
#[cfg(not(target_arch = "wasm32"))]
pub fn native_gpu() -> Result<Device, String> {
    static GPU: std::sync::OnceLock<Result<Device, String>> = std::sync::OnceLock::new();
    GPU.get_or_init(|| Device::wgpu_options().init().map_err(|e| format!("burn's wgpu runtime found no usable adapter: {e}"))).clone()
}

/// Blocking variant of [`self_check`] for native code.
#[cfg(not(target_arch = "wasm32"))]
pub fn self_check_blocking(device: &Device) -> Result<f32, String> {
    max_error(check_tensor(device).into_data())
}

/// `m` with every parameter drawn uniformly from ±`amplitude` by a hash of `seed` (tests: a
/// zero-initialised tail or untrained layers would prove nothing).
#[cfg(all(test, feature = "train"))]
pub(crate) fn random_weights<M: burn::module::Module>(m: M, device: &Device, seed: u64, amplitude: f32) -> M {
    use crate::grid::mix64;
    use burn::module::{ModuleMapper, Param};
    struct Random(Device, u64, f32);
    impl ModuleMapper for Random {
        fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
            let (device, a) = (self.0.clone(), self.2);
            self.1 = mix64(self.1);
            let seed = self.1;
            param.map(|t| {
                let n = t.shape().num_elements();
                let v: Vec<f32> = (0..n as u64).map(|k| ((mix64(seed ^ k) >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0) * a).collect();
                Tensor::<D>::from_data(TensorData::new(v, t.shape()), &device)
            })
        }
    }
    m.map(&mut Random(device.clone(), seed, amplitude))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The native wgpu device (burn registers it once per process, so the tests share it).
    fn test_gpu() -> Device {
        native_gpu().expect("a Vulkan device (install mesa-vulkan-drivers for lavapipe)")
    }

    #[test]
    fn reference_blur_preserves_the_mean_inside() {
        let out = reference_output();
        let x = check_input();
        // Away from the zero-padded border a normalised blur of a ramp keeps the ramp.
        let k = 9 * CHECK_SIZE + 13; // (13, 9): its 3×3 lies inside one checker square
        assert!((out[k] - x[k]).abs() < 1e-4, "{} vs {}", out[k], x[k]);
        assert!(out[0] < x[0], "zero padding pulls the corner down");
    }

    /// Natively burn's wgpu backend runs on Vulkan (Mesa's lavapipe on a machine without a
    /// GPU): the kernel must agree with the CPU to well under a millimetre.
    #[test]
    fn burn_wgpu_convolution_matches_the_cpu() {
        let err = self_check_blocking(&test_gpu()).unwrap();
        assert!(err < 1e-3, "max |Δ| {err} m");
    }

    /// The TEM itself on burn's wgpu backend (lavapipe) against the project's CPU kernels,
    /// with the shipped weights on the fixed probe of every level: heights agree to < 1 mm.
    #[test]
    fn tem_on_wgpu_matches_the_cpu() {
        use tem::{Exec, LEVELS, PROBE_SIDE, TemSet, probe_input};
        let dir = crate::repo_root().join("weights");
        let (tg, tc) = (TemSet::load_dir(&dir, &Exec::Burn(test_gpu())).unwrap(), TemSet::load_dir(&dir, &Exec::cpu()).unwrap());
        let mut worst = 0f32;
        for k in 0..LEVELS {
            let t = web_time::Instant::now();
            let a = tg.enhance_blocking(k, probe_input(k), 1, PROBE_SIDE).unwrap();
            let gpu_ms = t.elapsed().as_secs_f64() * 1e3;
            let t = web_time::Instant::now();
            let b = tc.enhance_blocking(k, probe_input(k), 1, PROBE_SIDE).unwrap();
            let cpu_ms = t.elapsed().as_secs_f64() * 1e3;
            let d = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
            eprintln!("level {k}: max |Δ| {d:.2e} m, wgpu {gpu_ms:.0} ms, cpu {cpu_ms:.0} ms");
            worst = worst.max(d);
        }
        assert!(worst < 1e-3, "wgpu and CPU differ by {worst} m");
    }

    /// The sketch generator on burn's wgpu backend (lavapipe) against the project's CPU
    /// kernels, with the shipped weights on every example sketch: terrains agree within 0.01 on
    /// the format's 0–255 scale (0.06 m at 1,500 m relief), and both span 0–255.
    #[test]
    fn sketch_generator_on_wgpu_matches_the_cpu() {
        use sketch::{SketchGenCpu, SketchGenGpu, WEIGHT_FILE};
        let bytes = std::fs::read(crate::repo_root().join("weights").join(WEIGHT_FILE)).unwrap();
        let (gpu, cpu) = (SketchGenGpu::from_burnpack(&bytes, &test_gpu()).unwrap(), SketchGenCpu::from_burnpack(&bytes).unwrap());
        for (name, s) in crate::sketch::examples::all() {
            let t = web_time::Instant::now();
            let a = gpu.generate_blocking(&s, crate::models::sketch::FORMAT_EXTENT_M).unwrap();
            let gpu_ms = t.elapsed().as_secs_f64() * 1e3;
            let b = cpu.generate(&s, crate::models::sketch::FORMAT_EXTENT_M, &mut Default::default(), 2);
            let d = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
            let (lo, hi) = a.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), &v| (l.min(v), h.max(v)));
            eprintln!("{name}: max |Δ| {d:.2e} of 255, wgpu {gpu_ms:.0} ms");
            assert!(d < 0.01, "{name}: wgpu and CPU differ by {d}");
            assert!(lo.abs() < 1e-3 && (hi - 255.0).abs() < 1e-3, "{name}: wgpu terrain spans {lo}–{hi}");
        }
    }

    /// A broken generator weight file is an error naming the file, not a panic.
    #[test]
    fn a_broken_sketch_weight_file_is_refused_on_the_gpu() {
        let e = sketch::SketchGenGpu::from_burnpack(b"not a burnpack file", &test_gpu()).unwrap_err();
        assert!(e.to_string().starts_with(&format!("{}: not a weight file", sketch::WEIGHT_FILE)), "{e}");
    }
}
