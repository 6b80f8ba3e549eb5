//! The terrain completion module (TCM): a compact conditional UNet that makes one tile of the
//! world at 128 m (32² samples, [`TILE_PX`]) from whichever of its 8 neighbours the schedule
//! gives it, a coarse seeded "macro" field (the absolute level and the large-scale relief) and
//! seeded noise. Learned ×2 steps then bring it to the world's 32 m.
//!
//! Input ([`IN_CHANNELS`] × [`CONTEXT_PX`]², the 3×3 tiles at 128 m, all heights relative to the
//! macro level of the centre and divided by [`HEIGHT_SCALE_M`]):
//! 0. known heights (zero where a tile is not an input, and in the centre),
//! 1. predict mask (1 on the centre), 2. available mask, 3. unavailable mask (as the paper),
//! 4. the macro field (bilinear between the nine tile centres),
//! 5. fine noise (one value per pixel) and 6. coarse noise (one value per 12² block), both
//!    drawn from the tile's seed with integer arithmetic only, so every platform draws the same,
//! 7. the ruggedness field (bilinear between the nine tiles' ruggedness, [`tile_ruggedness`]):
//!    how much relief the tiles have below the 1 km scale. In training it is measured on the
//!    real window; in the world it is seeded, so the world has plains, hills and mountains.
//!
//! Network: an encoder of two 3×3 convolutions + ReLU per scale (96², 48², 24², 12², 6²; 2×2
//! mean pooling between them) and a decoder that upsamples (nearest), concatenates the skip and
//! applies two convolutions, computed only on the centre crop the output needs
//! ([`DECODER_CROP`]); a 3×3 convolution makes the centre tile. No normalisation layers, so
//! training and inference compute the same function.

use burn::module::Module;
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};

use crate::grid::mix64;
use crate::grid::schedule::{PHASES, dependency_offsets};
use crate::models::cpu::{self, Conv3, Map, Post};

/// Spacing of the TCM's tiles (metres per sample).
pub const COARSE_SPACING_M: f64 = 128.0;
/// Side of a tile at [`COARSE_SPACING_M`] (samples): the world's 4096 m tile.
pub const TILE_PX: usize = 32;
/// Side of the 3×3-tile context window (samples).
pub const CONTEXT_PX: usize = 3 * TILE_PX;
/// Heights enter and leave the network relative to the centre's macro level, in units of this
/// many metres (the reference's global standard deviation).
pub const HEIGHT_SCALE_M: f32 = 500.0;
/// Input channels (see the module documentation).
pub const IN_CHANNELS: usize = 8;
/// Input channels of the first weights, made before the ruggedness channel (a training run
/// can start from them: [`TcmCpu::widened`]).
pub const IN_CHANNELS_V1: usize = 7;
/// Reference relief of the ruggedness channel (metres): a tile whose heights differ from their
/// 1.2 km mean by this much (root mean square) has ruggedness 0; the channel is the natural
/// logarithm of the ratio.
pub const RUGGEDNESS_REF_M: f32 = 30.0;
/// Side (samples at 128 m) of the box whose mean [`tile_ruggedness`] subtracts: 1152 m.
pub const RUGGEDNESS_BOX_PX: usize = 9;
/// Side (samples) of the coarse noise blocks.
pub const COARSE_NOISE_PX: usize = 12;
/// Channels of the encoder scales 96², 48², 24², 12² and the 6² bottleneck.
pub const WIDTHS: [usize; 5] = [24, 48, 72, 96, 112];
/// Side of the centre crop the decoder computes at 96², 48², 24² and 12²: the output tile plus
/// the rows its remaining convolutions read (3 at 96², 2 more per coarser scale, rounded up).
pub const DECODER_CROP: [usize; 4] = [38, 24, 16, 12];

/// Which of the 3×3 tiles are inputs, for the schedule's phase `p` (0..4, see
/// [`crate::grid::schedule::PHASES`]), in row-major order (dj = −1, 0, 1; di = −1, 0, 1): the
/// schedule's dependencies; the centre is never an input.
pub fn phase_mask(p: usize) -> [bool; 9] {
    let mut m = [false; 9];
    for &(di, dj) in dependency_offsets(PHASES[p]) {
        m[((dj + 1) * 3 + di + 1) as usize] = true;
    }
    m
}

/// A standard-normal-like value from 64 random bits, with integer arithmetic and exact float
/// conversions only (the sum of four 16-bit uniforms, centred and scaled to unit variance), so
/// it is bit-identical on every platform.
pub fn gauss(bits: u64) -> f32 {
    let s: u64 = (0..4).map(|k| (bits >> (16 * k)) & 0xffff).sum();
    // Four uniforms on [0, 1): mean 2, variance 4/12.
    (s as f32 / 65_536.0 - 2.0) * 1.732_050_8
}

/// A field over the context window ([`CONTEXT_PX`]²) bilinear between the nine tile-centre
/// values `centres` (row-major like [`phase_mask`]), constant beyond the outer centres: the
/// macro field (metres) and the ruggedness field. [`macro_field_cells`] with 3 cells a side.
pub fn macro_field(centres: &[f32; 9]) -> Vec<f32> {
    macro_field_cells(centres, 3)
}

