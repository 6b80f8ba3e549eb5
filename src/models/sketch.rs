//! The sketch generator: a compact UNet that turns a sketch ([`crate::sketch`]) into relative
//! heights on the format's scale, by learning what the non-learned interpolation between band
//! borders ([`crate::sketch::baseline`]) misses (pix2pix's task, trained with L1 + PatchGAN).
//!
//! Input ([`IN_CHANNELS`] × H × W, any H and W divisible by 16; [`SKETCH_PX`]² in use):
//! band / 3, ridge, valley ([`Sketch::channels`]), the tile's ground extent ([`extent_value`],
//! the same at every pixel) and the baseline / 255. Output: heights / 255,
//! the baseline plus the network's correction; the caller puts them on the 0–255 scale by the
//! sketch's bands ([`crate::sketch::calibrate`]). Network: two 3×3 convolutions + ReLU per
//! scale ([`WIDTHS`] at 1, 1/2 … 1/16 of the size; 2×2 mean pooling between them), a decoder
//! that upsamples (nearest), concatenates the skip and applies two convolutions, and a 3×3
//! output convolution. No normalisation layers: training and inference compute the same
//! function.

use burn::module::Module;
use burn::nn::conv::Conv2d;
use burn::tensor::{Device, Tensor};

use crate::dem::{dihedral, dihedral_channels, dihedral_inverse};
use crate::models::cpu::{self, Conv3, Map, Post};
use crate::models::tcm::{Stage, conv3, pool2, up2};
use crate::sketch::{self, SKETCH_PX, Sketch, baseline, calibrate};

/// Input channels: the sketch's three ([`sketch::INPUT_CHANNELS`]), the extent and the
/// baseline (last).
pub const IN_CHANNELS: usize = sketch::INPUT_CHANNELS + 2;
/// Input channels of the generators made before the extent channel (a weight file of theirs
/// is read with a zero-weighted extent channel: [`SketchGenCpu::from_burnpack`]).
pub const IN_CHANNELS_V1: usize = sketch::INPUT_CHANNELS + 1;
/// The extent channel's index (just before the baseline).
pub const EXTENT_CHANNEL: usize = sketch::INPUT_CHANNELS;
/// Ground extent (metres) of a tile of the sketch format (the authors' tiles are 400–512 m of
/// 2 m alpine DEM): what `terrain sketch` and `eval-sketch` tell the generator unless told
/// otherwise.
pub const FORMAT_EXTENT_M: f64 = 512.0;
/// The smallest and the largest extent (metres) the generator is told: the range it is
/// trained on (5 m alpine DEMs to 90 m ranges).
pub const EXTENT_RANGE_M: (f64, f64) = (256.0, 16_384.0);

/// The extent channel's value for a tile `extent_m` metres wide: log2(extent / 512 m) / 4,
/// so 0 at the format's scale ([`FORMAT_EXTENT_M`]) and 1 at 8 km; the extent is first
/// clamped to [`EXTENT_RANGE_M`].
pub fn extent_value(extent_m: f64) -> f32 {
    let e = if extent_m.is_finite() { extent_m.clamp(EXTENT_RANGE_M.0, EXTENT_RANGE_M.1) } else { FORMAT_EXTENT_M };
    (libm::log2(e / FORMAT_EXTENT_M) / 4.0) as f32
}
/// The sketch's rotations and flips ([`dihedral`] transforms) in the order
/// [`SketchGenCpu::generate_views`] adds them: the sketch itself, the half turn, the two
/// diagonal mirrorings, then the quarter turns and the axis mirrorings.
pub const VIEW_ORDER: [usize; 8] = [0, 2, 5, 7, 1, 3, 4, 6];
/// Views the CLI averages unless told otherwise (`terrain sketch --views`): all of them.
pub const CLI_VIEWS: usize = VIEW_ORDER.len();
/// Channels per scale, full size to 1/16.
pub const WIDTHS: [usize; 5] = [12, 24, 48, 64, 96];
/// Scales (the input side must be divisible by 2^(SCALES−1)).
pub const SCALES: usize = WIDTHS.len();
/// Name of the weight file in a weights folder.
pub const WEIGHT_FILE: &str = "sketch_gen.bpk";
/// Pixels of mirrored sketch the generator sees around the tile on each side (its terrain
/// there is cut away). Without them its zero padding draws a frame along the tile's border in
/// a hillshade: on the authors' 8 pairs the step between the outermost two rows or columns
/// is 1.34 × the mean step inside (the targets' 0.83); with 8 px it is 0.70, with 16 px 0.55,
/// and the mean RMSE 7.164 → 7.182 → 7.205. 13 % more work per view (272² instead of 256²;
/// a multiple of the UNet's 16).
pub const MARGIN_PX: usize = 8;
/// Side of the network's input with the margin (pixels).
pub const PADDED_PX: usize = SKETCH_PX + 2 * MARGIN_PX;
const _: () = assert!(PADDED_PX.is_multiple_of(1 << (SCALES - 1)), "the UNet halves the side SCALES - 1 times");

