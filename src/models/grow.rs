//! The learned ×4 step of the learned world: from the TCM's 128 m tiles to the world's 32 m
//! (two ×2 stages in one network, with seeded noise at every scale so the detail it invents is
//! varied rather than the blurred mean of the possibilities).
//!
//! The output is a residual added to the bicubic ×4 upsampling of the input; both are computed
//! on a window of the 128 m field around the tile ([`MARGIN`] samples beyond it on every
//! side). Every input is local — the TEM's four height features (height minus its 3×3 mean,
//! ∂x, ∂z, |∂x| + |∂z|, see [`crate::models::tem::features`]) and noise drawn from the world
//! seed and the *global* sample position — so the tiles of one world agree wherever their
//! windows overlap: the 32 m world has no seams of its own.
//!
//! Network: head 3×3 conv (4 features + 2 noise → 48), three 3×3 conv + ReLU, a merge conv
//! with a skip from the head; pixel shuffle to 64 m (12 channels) + 1 noise channel, 3×3 convs
//! 13 → 32 → 32 (ReLU) → 16; pixel shuffle to 32 m (4 channels) + 1 noise channel; 3×3 conv
//! 5 → 16 (ReLU) and a tail 16 → 1 initialised to zero (an untrained model is bicubic).

use burn::module::Module;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{Initializer, PaddingConfig2d, PixelShuffle, PixelShuffleConfig};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};

use crate::dem::Heightfield;
use crate::grid::mix64;
use crate::models::cpu::{self, Conv3, Map, Post};
use crate::models::tcm::{COARSE_SPACING_M, TILE_PX, gauss};

/// Samples of the 128 m field read beyond the tile on every side (more than the network's
/// reach of 8 samples plus bicubic's 2).
pub const MARGIN: usize = 12;
/// Side of the input window (128 m samples).
pub const WINDOW: usize = TILE_PX + 2 * MARGIN;
/// Output samples per input sample along each axis.
pub const FACTOR: usize = 4;
/// Side of the output tile (32 m samples).
pub const OUT_TILE: usize = TILE_PX * FACTOR;
/// Heights enter the network divided by this (metres): 1.25 × the input spacing, as the TEM.
pub const HEIGHT_SCALE_M: f32 = 160.0;
/// Channels of the 128 m body.
const WIDTH: usize = 48;

/// One noise value for global sample (`gx`, `gy`) of stage `stage` (0: 128 m, 1: 64 m,
/// 2: 32 m) in world `seed`.
pub fn noise_at(seed: u64, stage: u64, gx: i64, gy: i64) -> f32 {
    let h = mix64(seed ^ 0x6A09_E667_F3BC_C908 ^ stage.wrapping_mul(0xBB67_AE85_84CA_A73B));
    let h = mix64(h ^ gx as u64);
    gauss(mix64(h ^ (gy as u64).rotate_left(32)))
}

/// The inputs of one window whose top-left 128 m sample is global (`gx0`, `gy0`): `heights`
/// ([`WINDOW`]², metres) → (6 channels at 128 m, 1 at 64 m, 1 at 32 m), channel-first.
pub fn assemble(heights: &[f32], seed: u64, gx0: i64, gy0: i64) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let n = WINDOW;
    let feats = crate::models::tem::features_cpu(heights, n, HEIGHT_SCALE_M);
    let mut x = feats;
    for stage_ch in 0..2u64 {
        for y in 0..n {
            for xx in 0..n {
                x.push(noise_at(seed, stage_ch * 7, gx0 + xx as i64, gy0 + y as i64));
            }
        }
    }
    let grid = |stage: u64, f: usize| -> Vec<f32> {
        let m = n * f;
        (0..m * m).map(|p| noise_at(seed, 10 + stage, gx0 * f as i64 + (p % m) as i64, gy0 * f as i64 + (p / m) as i64)).collect()
    };
    (x, grid(1, 2), grid(2, 4))
}

/// The bicubic ×4 base of a [`WINDOW`]² window (metres), ([`WINDOW`]·4)².
pub fn base(heights: &[f32]) -> Vec<f32> {
    Heightfield::new(WINDOW, WINDOW, COARSE_SPACING_M, heights.to_vec()).upsample_bicubic(FACTOR).data
}

/// The ×4 network.
#[derive(Module, Debug)]
pub struct Grow {
    head: Conv2d,
    body: Vec<Conv2d>,
    merge: Conv2d,
    mid: Vec<Conv2d>,
    fine: Conv2d,
    tail: Conv2d,
    shuffle: PixelShuffle,
}

fn conv3(cin: usize, cout: usize, device: &Device) -> Conv2d {
    Conv2dConfig::new([cin, cout], [3, 3]).with_padding(PaddingConfig2d::Same).init(device)
}