/// A field over the context window ([`CONTEXT_PX`]², row-major) bilinear between the centres
/// of `k`×`k` square cells of side [`CONTEXT_PX`]` / k` samples whose values are `cells`
/// (row-major), constant beyond the outer centres. `k` = 3: one cell per tile (4096 m); 6:
/// cells of 2048 m. Panics unless `k` is at least 2 and divides [`CONTEXT_PX`] and `cells`
/// holds `k`² values.
pub fn macro_field_cells(cells: &[f32], k: usize) -> Vec<f32> {
    assert!(k >= 2 && CONTEXT_PX.is_multiple_of(k), "{k} cells a side do not divide the {CONTEXT_PX}-sample window");
    assert_eq!(cells.len(), k * k, "{k}×{k} cells need {} values, not {}", k * k, cells.len());
    let side = (CONTEXT_PX / k) as f32;
    let axis = |p: usize| -> (usize, f32) {
        // Position in units of cells from the first centre, clamped to [0, k − 1].
        let t = ((p as f32 + 0.5 - side / 2.0) / side).clamp(0.0, (k - 1) as f32);
        let i = (t as usize).min(k - 2);
        (i, t - i as f32)
    };
    let mut out = vec![0f32; CONTEXT_PX * CONTEXT_PX];
    for y in 0..CONTEXT_PX {
        let (ky, fy) = axis(y);
        for x in 0..CONTEXT_PX {
            let (kx, fx) = axis(x);
            let c = |j: usize, i: usize| cells[j * k + i];
            let top = c(ky, kx) * (1.0 - fx) + c(ky, kx + 1) * fx;
            let bottom = c(ky + 1, kx) * (1.0 - fx) + c(ky + 1, kx + 1) * fx;
            out[y * CONTEXT_PX + x] = top * (1.0 - fy) + bottom * fy;
        }
    }
    out
}

/// The level of the centre tile given `k`×`k` macro cells (metres, row-major, `k` a multiple
/// of 3): the mean of the cells that cover the centre tile (the centre cell itself for 3).
pub fn centre_level(cells: &[f32], k: usize) -> f32 {
    assert!(k.is_multiple_of(3) && cells.len() == k * k, "{k}×{k} cells do not cover the 3×3 tiles");
    let inner = k / 3..2 * k / 3;
    let sum: f32 = inner.clone().flat_map(|j| inner.clone().map(move |i| cells[j * k + i])).sum();
    sum / (k / 3 * (k / 3)) as f32
}

/// The ruggedness of each of the nine tiles of a context window `h` ([`CONTEXT_PX`]² heights,
/// metres, row-major): the natural logarithm of the root mean square difference between the
/// tile's heights and their mean over a [`RUGGEDNESS_BOX_PX`]² box (clamped at the window's
/// edges), over [`RUGGEDNESS_REF_M`]. Plains are about −2, the Pyrenees about +1.
pub fn tile_ruggedness(h: &[f32]) -> [f32; 9] {
    let n = CONTEXT_PX;
    let r = RUGGEDNESS_BOX_PX / 2;
    // Summed-area table for the box means.
    let mut sat = vec![0f64; (n + 1) * (n + 1)];
    for y in 0..n {
        for x in 0..n {
            sat[(y + 1) * (n + 1) + x + 1] = h[y * n + x] as f64 + sat[y * (n + 1) + x + 1] + sat[(y + 1) * (n + 1) + x] - sat[y * (n + 1) + x];
        }
    }
    let mut sq = [0f64; 9];
    for y in 0..n {
        let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(n));
        for x in 0..n {
            let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(n));
            let sum = sat[y1 * (n + 1) + x1] - sat[y0 * (n + 1) + x1] - sat[y1 * (n + 1) + x0] + sat[y0 * (n + 1) + x0];
            let mean = sum / ((y1 - y0) * (x1 - x0)) as f64;
            sq[(y / TILE_PX) * 3 + x / TILE_PX] += (h[y * n + x] as f64 - mean).powi(2);
        }
    }
    sq.map(|s| libm::logf((s / (TILE_PX * TILE_PX) as f64).sqrt().max(0.01) as f32 / RUGGEDNESS_REF_M))
}

/// The network's input for one tile, channel-first ([`IN_CHANNELS`] × [`CONTEXT_PX`]²):
/// `tiles` are the 3×3 tiles' heights (metres, [`TILE_PX`]² row-major each) where they are
/// inputs, `macro_centres` the macro field at the nine tile centres (metres), `rugged_centres`
/// the nine tiles' ruggedness ([`tile_ruggedness`]) and `noise_seed` the centre tile's seed.
/// Heights are taken relative to `macro_centres[4]`.
pub fn assemble_input(tiles: &[Option<&[f32]>; 9], macro_centres: &[f32; 9], rugged_centres: &[f32; 9], noise_seed: u64) -> Vec<f32> {
    assemble_input_field(tiles, &macro_field(macro_centres), macro_centres[4], rugged_centres, noise_seed)
}

/// [`assemble_input`] with the macro field given whole: `field` ([`CONTEXT_PX`]², metres,
/// row-major, e.g. [`macro_field_cells`]) and the centre tile's macro level `level` (metres)
/// that every height is taken relative to.
pub fn assemble_input_field(tiles: &[Option<&[f32]>; 9], field: &[f32], level: f32, rugged_centres: &[f32; 9], noise_seed: u64) -> Vec<f32> {
    assert_eq!(field.len(), CONTEXT_PX * CONTEXT_PX, "the macro field covers the {CONTEXT_PX}² window");
    let n = CONTEXT_PX * CONTEXT_PX;
    let mut x = vec![0f32; IN_CHANNELS * n];
    for (t, tile) in tiles.iter().enumerate() {
        let (ti, tj) = (t % 3, t / 3);
        for v in 0..TILE_PX {
            for u in 0..TILE_PX {
                let p = (tj * TILE_PX + v) * CONTEXT_PX + ti * TILE_PX + u;
                match tile {
                    _ if t == 4 => x[n + p] = 1.0,
                    Some(h) => {
                        x[p] = (h[v * TILE_PX + u] - level) / HEIGHT_SCALE_M;
                        x[2 * n + p] = 1.0;
                    }
                    None => x[3 * n + p] = 1.0,
                }
            }
        }
    }
    for (p, &m) in field.iter().enumerate() {
        x[4 * n + p] = (m - level) / HEIGHT_SCALE_M;
    }
    x[7 * n..].copy_from_slice(&macro_field(rugged_centres));
    let blocks = CONTEXT_PX / COARSE_NOISE_PX;
    for p in 0..n {
        x[5 * n + p] = gauss(mix64(noise_seed ^ (p as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)));
        let (bx, by) = (p % CONTEXT_PX / COARSE_NOISE_PX, p / CONTEXT_PX / COARSE_NOISE_PX);
        x[6 * n + p] = gauss(mix64(!noise_seed ^ ((by * blocks + bx) as u64 + 1).wrapping_mul(0xD1B5_4A32_D192_ED03)));
    }
    x
}