/// The channel-first `SKETCH_PX`² input `x` mirrored out to [`PADDED_PX`]² (pixel −1 is
/// pixel 1: even reflection without repeating the edge).
pub fn with_margin(x: &[f32]) -> Vec<f32> {
    let (n, m, big) = (SKETCH_PX, MARGIN_PX, PADDED_PX);
    let mirror = |i: usize| -> usize {
        let i = i as isize - m as isize;
        let n = n as isize;
        (if i < 0 {
            -i
        } else if i >= n {
            2 * n - 2 - i
        } else {
            i
        }) as usize
    };
    let channels = x.len() / (n * n);
    let mut out = vec![0f32; channels * big * big];
    for c in 0..channels {
        for y in 0..big {
            let src = &x[(c * n + mirror(y)) * n..][..n];
            for (xx, o) in out[(c * big + y) * big..][..big].iter_mut().enumerate() {
                *o = src[mirror(xx)];
            }
        }
    }
    out
}

/// The `SKETCH_PX`² centre of a [`PADDED_PX`]² row-major field (the network's output for an
/// input [`with_margin`]).
pub fn crop_margin(o: &[f32]) -> Vec<f32> {
    (0..SKETCH_PX).flat_map(|y| o[(y + MARGIN_PX) * PADDED_PX + MARGIN_PX..][..SKETCH_PX].iter().copied()).collect()
}

/// The network's input for `sketch` on a tile `extent_m` metres wide, channel-first
/// ([`IN_CHANNELS`] × [`SKETCH_PX`]²), and the baseline it starts from (0–255).
pub fn assemble_input(sketch: &Sketch, extent_m: f64) -> (Vec<f32>, Vec<f32>) {
    let base = baseline::interpolate(sketch);
    let mut x = sketch.channels();
    x.extend(std::iter::repeat_n(extent_value(extent_m), SKETCH_PX * SKETCH_PX));
    x.extend(base.iter().map(|v| v / 255.0));
    (x, base)
}

/// The sketch generator.
#[derive(Module, Debug)]
pub struct SketchGen {
    enc: Vec<Stage>,
    dec: Vec<Stage>,
    out: Conv2d,
}

impl SketchGen {
    /// A freshly initialised generator on `device`.
    pub fn new(device: &Device) -> Self {
        let w = WIDTHS;
        let enc = (0..SCALES).map(|k| Stage::new(if k == 0 { IN_CHANNELS } else { w[k - 1] }, w[k], device)).collect();
        let dec = (0..SCALES - 1).map(|k| Stage::new(w[k + 1] + w[k], w[k], device)).collect();
        Self { enc, dec, out: conv3(w[0], 1, device) }
    }

    /// Number of learned parameters.
    pub fn parameters(&self) -> usize {
        self.num_params()
    }

    /// Heights / 255 ([B, 1, H, W]) for inputs `x` ([B, [`IN_CHANNELS`], H, W]).
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let base = x.clone().narrow(1, IN_CHANNELS - 1, 1);
        let mut skips = Vec::with_capacity(SCALES - 1);
        let mut h = x;
        for (k, stage) in self.enc.iter().enumerate() {
            if k > 0 {
                h = pool2(h);
            }
            h = stage.forward(h);
            if k < SCALES - 1 {
                skips.push(h.clone());
            }
        }
        for k in (0..SCALES - 1).rev() {
            h = self.dec[k].forward(Tensor::cat(vec![up2(h), skips[k].clone()], 1));
        }
        base + self.out.forward(h)
    }
}

/// Names and shapes (name, output channels, input channels) of the generator's convolutions
/// in network order, as burn names them in a weight file.
pub fn conv_layers() -> Vec<(String, usize, usize)> {
    conv_layers_of(WIDTHS)
}

/// [`conv_layers`] for a generator of channel widths `w` per scale.
fn conv_layers_of(w: [usize; SCALES]) -> Vec<(String, usize, usize)> {
    conv_layers_with(w, IN_CHANNELS)
}