/// Names and shapes (name, output channels, input channels) of the convolutions in network
/// order, as in a weight file.
pub fn conv_layers() -> Vec<(String, usize, usize)> {
    let mut v = vec![("head".to_string(), WIDTH, 6)];
    v.extend((0..3).map(|k| (format!("body.{k}"), WIDTH, WIDTH)));
    v.push(("merge".into(), WIDTH, WIDTH));
    v.push(("mid.0".into(), 32, WIDTH / 4 + 1));
    v.push(("mid.1".into(), 32, 32));
    v.push(("mid.2".into(), 16, 32));
    v.push(("fine".into(), 16, 5));
    v.push(("tail".into(), 1, 16));
    v
}

impl Grow {
    /// A freshly initialised network (its residual is zero: the output is bicubic).
    pub fn new(device: &Device) -> Self {
        Self {
            head: conv3(6, WIDTH, device),
            body: (0..3).map(|_| conv3(WIDTH, WIDTH, device)).collect(),
            merge: conv3(WIDTH, WIDTH, device),
            mid: vec![conv3(WIDTH / 4 + 1, 32, device), conv3(32, 32, device), conv3(32, 16, device)],
            fine: conv3(5, 16, device),
            tail: Conv2dConfig::new([16, 1], [3, 3]).with_padding(PaddingConfig2d::Same).with_initializer(Initializer::Zeros).init(device),
            shuffle: PixelShuffleConfig::new(2).init(),
        }
    }

    /// Number of learned parameters.
    pub fn parameters(&self) -> usize {
        self.num_params()
    }

    /// The residual [B, 1, 4S, 4S] (units of [`HEIGHT_SCALE_M`]) for inputs `x` [B, 6, S, S],
    /// `n64` [B, 1, 2S, 2S] and `n32` [B, 1, 4S, 4S] from [`assemble`].
    pub fn forward(&self, x: Tensor<4>, n64: Tensor<4>, n32: Tensor<4>) -> Tensor<4> {
        let head = self.head.forward(x);
        let mut b = head.clone();
        for c in &self.body {
            b = relu(c.forward(b));
        }
        let b = self.merge.forward(b) + head;
        let m = Tensor::cat(vec![self.shuffle.forward(b), n64], 1);
        let m = relu(self.mid[0].forward(m));
        let m = relu(self.mid[1].forward(m));
        let m = self.mid[2].forward(m);
        let f = Tensor::cat(vec![self.shuffle.forward(m), n32], 1);
        self.tail.forward(relu(self.fine.forward(f)))
    }
}

/// Reused buffers of [`GrowCpu::forward`].
#[derive(Default)]
pub struct GrowScratch {
    x: Map,
    head: Map,
    a: Map,
    b: Map,
    shuffled: Map,
    cat: Map,
    out: Map,
}

/// [`Grow`] on the project's own CPU kernels.
#[derive(Clone, Debug)]
pub struct GrowCpu {
    convs: Vec<Conv3>,
}

/// `src`'s channels followed by one channel from `extra` (row-major, `src`'s size).
fn with_channel(src: &Map, extra: &[f32], dst: &mut Map) {
    let (h, w, c) = (src.height(), src.width(), src.channels());
    dst.reset(h, w, c + 1);
    for y in 0..h {
        for x in 0..w {
            let p = dst.pixel_mut(y, x);
            p[..c].copy_from_slice(src.pixel(y, x));
            p[c] = extra[y * w + x];
        }
    }
}

impl GrowCpu {
    /// Every layer random (uniform ±`amplitude`, from `seed`), for tests.
    pub fn randomized(seed: u64, amplitude: f32) -> Self {
        Self { convs: cpu::random_convs(&conv_layers(), seed, amplitude) }
    }

    /// Reads a weight file (burnpack, as training writes it).
    pub fn from_burnpack(bytes: &[u8]) -> Result<Self, crate::models::WeightError> {
        Ok(Self { convs: cpu::convs_from_burnpack(bytes, &conv_layers())? })
    }

    /// Writes these weights into a burn network (the start of a training run).
    #[cfg(feature = "train")]
    pub fn into_model(&self, m: Grow) -> Grow {
        let mut m = m;
        let layers = std::iter::once(&mut m.head).chain(m.body.iter_mut()).chain([&mut m.merge]).chain(m.mid.iter_mut()).chain([&mut m.fine, &mut m.tail]);
        for (c, layer) in self.convs.iter().zip(layers) {
            cpu::conv_into_burn(c, layer);
        }
        m
    }