/// One encoder or decoder stage: two 3×3 convolutions, each followed by ReLU.
#[derive(Module, Debug)]
pub struct Stage {
    a: Conv2d,
    b: Conv2d,
}

pub(crate) fn conv3(cin: usize, cout: usize, device: &Device) -> Conv2d {
    Conv2dConfig::new([cin, cout], [3, 3]).with_padding(PaddingConfig2d::Same).init(device)
}

impl Stage {
    pub(crate) fn new(cin: usize, cout: usize, device: &Device) -> Self {
        Self { a: conv3(cin, cout, device), b: conv3(cout, cout, device) }
    }

    pub(crate) fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        relu(self.b.forward(relu(self.a.forward(x))))
    }

    /// The two convolutions (for the CPU kernels and parameter counts).
    pub fn convs(&self) -> [&Conv2d; 2] {
        [&self.a, &self.b]
    }

    /// The two convolutions, to write weights into.
    #[cfg(feature = "train")]
    pub(crate) fn convs_mut(&mut self) -> [&mut Conv2d; 2] {
        [&mut self.a, &mut self.b]
    }
}

/// Writes `convs` (network order: the encoder's and decoder's stages, then the output
/// convolution) into the burn layers of a UNet of [`Stage`]s (the TCM's and the sketch
/// generator's `into_model`).
#[cfg(feature = "train")]
pub(crate) fn unet_into_burn(convs: &[Conv3], enc: &mut [Stage], dec: &mut [Stage], out: &mut Conv2d) {
    let layers: Vec<&mut Conv2d> = enc.iter_mut().chain(dec.iter_mut()).flat_map(|st| st.convs_mut()).chain([out]).collect();
    assert_eq!(convs.len(), layers.len(), "one set of weights per convolution");
    for (c, layer) in convs.iter().zip(layers) {
        cpu::conv_into_burn(c, layer);
    }
}

/// 2×2 mean pooling of [B, C, H, W] (H, W even).
pub fn pool2(x: Tensor<4>) -> Tensor<4> {
    let [b, c, h, w] = x.dims();
    x.reshape([b, c, h / 2, 2, w / 2, 2]).mean_dim(5).mean_dim(3).reshape([b, c, h / 2, w / 2])
}

/// Nearest-neighbour ×2 upsampling of [B, C, H, W].
pub fn up2(x: Tensor<4>) -> Tensor<4> {
    let [b, c, h, w] = x.dims();
    x.reshape([b, c, h, 1, w, 1]).repeat_dim(3, 2).repeat_dim(5, 2).reshape([b, c, 2 * h, 2 * w])
}

/// The centre `side`² of [B, C, H, W].
pub fn centre(x: Tensor<4>, side: usize) -> Tensor<4> {
    let [_, _, h, w] = x.dims();
    x.narrow(2, (h - side) / 2, side).narrow(3, (w - side) / 2, side)
}

/// The TCM generator.
#[derive(Module, Debug)]
pub struct Tcm {
    enc: Vec<Stage>,
    dec: Vec<Stage>,
    out: Conv2d,
}

impl Tcm {
    /// A freshly initialised generator on `device`.
    pub fn new(device: &Device) -> Self {
        let w = WIDTHS;
        let enc = (0..5).map(|k| Stage::new(if k == 0 { IN_CHANNELS } else { w[k - 1] }, w[k], device)).collect();
        // Decoder stage k (scales 12², 24², 48², 96² for k = 3, 2, 1, 0) reads the upsampled
        // coarser stage and the skip of its scale.
        let dec = (0..4).map(|k| Stage::new(w[k + 1] + w[k], w[k], device)).collect();
        Self { enc, dec, out: conv3(w[0], 1, device) }
    }

    /// Number of learned parameters.
    pub fn parameters(&self) -> usize {
        self.num_params()
    }

    /// Makes the centre tiles: `x` is [B, [`IN_CHANNELS`], 96, 96] from [`assemble_input`];
    /// returns [B, 1, 32, 32] heights relative to the centre's macro level, in units of
    /// [`HEIGHT_SCALE_M`].
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let mut skips = Vec::with_capacity(4);
        let mut h = x;
        for (k, stage) in self.enc.iter().enumerate() {
            if k > 0 {
                h = pool2(h);
            }
            h = stage.forward(h);
            if k < 4 {
                skips.push(h.clone());
            }
        }
        for k in (0..4).rev() {
            let crop = DECODER_CROP[k];
            let up = centre(up2(h), crop);
            let skip = centre(skips[k].clone(), crop);
            h = self.dec[k].forward(Tensor::cat(vec![up, skip], 1));
        }
        centre(self.out.forward(h), TILE_PX)
    }
}

/// Names and shapes (name, output channels, input channels) of the generator's convolutions
/// in network order, as burn names them in a weight file.
pub fn conv_layers() -> Vec<(String, usize, usize)> {
    conv_layers_with(IN_CHANNELS)
}

/// [`conv_layers`] of a generator with `in_channels` input channels.
fn conv_layers_with(in_channels: usize) -> Vec<(String, usize, usize)> {
    let w = WIDTHS;
    let mut v = Vec::new();
    for k in 0..5 {
        let cin = if k == 0 { in_channels } else { w[k - 1] };
        v.push((format!("enc.{k}.a"), w[k], cin));
        v.push((format!("enc.{k}.b"), w[k], w[k]));
    }
    for k in 0..4 {
        v.push((format!("dec.{k}.a"), w[k], w[k + 1] + w[k]));
        v.push((format!("dec.{k}.b"), w[k], w[k]));
    }
    v.push(("out".into(), 1, w[0]));
    v
}

/// Reused activation buffers of [`TcmCpu::forward`].
#[derive(Default)]
pub struct TcmScratch {
    input: Map,
    skips: [Map; 4],
    pooled: Map,
    t: Map,
    h: Map,
    cat: Map,
    out: Map,
}