/// [`conv_layers_of`] with `cin` input channels.
fn conv_layers_with(w: [usize; SCALES], cin: usize) -> Vec<(String, usize, usize)> {
    let mut v = Vec::new();
    for k in 0..SCALES {
        v.push((format!("enc.{k}.a"), w[k], if k == 0 { cin } else { w[k - 1] }));
        v.push((format!("enc.{k}.b"), w[k], w[k]));
    }
    for k in 0..SCALES - 1 {
        v.push((format!("dec.{k}.a"), w[k], w[k + 1] + w[k]));
        v.push((format!("dec.{k}.b"), w[k], w[k]));
    }
    v.push(("out".into(), 1, w[0]));
    v
}

/// Reused activation buffers of [`SketchGenCpu::forward`].
#[derive(Default)]
pub struct SketchScratch {
    input: Map,
    skips: [Map; SCALES - 1],
    pooled: Map,
    t: Map,
    h: Map,
    cat: Map,
    out: Map,
}

/// Channels per scale as the CPU kernels run them: [`WIDTHS`] rounded up to the vectorised
/// kernels' block of 8 channels (the full-size stage, most of the work, 12 → 16), the extra
/// channels zero. A width that is not a multiple of 8 would run on the scalar kernel.
const KERNEL_WIDTHS: [usize; SCALES] = {
    let mut w = WIDTHS;
    let mut k = 0;
    while k < SCALES {
        w[k] = w[k].next_multiple_of(8);
        k += 1;
    }
    w
};

// [`Conv3::widened`] appends the padding after a layer's own channels. A decoder stage reads
// the upsampled deeper features, then the skip, so only the last group, the full-size skip,
// may grow: the deeper widths must be multiples of 8 already.
const _: () = {
    let mut k = 1;
    while k < SCALES {
        assert!(WIDTHS[k].is_multiple_of(8), "only the full-size width may be padded");
        k += 1;
    }
};

/// `convs` (in [`conv_layers`] order) widened for the vectorised kernels: the same function.
/// - Where the kernels run any number of channels (AVX-512, [`cpu::runs_any_channels`]):
///   every layer as trained but the last decoder layer run (`dec.0.b`), widened to 16
///   outputs (4 zero), and the output layer to 16 inputs, for the vectorised one-channel
///   kernel, which takes multiples of 8. A padded input channel costs as much as a real one (12 → 16 is a third
///   more work in the full-size layers), a padded output lane of the masked AVX-512 vector
///   nothing.
/// - Elsewhere: every width rounded up to [`KERNEL_WIDTHS`].
///
/// Both give the same heights: a zero-weighted channel adds exact zeros to every sum, in the
/// same order.
fn widened_for_kernels(convs: &[Conv3], any_channels: bool) -> Vec<Conv3> {
    if any_channels {
        return conv_layers()
            .iter()
            .zip(convs)
            .map(|((name, _, _), c)| match name.as_str() {
                "dec.0.b" => c.widened(c.cout().next_multiple_of(8), c.cin()),
                "out" => c.widened(1, c.cin().next_multiple_of(8)),
                _ => c.clone(),
            })
            .collect();
    }
    conv_layers_of(KERNEL_WIDTHS).into_iter().zip(convs).map(|((_, cout, cin), c)| c.widened(cout, cin)).collect()
}

/// The sketch generator on the project's own CPU kernels: the same network as
/// [`SketchGen::forward`] without a tensor framework (the CLI, the page's worker).
#[derive(Clone, Debug)]
pub struct SketchGenCpu {
    /// The layers as trained, in [`conv_layers`] order.
    convs: Vec<Conv3>,
    /// The same layers as the kernels run them ([`widened_for_kernels`]), each multiply and
    /// add fused into one FMA natively ([`Conv3::with_fused`]).
    run: Vec<Conv3>,
}

impl SketchGenCpu {
    /// The generator with these layers ([`conv_layers`] order), widened as this machine's
    /// kernels run them best.
    fn new(convs: Vec<Conv3>) -> Self {
        Self::with_widths(convs, cpu::runs_any_channels())
    }

    /// The generator with these layers, widened for kernels that run any number of channels
    /// or only multiples of 8 ([`widened_for_kernels`]), and fused: natively each multiply and
    /// add is one FMA, as ONNX Runtime does (a sketch 48 → 41 ms on 1 thread, Zen 4). The
    /// terrain then differs from the page's worker (no FMA in SIMD128) in the last bits, as
    /// the page's WebGPU terrain already does (the e2e tests hold the page to the native CLI
    /// within half a 16-bit step). A sketch pinned into the learned world takes
    /// [`Self::exact`] instead.
    fn with_widths(convs: Vec<Conv3>, any_channels: bool) -> Self {
        let run = widened_for_kernels(&convs, any_channels).into_iter().map(|c| c.with_fused(true)).collect();
        Self { convs, run }
    }