    /// Copies a burn network's weights.
    pub fn from_model(m: &Grow) -> Result<Self, String> {
        let layers = std::iter::once(&m.head).chain(&m.body).chain([&m.merge]).chain(&m.mid).chain([&m.fine, &m.tail]);
        Ok(Self { convs: layers.map(cpu::conv_from_burn).collect::<Result<_, _>>()? })
    }

    /// The residual ((4·S)², row-major, units of [`HEIGHT_SCALE_M`]) for the inputs of
    /// [`assemble`] on an S² window.
    pub fn forward(&self, x: &[f32], n64: &[f32], n32: &[f32], side: usize, s: &mut GrowScratch, threads: usize) -> Vec<f32> {
        let c = &self.convs;
        s.x.set_chw(x, 6, side, side);
        cpu::conv(&c[0], &s.x, &mut s.head, Post::None, threads);
        cpu::conv(&c[1], &s.head, &mut s.a, Post::Relu, threads);
        cpu::conv(&c[2], &s.a, &mut s.b, Post::Relu, threads);
        cpu::conv(&c[3], &s.b, &mut s.a, Post::Relu, threads);
        cpu::conv(&c[4], &s.a, &mut s.b, Post::Add(&s.head), threads);
        cpu::pixel_shuffle2(&s.b, &mut s.shuffled);
        with_channel(&s.shuffled, n64, &mut s.cat);
        cpu::conv(&c[5], &s.cat, &mut s.a, Post::Relu, threads);
        cpu::conv(&c[6], &s.a, &mut s.b, Post::Relu, threads);
        cpu::conv(&c[7], &s.b, &mut s.a, Post::None, threads);
        cpu::pixel_shuffle2(&s.a, &mut s.shuffled);
        with_channel(&s.shuffled, n32, &mut s.cat);
        cpu::conv(&c[8], &s.cat, &mut s.a, Post::Relu, threads);
        cpu::conv(&c[9], &s.a, &mut s.out, Post::None, threads);
        let m = 4 * side;
        (0..m * m).map(|p| s.out.pixel(p / m, p % m)[0]).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Noise depends on the global position only: two windows offset by (5, 3) samples
    /// give the same values where they overlap, and different seeds differ.
    #[test]
    fn noise_is_a_function_of_global_position() {
        let h = vec![100.0f32; WINDOW * WINDOW];
        let (a, a64, _) = assemble(&h, 7, 0, 0);
        let (b, b64, _) = assemble(&h, 7, 5, 3);
        let n = WINDOW;
        // Channel 4 (the first noise channel) of sample (x, y) in a equals (x − 5, y − 3) in b.
        for y in 3..n {
            for x in 5..n {
                assert_eq!(a[(4 * n + y) * n + x].to_bits(), b[(4 * n + y - 3) * n + x - 5].to_bits());
            }
        }
        let m = 2 * n;
        // At 64 m, window b starts at global (10, 6): its first sample is a's (10, 6).
        assert_eq!(a64[6 * m + 10].to_bits(), b64[0].to_bits());
        let (c, _, _) = assemble(&h, 8, 0, 0);
        assert_ne!(a[4 * n * n..], c[4 * n * n..]);
    }

    /// The CPU kernels compute the burn network (random weights, so the residual is not
    /// trivially zero): every output within 1e-4 of burn's.
    #[cfg(feature = "train")]
    #[test]
    fn cpu_forward_equals_burn_forward() {
        let device = Device::flex();
        let g = crate::models::random_weights(Grow::new(&device), &device, 3, 0.1);
        let cpu_g = GrowCpu::from_model(&g).unwrap();
        let h: Vec<f32> = (0..WINDOW * WINDOW).map(|p| 500.0 + 80.0 * ((p % WINDOW) as f32 * 0.4).sin() * ((p / WINDOW) as f32 * 0.25).cos()).collect();
        let (x, n64, n32) = assemble(&h, 11, -40, 17);
        let t = |v: &Vec<f32>, c: usize, s: usize| Tensor::<4>::from_data(burn::tensor::TensorData::new(v.clone(), [1, c, s, s]), &device);
        let want: Vec<f32> = g.forward(t(&x, 6, WINDOW), t(&n64, 1, 2 * WINDOW), t(&n32, 1, 4 * WINDOW)).into_data().try_to_vec::<f32>().unwrap();
        let got = cpu_g.forward(&x, &n64, &n32, WINDOW, &mut GrowScratch::default(), 2);
        let worst = got.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        let scale = want.iter().map(|v| v.abs()).fold(0f32, f32::max);
        assert!(scale > 1e-3, "random network output {scale}");
        assert!(worst < 1e-4, "CPU and burn differ by {worst}");
        assert!(g.parameters() < 150_000, "{} parameters", g.parameters());
    }
}