/// The TCM generator on the project's own CPU kernels ([`crate::models::cpu`]): the same
/// network as [`Tcm::forward`] without a tensor framework.
#[derive(Clone, Debug)]
pub struct TcmCpu {
    /// Convolutions in the order of [`conv_layers`].
    convs: Vec<Conv3>,
}

impl TcmCpu {
    /// Every layer random (uniform ±`amplitude`, from `seed`), for tests.
    pub fn randomized(seed: u64, amplitude: f32) -> Self {
        Self { convs: cpu::random_convs(&conv_layers(), seed, amplitude) }
    }

    /// Reads a generator weight file (burnpack, as training writes it).
    pub fn from_burnpack(bytes: &[u8]) -> Result<Self, crate::models::WeightError> {
        Ok(Self { convs: cpu::convs_from_burnpack(bytes, &conv_layers())? })
    }

    /// Reads a weight file of the first generator ([`IN_CHANNELS_V1`] inputs, no ruggedness
    /// channel) and widens its first layer with zero weights for the channels it lacks: the
    /// same function of the first seven channels, the starting point of a training run.
    pub fn widened(bytes: &[u8]) -> Result<Self, crate::models::WeightError> {
        let mut convs = cpu::convs_from_burnpack(bytes, &conv_layers_with(IN_CHANNELS_V1))?;
        convs[0] = convs[0].widened(convs[0].cout(), IN_CHANNELS);
        Ok(Self { convs })
    }

    /// Writes these weights into a burn generator (the start of a training run).
    #[cfg(feature = "train")]
    pub fn into_model(&self, m: Tcm) -> Tcm {
        let mut m = m;
        unet_into_burn(&self.convs, &mut m.enc, &mut m.dec, &mut m.out);
        m
    }

    /// Copies a burn generator's weights.
    pub fn from_model(m: &Tcm) -> Result<Self, String> {
        let convs = m.enc.iter().chain(&m.dec).flat_map(|st| st.convs()).chain([&m.out]);
        Ok(Self { convs: convs.map(cpu::conv_from_burn).collect::<Result<_, _>>()? })
    }

    /// One tile: `x` from [`assemble_input`] (channel-first); returns the centre tile
    /// ([`TILE_PX`]², row-major) relative to the macro level in units of [`HEIGHT_SCALE_M`].
    pub fn forward(&self, x: &[f32], s: &mut TcmScratch, threads: usize) -> Vec<f32> {
        s.input.set_chw(x, IN_CHANNELS, CONTEXT_PX, CONTEXT_PX);
        unet(|l| &self.convs[l], |_| None, s, threads, cpu::Kernels::chosen(), |_, _| {})
    }
}

/// The generator's layers on the CPU kernels in the order it runs them, from `s.input`:
/// `layer(l)` is convolution `l` ([`conv_layers`] order); `after(Some(l), map)` is called on
/// each ReLU layer's output and `after(None, map)` on each pooled map, before the next layer
/// reads it (the integer-exact TCM rounds them there), unless `grid(l)` gives the scales of
/// the integer grid ([`cpu::requantize`], ±[`crate::models::exact::ACT_LEVELS`]) that the
/// threads making its rows round them to. Returns the output layer's centre tile.
#[allow(clippy::too_many_arguments)]
fn unet<'a>(
    layer: impl Fn(usize) -> &'a Conv3,
    grid: impl Fn(usize) -> Option<Vec<f32>>,
    s: &mut TcmScratch,
    threads: usize,
    kernels: cpu::Kernels,
    mut after: impl FnMut(Option<usize>, &mut Map),
) -> Vec<f32> {
    let conv = |l: usize, src: &Map, dst: &mut Map, after: &mut dyn FnMut(Option<usize>, &mut Map)| match grid(l) {
        Some(scale) => cpu::conv_on_grid(layer(l), src, dst, Post::Relu, &scale, crate::models::exact::ACT_LEVELS, threads, kernels),
        None => {
            cpu::conv_impl(layer(l), src, dst, Post::Relu, threads, kernels);
            after(Some(l), dst);
        }
    };
    // Encoder: stage k reads the input (k = 0) or the pooled previous stage.
    for k in 0..5 {
        let src = if k == 0 {
            &s.input
        } else {
            cpu::pool2(&s.skips[k - 1], &mut s.pooled, threads);
            after(None, &mut s.pooled);
            &s.pooled
        };
        conv(2 * k, src, &mut s.t, &mut after);
        let dst = if k < 4 { &mut s.skips[k] } else { &mut s.h };
        conv(2 * k + 1, &s.t, dst, &mut after);
    }
    // Decoder: upsample, take the centre crop beside the skip's, two convolutions.
    for k in (0..4).rev() {
        cpu::up2_concat(&s.h, &s.skips[k], DECODER_CROP[k], &mut s.cat, threads);
        conv(10 + 2 * k, &s.cat, &mut s.t, &mut after);
        conv(11 + 2 * k, &s.t, &mut s.h, &mut after);
    }
    cpu::conv_impl(layer(18), &s.h, &mut s.out, Post::None, threads, kernels);
    let off = (DECODER_CROP[0] - TILE_PX) / 2;
    let mut tile = Vec::with_capacity(TILE_PX * TILE_PX);
    for y in 0..TILE_PX {
        for xx in 0..TILE_PX {
            tile.push(s.out.pixel(y + off, xx + off)[0]);
        }
    }
    tile
}

/// Grid exponent of the integer-exact TCM's input (every channel: 1/256 of a unit, about 2 m
/// of height; [`TcmExact`]).
pub const EXACT_INPUT_EXP: i32 = -8;

/// Largest input level (magnitude) of the integer-exact TCM: ±8 units (±4,000 m from the
/// macro level; noise ±7σ).
pub const EXACT_INPUT_LEVELS: f32 = 2047.0;