    /// The same generator with every layer unfused: each step a multiply, then an add, as the
    /// page's worker runs it (SIMD128 has no FMA), so its terrain is the worker's to the bit.
    /// A sketch pinned into the learned world (`terrain world --sketch`, and the same terrain in
    /// metres from `terrain sketch --format`) must be: downstream, a
    /// last-bit difference can flip a drainage choice (with the fused generator the world beside
    /// the sketch was 4.2 m from the page's in the e2e test).
    pub fn exact(&self) -> Self {
        Self { convs: self.convs.clone(), run: self.run.iter().map(|c| c.clone().with_fused(false)).collect() }
    }

    /// Every layer random (uniform ±`amplitude`, from `seed`), for tests.
    pub fn randomized(seed: u64, amplitude: f32) -> Self {
        Self::new(cpu::random_convs(&conv_layers(), seed, amplitude))
    }

    /// Reads a generator weight file (burnpack, as training writes it). A file of a generator
    /// made before the extent channel ([`IN_CHANNELS_V1`] inputs) is read with that channel's
    /// weights zero: the same function as before, whatever the extent.
    pub fn from_burnpack(bytes: &[u8]) -> Result<Self, crate::models::WeightError> {
        match cpu::convs_from_burnpack(bytes, &conv_layers()) {
            Ok(convs) => Ok(Self::new(convs)),
            Err(e) => match cpu::convs_from_burnpack(bytes, &conv_layers_with(WIDTHS, IN_CHANNELS_V1)) {
                Ok(mut convs) => {
                    convs[0] = convs[0].with_zero_input(EXTENT_CHANNEL);
                    Ok(Self::new(convs))
                }
                Err(_) => Err(e),
            },
        }
    }

    /// These weights as a burnpack file of the current generator ([`IN_CHANNELS`] inputs,
    /// float32): what a file made before the extent channel becomes.
    pub fn to_burnpack(&self) -> Vec<u8> {
        cpu::convs_to_burnpack(&conv_layers(), &self.convs)
    }

    /// Whether the extent channel has any weight: false for a generator read from a file made
    /// before it ([`Self::from_burnpack`]), which makes the same terrain at every extent.
    pub fn knows_extent(&self) -> bool {
        let (w, _) = self.convs[0].to_oihw();
        let cin = self.convs[0].cin();
        w.chunks_exact(cin * 9).any(|o| o[EXTENT_CHANNEL * 9..][..9].iter().any(|&v| v != 0.0))
    }

    /// Writes these weights into a burn generator (training starts from shipped weights).
    #[cfg(feature = "train")]
    pub fn into_model(&self, m: SketchGen) -> SketchGen {
        let mut m = m;
        crate::models::tcm::unet_into_burn(&self.convs, &mut m.enc, &mut m.dec, &mut m.out);
        m
    }

    /// Copies a burn generator's weights.
    pub fn from_model(m: &SketchGen) -> Result<Self, String> {
        let convs = m.enc.iter().chain(&m.dec).flat_map(|st| st.convs()).chain([&m.out]);
        Ok(Self::new(convs.map(cpu::conv_from_burn).collect::<Result<_, _>>()?))
    }

    /// Every convolution's weights and bias as trained, keyed by its [`conv_layers`] name (see
    /// [`cpu::convs_json`]), for reference runtimes that rebuild the network.
    pub fn convs_json(&self) -> serde_json::Value {
        cpu::convs_json(conv_layers().into_iter().map(|(name, _, _)| name).zip(&self.convs))
    }

    /// Heights / 255 (`side`², row-major) for the channel-first input `x` of a `side`² sketch.
    pub fn forward(&self, x: &[f32], side: usize, s: &mut SketchScratch, threads: usize) -> Vec<f32> {
        s.input.set_chw(x, IN_CHANNELS, side, side);
        let c = &self.run;
        for k in 0..SCALES {
            let src = if k == 0 {
                &s.input
            } else {
                cpu::pool2(&s.skips[k - 1], &mut s.pooled, threads);
                &s.pooled
            };
            cpu::conv(&c[2 * k], src, &mut s.t, Post::Relu, threads);
            let dst = if k < SCALES - 1 { &mut s.skips[k] } else { &mut s.h };
            cpu::conv(&c[2 * k + 1], &s.t, dst, Post::Relu, threads);
        }
        let d = 2 * SCALES;
        for k in (0..SCALES - 1).rev() {
            let side_k = s.skips[k].height();
            cpu::up2_concat(&s.h, &s.skips[k], side_k, &mut s.cat, threads);
            cpu::conv(&c[d + 2 * k], &s.cat, &mut s.t, Post::Relu, threads);
            cpu::conv(&c[d + 2 * k + 1], &s.t, &mut s.h, Post::Relu, threads);
        }
        cpu::conv(&c[d + 2 * (SCALES - 1)], &s.h, &mut s.out, Post::None, threads);
        let n = side * side;
        (0..n).map(|p| x[(IN_CHANNELS - 1) * n + p] + s.out.pixel(p / side, p % side)[0]).collect()
    }

    /// The terrain of a sketch on a tile `extent_m` metres wide ([`extent_value`]) on the
    /// format's 0–255 scale (stretched to span it, like the targets), [`SKETCH_PX`]²
    /// row-major: one view, as the page draws it while strokes land.
    pub fn generate(&self, sketch: &Sketch, extent_m: f64, s: &mut SketchScratch, threads: usize) -> Vec<f32> {
        self.generate_views(sketch, extent_m, 1, s, threads)
    }

    /// [`Self::generate`] averaged over the first `views` (1 to [`VIEW_ORDER`]'s 8) rotations and
    /// flips of the sketch, each output turned back before the mean, so the network's
    /// orientation-dependent errors partly cancel; with 8 views the terrain turns exactly with
    /// the sketch. Costs `views` forward passes, each with the mirrored margin ([`MARGIN_PX`]).
    pub fn generate_views(&self, sketch: &Sketch, extent_m: f64, views: usize, s: &mut SketchScratch, threads: usize) -> Vec<f32> {
        let (x, _) = assemble_input(sketch, extent_m);
        let n = SKETCH_PX * SKETCH_PX;
        let order = &VIEW_ORDER[..views.clamp(1, VIEW_ORDER.len())];
        let mut sum = vec![0f32; n];
        let framed = |x: &[f32], s: &mut SketchScratch| crop_margin(&self.forward(&with_margin(x), PADDED_PX, s, threads));
        for &t in order {
            let out = if t == 0 {
                framed(&x, s)
            } else {
                let xt = dihedral_channels(&x, SKETCH_PX, t);
                dihedral(&framed(&xt, s), SKETCH_PX, dihedral_inverse(t))
            };
            sum.iter_mut().zip(out).for_each(|(a, b)| *a += b);
        }
        let k = order.len() as f32;
        to_format_scale(sum.into_iter().map(|v| v / k).collect(), sketch)
    }
}

/// The network's output (heights / 255) for `sketch` on the format's 0–255 scale: spanning it
/// like the targets, with the sketch's band borders at their thresholds
/// ([`calibrate::to_band_scale`]).
fn to_format_scale(out: Vec<f32>, sketch: &Sketch) -> Vec<f32> {
    let mut h: Vec<f32> = out.into_iter().map(|v| v * 255.0).collect();
    calibrate::to_band_scale(&mut h, &sketch.band, SKETCH_PX);
    h
}

/// The sketch generator on burn's wgpu backend (WebGPU in the page on a hardware adapter,
/// Vulkan natively): the same network and weight file as [`SketchGenCpu`], for the page's
/// strokes when it has a GPU.
#[derive(Debug)]
pub struct SketchGenGpu {
    model: SketchGen,
    device: Device,
}

impl SketchGenGpu {
    /// Reads a generator weight file (burnpack, float32 or float16) onto `device`; a file made
    /// before the extent channel is read as [`SketchGenCpu::from_burnpack`] reads it.
    pub fn from_burnpack(bytes: &[u8], device: &Device) -> Result<Self, crate::models::WeightError> {
        let model = match crate::models::load_burnpack(SketchGen::new(device), bytes) {
            Ok(m) => m,
            Err(e) => match SketchGenCpu::from_burnpack(bytes) {
                Ok(old) => crate::models::load_burnpack(SketchGen::new(device), &old.to_burnpack()).map_err(|e| e.in_file(WEIGHT_FILE))?,
                Err(_) => return Err(e.in_file(WEIGHT_FILE)),
            },
        };
        Ok(Self { model, device: device.clone() })
    }

    /// The queued computation for `sketch`, with the mirrored margin ([`MARGIN_PX`]) cut
    /// away again (read back by the callers).
    fn launch(&self, sketch: &Sketch, extent_m: f64) -> Tensor<4> {
        let (x, _) = assemble_input(sketch, extent_m);
        let x = Tensor::<4>::from_data(burn::tensor::TensorData::new(with_margin(&x), [1, IN_CHANNELS, PADDED_PX, PADDED_PX]), &self.device);
        let (a, b) = (MARGIN_PX, MARGIN_PX + SKETCH_PX);
        self.model.forward(x).slice([0..1, 0..1, a..b, a..b])
    }