/// The integer-exact TCM's activation grids ([`TcmExact::calibrate`]) for the TCM weight files
/// they were calibrated on, by [`crate::models::weights_hash`] of the file: the shipped
/// weights' from the world's tiles −3…2 of seeds 1–4 (`terrain tcm-calibrate`).
pub const EXACT_CALIBRATIONS: &[(&str, &[i32])] = &[("76504e20", &[-7, -6, -6, -7, -7, -6, -7, -8, -9, -10, -7, -8, -7, -9, -8, -9, -9, -9])];

/// The activation grids of [`EXACT_CALIBRATIONS`] for the TCM weight file whose hash is
/// `tcm_hash`, if it has them.
pub fn exact_calibration(tcm_hash: &str) -> Option<&'static [i32]> {
    EXACT_CALIBRATIONS.iter().find(|(h, _)| *h == tcm_hash).map(|(_, e)| *e)
}

/// The TCM on integer grids ([`crate::models::exact`]): the same network as [`TcmCpu`], with
/// 9-bit weights (fewer where the bound on the sums needs it) and 10-bit activations carried
/// in f32, so that every kernel (portable, AVX2, AVX-512 with fused multiply-adds, the page's
/// SIMD128) and a GPU's convolutions give the same bits.
#[derive(Clone, Debug)]
pub struct TcmExact {
    layers: Vec<crate::models::exact::ExactConv>,
    /// Activation grid exponent of each layer but the output (network order).
    act_exp: Vec<i32>,
}

impl TcmExact {
    /// Quantizes `tcm` with the activation grids `act_exp` (one per layer but the output, in
    /// [`conv_layers`] order, e.g. from [`TcmExact::calibrate`]).
    pub fn new(tcm: &TcmCpu, act_exp: &[i32]) -> Result<Self, cpu::LayerError> {
        use crate::models::exact::{ACT_LEVELS, pow2, quantize};
        let c = &tcm.convs;
        assert_eq!(act_exp.len(), c.len() - 1, "one activation grid per layer but the output");
        let mut layers = Vec::with_capacity(c.len());
        let act = |l: usize, n: usize| (vec![act_exp[l]; n], vec![(0.0, ACT_LEVELS); n]);
        for (l, conv) in c.iter().enumerate() {
            let (exp, max) = match l {
                // The input: the three masks (channels 1–3) are 0 or 1, the others signed.
                0 => (
                    vec![EXACT_INPUT_EXP; conv.cin()],
                    (0..conv.cin()).map(|i| if (1..=3).contains(&i) { (0.0, pow2(-EXACT_INPUT_EXP)) } else { (-EXACT_INPUT_LEVELS, EXACT_INPUT_LEVELS) }).collect(),
                ),
                // Encoder: the previous layer (the pooled skip's grid is its own).
                1..=9 => act(l - 1, conv.cin()),
                // Decoder stage k's first layer: the coarser map (enc.4.b, or dec.k+1.b) upsampled,
                // then skip k (enc.k.b).
                10 | 12 | 14 | 16 => {
                    let k = (l - 10) / 2;
                    let coarse = if k == 3 { 9 } else { 11 + 2 * (k + 1) };
                    let n_coarse = WIDTHS[k + 1];
                    let (mut e, mut m) = act(coarse, n_coarse);
                    let (e2, m2) = act(2 * k + 1, WIDTHS[k]);
                    e.extend(e2);
                    m.extend(m2);
                    (e, m)
                }
                // The output layer reads the last decoder stage (dec.0.b).
                18 => act(11, conv.cin()),
                _ => act(l - 1, conv.cin()),
            };
            // Sums of integers below 2²⁴ are exact in any order, fused or not: the fastest kernels.
            let mut q = quantize(conv, &exp, &max)?;
            q.conv = q.conv.with_fused(true);
            layers.push(q);
        }
        Ok(Self { layers, act_exp: act_exp.to_vec() })
    }

    /// The largest sum any layer can form (below 2²⁴).
    pub fn bound(&self) -> f64 {
        self.layers.iter().map(|l| l.bound).fold(0.0, f64::max)
    }

    /// One tile, as [`TcmCpu::forward`]: `x` from [`assemble_input`]; the centre tile relative
    /// to the macro level in units of [`HEIGHT_SCALE_M`], a multiple of the output layer's grid.
    pub fn forward(&self, x: &[f32], s: &mut TcmScratch, threads: usize) -> Vec<f32> {
        self.run(x, s, threads, cpu::Kernels::chosen(), None)
    }

    /// [`TcmExact::forward`] on `kernels`; `record` gets each layer's largest value before
    /// rounding (real units, after the ReLU).
    pub(crate) fn run(&self, x: &[f32], s: &mut TcmScratch, threads: usize, kernels: cpu::Kernels, mut record: Option<&mut [f32]>) -> Vec<f32> {
        use crate::models::exact::{ACT_LEVELS, pow2};
        s.input.set_chw(x, IN_CHANNELS, CONTEXT_PX, CONTEXT_PX);
        cpu::requantize(&mut s.input, &[pow2(-EXACT_INPUT_EXP); IN_CHANNELS], EXACT_INPUT_LEVELS);
        let ones = [1.0; WIDTHS[4]];
        let recording = record.is_some();
        let tile = unet(
            |l| &self.layers[l].conv,
            // Without a record, each layer's rows are rounded by the threads that made them.
            |l| (!recording).then(|| self.layers[l].to_grid(self.act_exp[l])),
            s,
            threads,
            kernels,
            |l, map| match l {
                Some(l) => {
                    let layer = &self.layers[l];
                    if let Some(r) = record.as_deref_mut() {
                        r[l] = crate::models::exact::largest(map, |c| pow2(layer.acc_exp[c]), r[l]);
                    }
                    cpu::requantize(map, &layer.to_grid(self.act_exp[l]), ACT_LEVELS);
                }
                None => cpu::requantize(map, &ones[..map.channels()], ACT_LEVELS),
            },
        );
        let unit = pow2(self.layers[18].acc_exp[0]);
        tile.into_iter().map(|v| v * unit).collect()
    }

    /// This network's integer weights in a burn generator on `device` (for
    /// [`TcmExact::forward_burn`]).
    pub fn to_burn(&self, device: &Device) -> Result<Tcm, crate::models::WeightError> {
        let convs: Vec<Conv3> = self.layers.iter().map(|l| l.conv.clone()).collect();
        crate::models::load_burnpack(Tcm::new(device), &cpu::convs_to_burnpack(&conv_layers(), &convs))
    }

    /// [`TcmExact::forward`] on burn's backends (a GPU's convolutions, whatever their order of
    /// sums): `m` from [`TcmExact::to_burn`], `x` [B, [`IN_CHANNELS`], 96, 96] from
    /// [`assemble_input`]; returns [B, 1, 32, 32], the same bits as the CPU kernels.
    pub fn forward_burn(&self, m: &Tcm, x: Tensor<4>) -> Tensor<4> {
        use crate::models::exact::{ACT_LEVELS, pow2};
        let grid = crate::models::exact::grid_burn;
        let inputs = vec![pow2(-EXACT_INPUT_EXP); IN_CHANNELS];
        let mut h = grid(x, &inputs, EXACT_INPUT_LEVELS);
        let conv = |l: usize, conv: &Conv2d, v: Tensor<4>| grid(relu(conv.forward(v)), &self.layers[l].to_grid(self.act_exp[l]), ACT_LEVELS);
        let mut skips = Vec::with_capacity(4);
        for (k, stage) in m.enc.iter().enumerate() {
            if k > 0 {
                h = grid(pool2(h), &vec![1.0; WIDTHS[k - 1]], ACT_LEVELS);
            }
            h = conv(2 * k + 1, &stage.b, conv(2 * k, &stage.a, h));
            if k < 4 {
                skips.push(h.clone());
            }
        }
        for k in (0..4).rev() {
            let crop = DECODER_CROP[k];
            let cat = Tensor::cat(vec![centre(up2(h), crop), centre(skips[k].clone(), crop)], 1);
            h = conv(11 + 2 * k, &m.dec[k].b, conv(10 + 2 * k, &m.dec[k].a, cat));
        }
        centre(m.out.forward(h), TILE_PX) * pow2(self.layers[18].acc_exp[0])
    }

    /// Activation grids for `tcm` from network inputs `inputs` ([`assemble_input`]): layer by
    /// layer, the coarsest power of two on which the layer's largest value (with the grids
    /// already chosen before it) needs at most [`crate::models::exact::ACT_LEVELS`] levels.
    pub fn calibrate(tcm: &TcmCpu, inputs: &[Vec<f32>]) -> Result<Vec<i32>, cpu::LayerError> {
        let n = tcm.convs.len() - 1;
        let mut exps = vec![0; n];
        let mut s = TcmScratch::default();
        // In the order the network runs them: the encoder, then the decoder from its coarsest
        // stage (each layer's inputs on grids already chosen).
        let order = (0..10).chain((0..4).rev().flat_map(|k| [10 + 2 * k, 11 + 2 * k]));
        for l in order {
            let net = Self::new(tcm, &exps)?;
            let mut most = vec![0f32; n + 1];
            for x in inputs {
                net.run(x, &mut s, 1, cpu::Kernels::chosen(), Some(&mut most));
            }
            exps[l] = crate::models::exact::grid_exp(most[l].max(f32::MIN_POSITIVE) as f64, crate::models::exact::ACT_LEVELS as f64);
        }
        Ok(exps)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The noise has mean ≈ 0 and variance ≈ 1 over 100,000 draws, and is the same on every
    /// call for the same bits.
    #[test]
    fn gauss_has_unit_variance_and_zero_mean() {
        let v: Vec<f32> = (0..100_000u64).map(|k| gauss(mix64(k))).collect();
        let mean = v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64;
        let var = v.iter().map(|&x| (x as f64 - mean).powi(2)).sum::<f64>() / v.len() as f64;
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.02, "variance {var}");
        assert_eq!(gauss(mix64(7)).to_bits(), gauss(mix64(7)).to_bits());
    }

    /// The macro field equals the nine centre values at the tile centres, is linear between
    /// them and constant beyond the outer centres.
    #[test]
    fn macro_field_interpolates_the_tile_centres() {
        let c: [f32; 9] = [0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0];
        let m = macro_field(&c);
        let at = |x: usize, y: usize| m[y * CONTEXT_PX + x];
        // The centre tile's centre lies between pixels 47 and 48 (and 15, 16 of every tile
        // along the other axis): the mean of the four pixels around it is its value.
        let mid = |x: usize, y: usize| (at(x, y) + at(x + 1, y) + at(x, y + 1) + at(x + 1, y + 1)) / 4.0;
        assert!((mid(47, 47) - c[4]).abs() < 1e-4, "centre: {}", mid(47, 47));
        // Outer centres: everything outward of them is clamped to their value.
        assert_eq!(at(15, 15), c[0]);
        assert_eq!(at(95, 0), c[2]);
        assert_eq!(at(0, 95), c[6]);
        assert_eq!(at(0, 0), at(10, 10), "constant beyond the outer centres");
        assert!((at(95, 95) - 80.0).abs() < 1e-4);
        let step = at(40, 48) - at(39, 48);
        assert!((step - 10.0 / 32.0).abs() < 1e-4, "linear in x: {step}");
    }