    /// [`SketchGenCpu::generate`] on the GPU, with an asynchronous readback (as browsers
    /// require for GPU buffers).
    pub async fn generate_async(&self, sketch: &Sketch, extent_m: f64) -> Result<Vec<f32>, String> {
        let data = self.launch(sketch, extent_m).into_data_async().await.map_err(|e| format!("GPU readback failed: {e:?}"))?;
        Ok(to_format_scale(data.try_to_vec::<f32>().map_err(|e| format!("unexpected result type: {e:?}"))?, sketch))
    }

    /// [`Self::generate_async`] with a blocking readback (native).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn generate_blocking(&self, sketch: &Sketch, extent_m: f64) -> Result<Vec<f32>, String> {
        Ok(to_format_scale(self.launch(sketch, extent_m).into_data().try_to_vec::<f32>().map_err(|e| format!("unexpected result type: {e:?}"))?, sketch))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The generator maps [2, 5, 64, 64] to [2, 1, 64, 64] with at most 1 M parameters.
    #[cfg(feature = "train")]
    #[test]
    fn generator_shapes_and_size() {
        let device = Device::flex();
        let g = SketchGen::new(&device);
        let x = Tensor::<4>::zeros([2, IN_CHANNELS, 64, 64], &device);
        assert_eq!(g.forward(x).dims(), [2, 1, 64, 64]);
        let p = g.parameters();
        assert!(p <= 1_000_000, "{p} parameters");
        println!("sketch generator parameters: {p}");
    }

    /// A weight file of a generator made before the extent channel is read with that channel
    /// zero and the baseline's weights moved behind it (every other weight as in the file): it
    /// makes the same terrain at 512 m and 8 km, says it does not know the extent, and keeps
    /// that through [`SketchGenCpu::to_burnpack`]; a generator with weights on the channel
    /// makes different terrain at the two extents.
    #[test]
    fn an_old_weight_file_gets_a_zero_extent_channel_and_ignores_the_extent() {
        let old_layers = conv_layers_with(WIDTHS, IN_CHANNELS_V1);
        let old = cpu::random_convs(&old_layers, 5, 0.1);
        let g = SketchGenCpu::from_burnpack(&cpu::convs_to_burnpack(&old_layers, &old)).unwrap();
        let ((w_old, b_old), (w, b)) = (old[0].to_oihw(), g.convs[0].to_oihw());
        assert_eq!(b, b_old);
        for o in 0..WIDTHS[0] {
            for i in 0..IN_CHANNELS {
                let got = &w[(o * IN_CHANNELS + i) * 9..][..9];
                match i.cmp(&EXTENT_CHANNEL) {
                    std::cmp::Ordering::Less => assert_eq!(got, &w_old[(o * IN_CHANNELS_V1 + i) * 9..][..9]),
                    std::cmp::Ordering::Equal => assert!(got.iter().all(|&v| v == 0.0)),
                    std::cmp::Ordering::Greater => assert_eq!(got, &w_old[(o * IN_CHANNELS_V1 + i - 1) * 9..][..9]),
                }
            }
        }
        assert_eq!(g.convs[1..].iter().map(Conv3::to_oihw).collect::<Vec<_>>(), old[1..].iter().map(Conv3::to_oihw).collect::<Vec<_>>());
        let sk = lopsided_sketch();
        let mut s = SketchScratch::default();
        assert!(!g.knows_extent());
        assert_eq!(g.generate(&sk, FORMAT_EXTENT_M, &mut s, 1), g.generate(&sk, 8192.0, &mut s, 1));
        assert!(!SketchGenCpu::from_burnpack(&g.to_burnpack()).unwrap().knows_extent());
        let new = SketchGenCpu::randomized(5, 0.1);
        assert!(new.knows_extent());
        assert_ne!(new.generate(&sk, FORMAT_EXTENT_M, &mut s, 1), new.generate(&sk, 8192.0, &mut s, 1));
    }

    /// The extent channel is 0 at the format's 512 m, 1 at 8 km, −0.25 at 256 m, and clamped
    /// outside [`EXTENT_RANGE_M`] (a non-finite extent reads as the format's).
    #[test]
    fn the_extent_channel_is_a_quarter_of_log2_of_the_extent_over_512_m() {
        assert_eq!(extent_value(512.0), 0.0);
        assert_eq!(extent_value(8192.0), 1.0);
        assert_eq!(extent_value(256.0), -0.25);
        assert_eq!(extent_value(100.0), -0.25);
        assert_eq!(extent_value(1e9), 1.25);
        assert_eq!(extent_value(f64::NAN), 0.0);
    }