    /// With 6 cells a side (2048 m), the field is the plane through the cell values where they
    /// lie on one (10 m per cell in x, 100 m in y) to within 1e-3 m between the outer cell
    /// centres (pixels 8 to 88) and the outer value beyond them; the centre level is the
    /// mean of the four cells over the centre tile, and with 3 cells the centre cell.
    #[test]
    fn six_cell_field_is_the_plane_through_the_cells_and_the_level_their_centre_mean() {
        let k = 6;
        let cells: Vec<f32> = (0..k * k).map(|q| 10.0 * (q % k) as f32 + 100.0 * (q / k) as f32).collect();
        let m = macro_field_cells(&cells, k);
        let plane = |p: usize| ((p as f32 + 0.5 - 8.0) / 16.0).clamp(0.0, 5.0);
        for y in 0..CONTEXT_PX {
            for x in 0..CONTEXT_PX {
                let want = 10.0 * plane(x) + 100.0 * plane(y);
                assert!((m[y * CONTEXT_PX + x] - want).abs() < 1e-3, "({x}, {y}): {} against {want}", m[y * CONTEXT_PX + x]);
            }
        }
        assert_eq!(m[0], cells[0], "flat beyond the first cell's centre");
        assert_eq!(centre_level(&cells, 6), (cells[14] + cells[15] + cells[20] + cells[21]) / 4.0);
        assert_eq!(centre_level(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0], 3), 5.0);
    }

    /// The input marks exactly the given neighbours as available, the centre as predicted and
    /// the rest as unavailable, puts heights relative to the centre's macro level, and its noise
    /// depends on the seed only.
    #[test]
    fn input_channels_follow_the_phase_masks() {
        let n = CONTEXT_PX * CONTEXT_PX;
        let tile = vec![600.0f32; TILE_PX * TILE_PX];
        let centres = [100.0; 9];
        for p in 0..4 {
            let mask = phase_mask(p);
            let tiles: [Option<&[f32]>; 9] = std::array::from_fn(|t| mask[t].then_some(tile.as_slice()));
            let rugged = [0.5; 9];
            let x = assemble_input(&tiles, &centres, &rugged, 42);
            let sums: Vec<f32> = (0..4).map(|c| x[c * n..(c + 1) * n].iter().sum()).collect();
            let avail = mask.iter().filter(|&&m| m).count() as f32;
            let per = (TILE_PX * TILE_PX) as f32;
            assert_eq!(sums[1], per, "phase {p}: predict mask");
            assert_eq!(sums[2], avail * per, "phase {p}: available");
            assert_eq!(sums[3], (8.0 - avail) * per, "phase {p}: unavailable");
            assert!((sums[0] - avail * per * 1.0).abs() < 1e-2, "phase {p}: heights (600 − 100) / 500 = 1");
            assert!(x[4 * n..5 * n].iter().all(|&v| v == 0.0), "flat macro field at the centre's level");
            assert!(x[7 * n..].iter().all(|&v| v == 0.5), "the ruggedness field");
            let y = assemble_input(&tiles, &centres, &rugged, 43);
            assert_eq!(x[..5 * n], y[..5 * n]);
            assert_ne!(x[5 * n..7 * n], y[5 * n..7 * n], "the noise follows the seed");
            assert_eq!(x[7 * n..], y[7 * n..]);
        }
        assert_eq!([phase_mask(1)[3], phase_mask(1)[5], phase_mask(1)[1]], [true, true, false]);
    }

    /// Ruggedness: a flat window is at the floor (ln(0.01 / 30)); a tile of ±60 m
    /// checkerboard relief at the 2-sample scale measures ln(60 / 30) within 0.05, its flat
    /// neighbours stay near the floor except where the box reaches across the edge.
    #[test]
    fn tile_ruggedness_measures_relief_below_a_kilometre() {
        let flat = vec![500.0f32; CONTEXT_PX * CONTEXT_PX];
        let floor = (0.01f32 / RUGGEDNESS_REF_M).ln();
        assert!(tile_ruggedness(&flat).iter().all(|&r| (r - floor).abs() < 1e-3));
        let mut h = flat.clone();
        for y in TILE_PX..2 * TILE_PX {
            for x in TILE_PX..2 * TILE_PX {
                h[y * CONTEXT_PX + x] += if (x / 2 + y / 2) % 2 == 0 { 60.0 } else { -60.0 };
            }
        }
        let r = tile_ruggedness(&h);
        assert!((r[4] - 2f32.ln()).abs() < 0.05, "centre {}", r[4]);
        assert!(r[0] < -3.0, "corner tile {}", r[0]);
        assert!(r[1] > r[0] && r[1] < r[4], "edge tile {}", r[1]);
    }

    /// A generator of the first input layout (7 channels) widened with a zero-weight
    /// ruggedness channel computes, on the CPU, exactly what it computed before whatever the
    /// ruggedness says.
    #[test]
    fn widened_generator_ignores_the_new_channel() {
        let old = cpu::random_convs(&conv_layers_with(IN_CHANNELS_V1), 3, 0.1);
        let bytes = cpu::convs_to_burnpack(&conv_layers_with(IN_CHANNELS_V1), &old);
        let wide = TcmCpu::widened(&bytes).unwrap();
        let tile: Vec<f32> = (0..TILE_PX * TILE_PX).map(|p| 300.0 + (p % 17) as f32).collect();
        let mask = phase_mask(2);
        let tiles: [Option<&[f32]>; 9] = std::array::from_fn(|t| mask[t].then_some(tile.as_slice()));
        let mut s = TcmScratch::default();
        let a = wide.forward(&assemble_input(&tiles, &[280.0; 9], &[0.0; 9], 5), &mut s, 1);
        let b = wide.forward(&assemble_input(&tiles, &[280.0; 9], &[2.0; 9], 5), &mut s, 1);
        assert_eq!(a, b);
        assert!(a.iter().any(|v| v.abs() > 1e-4), "a random network computes something");
    }

    /// The generator maps [2, 8, 96, 96] to [2, 1, 32, 32] with at most 1 M parameters.
    #[cfg(feature = "train")]
    #[test]
    fn generator_shapes_and_size() {
        let device = Device::flex();
        let g = Tcm::new(&device);
        let x = Tensor::<4>::zeros([2, IN_CHANNELS, CONTEXT_PX, CONTEXT_PX], &device);
        assert_eq!(g.forward(x).dims(), [2, 1, TILE_PX, TILE_PX]);
        let p = g.parameters();
        assert!(p <= 1_000_000, "{p} parameters");
        println!("TCM parameters: {p}");
    }

    /// The CPU kernels compute the burn generator: random weights (uniform ±0.1, biases too)
    /// on two inputs of every phase pattern; every output within 1e-4 (units of 500 m: 5 cm).
    #[cfg(feature = "train")]
    #[test]
    fn cpu_forward_equals_burn_forward() {
        let device = Device::flex();
        let g = crate::models::random_weights(Tcm::new(&device), &device, 5, 0.1);
        let cpu_g = TcmCpu::from_model(&g).unwrap();
        let tile: Vec<f32> = (0..TILE_PX * TILE_PX).map(|p| 300.0 + 40.0 * ((p % 32) as f32 * 0.3).sin() + (p / 32) as f32).collect();
        let mut scratch = TcmScratch::default();
        for p in 0..4 {
            let mask = phase_mask(p);
            let tiles: [Option<&[f32]>; 9] = std::array::from_fn(|t| mask[t].then_some(tile.as_slice()));
            let rugged = [-1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 0.2, 0.3, 0.4];
            let x = assemble_input(&tiles, &[250.0, 260.0, 270.0, 280.0, 290.0, 300.0, 310.0, 320.0, 330.0], &rugged, 9 + p as u64);
            let burn_out: Vec<f32> = g
                .forward(Tensor::<4>::from_data(burn::tensor::TensorData::new(x.clone(), [1, IN_CHANNELS, CONTEXT_PX, CONTEXT_PX]), &device))
                .into_data()
                .try_to_vec::<f32>()
                .unwrap();
            for threads in [1, 2] {
                let ours = cpu_g.forward(&x, &mut scratch, threads);
                let worst = ours.iter().zip(&burn_out).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
                let scale = burn_out.iter().map(|v| v.abs()).fold(0f32, f32::max);
                assert!(scale > 1e-3, "phase {p}: the random network's output is not trivially zero ({scale})");
                assert!(worst < 1e-4, "phase {p}, {threads} threads: CPU and burn differ by {worst}");
            }
        }
    }

    /// The shipped TCM on integer grids ([`TcmExact`], its calibration) gives the same bits on
    /// the portable, AVX2 and widest CPU kernels at 1 and 2 threads, on burn's CPU backend and on
    /// burn's wgpu backend (lavapipe here: other kernels, other orders of sums), for inputs of
    /// every phase in one batch; and it stays within 12 m (root mean square) of the float
    /// network, whose tiles vary by hundreds of metres.
    #[cfg(feature = "train")]
    #[test]
    fn the_integer_exact_tcm_gives_the_same_bits_on_every_cpu_kernel_and_on_burn_cpu_and_wgpu() {
        let bytes = std::fs::read(crate::repo_root().join("weights").join(crate::world::learned::TCM_FILE)).unwrap();
        let float = TcmCpu::from_burnpack(&bytes).unwrap();
        let exps = exact_calibration(&crate::models::weights_hash(&[&bytes])).expect("the shipped TCM has a calibration");
        let exact = TcmExact::new(&float, exps).unwrap();
        assert!(exact.bound() < crate::models::exact::F32_EXACT);
        let tile: Vec<f32> = (0..TILE_PX * TILE_PX).map(|p| 900.0 + 400.0 * ((p % 32) as f32 * 0.3).sin() + 9.0 * (p / 32) as f32).collect();
        let inputs: Vec<Vec<f32>> = (0..4)
            .map(|p| {
                let mask = phase_mask(p);
                let tiles: [Option<&[f32]>; 9] = std::array::from_fn(|t| mask[t].then_some(tile.as_slice()));
                assemble_input(&tiles, &[850.0, 900.0, 950.0, 1000.0, 1050.0, 1100.0, 1150.0, 1200.0, 1250.0], &[1.0, 1.2, 1.3, 1.1, 1.27, 1.4, 1.2, 1.0, 1.5], 40 + p as u64)
            })
            .collect();
        let mut s = TcmScratch::default();
        let cpu_out: Vec<f32> = inputs.iter().flat_map(|x| exact.run(x, &mut s, 1, cpu::Kernels::Portable, None)).collect();
        for kernels in [cpu::Kernels::Avx2, cpu::Kernels::Best] {
            for threads in [1, 2] {
                let out: Vec<f32> = inputs.iter().flat_map(|x| exact.run(x, &mut s, threads, kernels, None)).collect();
                assert!(out.iter().zip(&cpu_out).all(|(a, b)| a.to_bits() == b.to_bits()), "{kernels:?}, {threads} threads");
            }
        }
        let float_out: Vec<f32> = inputs.iter().flat_map(|x| float.forward(x, &mut s, 1)).collect();
        let rms_m = (float_out.iter().zip(&cpu_out).map(|(a, b)| ((a - b) as f64).powi(2)).sum::<f64>() / cpu_out.len() as f64).sqrt() * HEIGHT_SCALE_M as f64;
        let mean = float_out.iter().map(|&v| v as f64).sum::<f64>() / float_out.len() as f64;
        let sd_m = (float_out.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / float_out.len() as f64).sqrt() * HEIGHT_SCALE_M as f64;
        assert!(rms_m < 12.0 && sd_m > 100.0, "integer vs float {rms_m} m RMS, tiles' spread {sd_m} m");
        for device in [Device::flex(), crate::models::native_gpu().expect("a Vulkan device (lavapipe)")] {
            let m = exact.to_burn(&device).unwrap();
            let x = Tensor::<4>::from_data(burn::tensor::TensorData::new(inputs.concat(), [4, IN_CHANNELS, CONTEXT_PX, CONTEXT_PX]), &device);
            let out: Vec<f32> = exact.forward_burn(&m, x).into_data().try_to_vec::<f32>().unwrap();
            let differ = out.iter().zip(&cpu_out).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
            assert_eq!(differ, 0, "{device:?}: {differ} of {} samples differ from the CPU kernels", out.len());
        }
        println!("integer-exact TCM: {rms_m:.2} m RMS from the float network (tiles' spread {sd_m:.0} m); largest sum {}", exact.bound());
    }
}