    /// The CPU kernels compute the burn generator: random weights (uniform ±0.1, biases too)
    /// on a 64² input with 1 and 2 threads; every output within 1e-4 (on a 0–1 scale).
    #[cfg(feature = "train")]
    #[test]
    fn cpu_forward_equals_burn_forward() {
        let device = Device::flex();
        let g = crate::models::random_weights(SketchGen::new(&device), &device, 11, 0.1);
        let cpu_g = SketchGenCpu::from_model(&g).unwrap();
        let side = 64;
        let x: Vec<f32> = (0..IN_CHANNELS * side * side).map(|i| ((i * 37 % 101) as f32 / 101.0) * if i % 7 == 0 { -1.0 } else { 1.0 }).collect();
        let burn_out: Vec<f32> =
            g.forward(Tensor::<4>::from_data(burn::tensor::TensorData::new(x.clone(), [1, IN_CHANNELS, side, side]), &device)).into_data().try_to_vec::<f32>().unwrap();
        let mut scratch = SketchScratch::default();
        for threads in [1, 2] {
            let ours = cpu_g.forward(&x, side, &mut scratch, threads);
            let base = &x[(IN_CHANNELS - 1) * side * side..];
            let scale = burn_out.iter().zip(base).map(|(v, b)| (v - b).abs()).fold(0f32, f32::max);
            assert!(scale > 1e-3, "the random network's correction is not trivially zero ({scale})");
            let worst = ours.iter().zip(&burn_out).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
            assert!(worst < 1e-4, "{threads} threads: CPU and burn differ by {worst}");
        }
    }

    /// Widened for kernels of multiples of 8 channels, every layer the CPU runs has a multiple
    /// of 8 outputs, but the single-output last one, which reads a multiple of 8 inputs (the
    /// full-size stage 16 wide where the trained one is 12). Widened for AVX-512, which runs
    /// any count, every layer is as trained but the last two run (12 → 16 outputs, 16 → 1).
    #[test]
    fn every_layer_the_cpu_runs_has_channels_in_blocks_of_eight_or_as_trained_on_avx512() {
        let convs = cpu::random_convs(&conv_layers(), 3, 0.1);
        let g = SketchGenCpu::with_widths(convs.clone(), false);
        assert_eq!(g.run.len(), g.convs.len());
        for ((name, _, _), c) in conv_layers().iter().zip(&g.run) {
            let blocks = if c.cout() == 1 { c.cin() % 8 == 0 } else { c.cout() % 8 == 0 };
            assert!(blocks, "{name}: {} → {} channels", c.cin(), c.cout());
        }
        assert_eq!((g.convs[0].cout(), g.run[0].cout()), (12, 16));
        let g = SketchGenCpu::with_widths(convs, true);
        let n = g.run.len();
        let shapes: Vec<(usize, usize)> = g.run.iter().map(|c| (c.cin(), c.cout())).collect();
        let trained: Vec<(usize, usize)> = conv_layers().iter().map(|&(_, cout, cin)| (cin, cout)).collect();
        // dec.0.b, the full-size decoder's second layer, runs last before the output layer.
        let d = 2 * SCALES + 1;
        assert_eq!(conv_layers()[d].0, "dec.0.b");
        for k in (0..n).filter(|&k| k != d && k != n - 1) {
            assert_eq!(shapes[k], trained[k], "{}", conv_layers()[k].0);
        }
        assert_eq!((shapes[d], shapes[n - 1]), ((12, 16), (16, 1)));
    }

    /// The generator widened for kernels of multiples of 8 and widened for AVX-512 gives the
    /// same heights for the same sketch (random weights; within 1e-6 of the 0–1 scale, the
    /// only difference being the order-free sign of a zero).
    #[test]
    fn both_widenings_give_the_same_heights() {
        let convs = cpu::random_convs(&conv_layers(), 5, 0.1);
        let (a, b) = (SketchGenCpu::with_widths(convs.clone(), false), SketchGenCpu::with_widths(convs, true));
        let x = assemble_input(&lopsided_sketch(), FORMAT_EXTENT_M).0;
        let (ha, hb) = (a.forward(&x, SKETCH_PX, &mut Default::default(), 2), b.forward(&x, SKETCH_PX, &mut Default::default(), 2));
        let worst = ha.iter().zip(&hb).map(|(p, q)| (p - q).abs()).fold(0f32, f32::max);
        assert!(worst <= 1e-6, "{worst}");
        assert!(ha.iter().any(|&v| v != ha[0]), "a flat output tests nothing");
    }

    /// The exact generator runs every layer unfused and the default one every layer fused; on
    /// a CPU with FMA kernels their heights differ somewhere, by last bits only (≤ 1e-5 of the
    /// 0–1 scale).
    #[test]
    fn the_exact_generator_is_the_unfused_one_and_differs_from_the_fused_in_last_bits_only() {
        let g = SketchGenCpu::randomized(5, 0.1);
        let e = g.exact();
        assert!(g.run.iter().all(|c| c.is_fused()) && e.run.iter().all(|c| !c.is_fused()));
        let x = assemble_input(&lopsided_sketch(), FORMAT_EXTENT_M).0;
        let (hg, he) = (g.forward(&x, SKETCH_PX, &mut Default::default(), 1), e.forward(&x, SKETCH_PX, &mut Default::default(), 1));
        let worst = hg.iter().zip(&he).map(|(p, q)| (p - q).abs()).fold(0f32, f32::max);
        assert!(worst <= 1e-5, "{worst}");
        if cpu::Kernels::Best.widest() != "portable" {
            assert!(worst > 0.0, "fused and unfused gave the same bits");
        }
    }

    /// The margin mirrors the tile without repeating its edge: padded pixel (0, 0) is pixel
    /// (8, 8), (8, 8) is (0, 0), (263, 270) is (255, 248); each channel on its own; and the
    /// centre cut out again is the input.
    #[test]
    fn the_margin_is_the_tile_mirrored_at_its_edges_and_its_centre_the_tile() {
        let n = SKETCH_PX;
        let x: Vec<f32> = (0..2 * n * n).map(|p| (p / (n * n)) as f32 * 1e6 + ((p / n) % n) as f32 * 1000.0 + (p % n) as f32).collect();
        let big = with_margin(&x);
        assert_eq!(big.len(), 2 * PADDED_PX * PADDED_PX);
        let at = |c: usize, y: usize, x: usize| big[(c * PADDED_PX + y) * PADDED_PX + x];
        assert_eq!((at(0, 0, 0), at(0, 8, 8), at(0, 263, 270), at(1, 9, 0)), (8008.0, 0.0, 255_248.0, 1e6 + 1008.0));
        assert_eq!(crop_margin(&big[..PADDED_PX * PADDED_PX]), x[..n * n]);
    }

    /// A sketch that no rotation or flip maps to itself: bands rising to the east, a ridge
    /// along one row in the north-west, a valley down one column in the south.
    fn lopsided_sketch() -> Sketch {
        let mut sk = Sketch::filled(0);
        for y in 0..SKETCH_PX {
            for x in 0..SKETCH_PX {
                let p = y * SKETCH_PX + x;
                sk.band[p] = ((x * 4 / SKETCH_PX) as u8 + u8::from(y < 40)).min(3);
                sk.ridge[p] = y == 60 && x < 100;
                sk.valley[p] = x == 30 && y > 150;
            }
        }
        sk
    }

    /// `sk` under dihedral transform `t`.
    fn turned(sk: &Sketch, t: usize) -> Sketch {
        let turn = |v: Vec<f32>| dihedral(&v, SKETCH_PX, t);
        let turn_mask = |m: &[bool]| turn(m.iter().map(|&b| f32::from(u8::from(b))).collect()).into_iter().map(|v| v > 0.5).collect();
        let band = turn(sk.band.iter().map(|&b| f32::from(b)).collect()).into_iter().map(|v| v as u8).collect();
        Sketch { band, ridge: turn_mask(&sk.ridge), valley: turn_mask(&sk.valley) }
    }

    /// With all 8 views, the terrain of the sketch turned a quarter and of the sketch mirrored
    /// is the turned (mirrored) terrain within 0.01 (0–255 scale); with 1 view a random
    /// network's terrain differs by more than 0.5 somewhere, so the averaging is what makes it
    /// turn.
    #[test]
    fn eight_views_turn_the_terrain_with_a_quarter_turned_or_mirrored_sketch() {
        let g = SketchGenCpu::randomized(5, 0.1);
        let sk = lopsided_sketch();
        let mut s = SketchScratch::default();
        let all = g.generate_views(&sk, FORMAT_EXTENT_M, VIEW_ORDER.len(), &mut s, 2);
        let one = g.generate(&sk, FORMAT_EXTENT_M, &mut s, 2);
        let worst = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
        for t in [1, 4] {
            let sk_t = turned(&sk, t);
            let d8 = worst(&g.generate_views(&sk_t, FORMAT_EXTENT_M, VIEW_ORDER.len(), &mut s, 2), &dihedral(&all, SKETCH_PX, t));
            assert!(d8 < 0.01, "transform {t}: 8 views differ from the turned terrain by {d8}");
            let d1 = worst(&g.generate(&sk_t, FORMAT_EXTENT_M, &mut s, 2), &dihedral(&one, SKETCH_PX, t));
            assert!(d1 > 0.5, "transform {t}: one view already turns with the sketch ({d1}), so the test shows nothing");
        }
        assert!(worst(&all, &one) > 0.5, "8 views equal 1 view");
    }
}
