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
use crate::models::exact::{ExactConv, largest};
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

/// Grid exponent of the integer-exact ×4 step's noise channels (1/256 of a σ; [`GrowExact`]).
pub const EXACT_NOISE_EXP: i32 = -8;

/// Largest input level (magnitude) of the integer-exact ×4 step: its four height features and
/// its noise (±8 σ) on their grids.
pub const EXACT_INPUT_LEVELS: f32 = 2047.0;

/// Largest level of the merge layer's output on the head's grid, before the head is added
/// back (2²⁰): far beyond any value it takes; it only bounds the sum.
const MERGE_LEVELS: f32 = 1_048_576.0;

/// Rounding points of the integer-exact ×4 step, in running order: the four height features,
/// the head, the three body layers, the head plus the merge (the skip's sum), the three 64 m
/// layers and the 32 m layer before the tail.
pub const EXACT_POINTS: usize = 13;
const P_HEAD: usize = 4;
const P_BODY: usize = 5;
const P_SUM: usize = 8;
const P_MID: usize = 9;
const P_FINE: usize = 12;

/// The integer-exact ×4 step's grids ([`GrowExact::calibrate`]) for the weight files they were
/// calibrated on, by [`crate::models::weights_hash`] of the file: the shipped weights' from the
/// world's tiles −3…2 of seeds 1–4 (`terrain grow-calibrate`).
pub const EXACT_CALIBRATIONS: &[(&str, &[i32])] = &[("ec5e0f77", &[-7, -7, -7, -6, -5, -5, -5, -5, -5, -5, -5, -5, -6])];

/// The grids of [`EXACT_CALIBRATIONS`] for the ×4 weight file whose hash is `grow_hash`, if
/// it has them.
pub fn exact_calibration(grow_hash: &str) -> Option<&'static [i32]> {
    EXACT_CALIBRATIONS.iter().find(|(h, _)| *h == grow_hash).map(|(_, e)| *e)
}

/// `v` on the grid 2^−log2(`scale`): ⌊v · scale + ½⌋ clamped to ±`max` (as
/// [`cpu::requantize`], for a plain slice).
fn on_grid(v: &[f32], scale: f32, max: f32) -> Vec<f32> {
    v.iter().map(|&x| (x * scale + 0.5).floor().clamp(-max, max)).collect()
}

/// The ×4 step on integer grids ([`crate::models::exact`]), as [`crate::models::tcm::TcmExact`]
/// for the TCM: 9-bit weights (fewer where the bound on the sums needs it), 10-bit activations
/// (signed after the layers without a ReLU) and 11-bit inputs carried in f32, so that every CPU
/// kernel and a GPU's convolutions give the same bits. The skip (head plus merge) is added on
/// the head's grid and the sum rounded to its own.
#[derive(Clone, Debug)]
pub struct GrowExact {
    layers: Vec<ExactConv>,
    /// Grid exponent of each rounding point ([`EXACT_POINTS`], running order).
    exps: Vec<i32>,
}

impl GrowExact {
    /// Quantizes `grow` with the grids `exps` (one per rounding point, [`EXACT_POINTS`], e.g.
    /// from [`GrowExact::calibrate`]).
    pub fn new(grow: &GrowCpu, exps: &[i32]) -> Result<Self, cpu::LayerError> {
        use crate::models::exact::{ACT_LEVELS, quantize};
        assert_eq!(exps.len(), EXACT_POINTS, "one grid per rounding point");
        let relu = |p: usize, n: usize| (vec![exps[p]; n], vec![(0.0, ACT_LEVELS); n]);
        let signed = |p: usize, n: usize| (vec![exps[p]; n], vec![(-ACT_LEVELS, ACT_LEVELS); n]);
        let with_noise = |(mut e, mut r): (Vec<i32>, Vec<(f32, f32)>), n: usize| {
            e.extend(std::iter::repeat_n(EXACT_NOISE_EXP, n));
            r.extend(std::iter::repeat_n((-EXACT_INPUT_LEVELS, EXACT_INPUT_LEVELS), n));
            (e, r)
        };
        let inputs = [
            with_noise((exps[..4].to_vec(), vec![(-EXACT_INPUT_LEVELS, EXACT_INPUT_LEVELS); 4]), 2),
            signed(P_HEAD, WIDTH),
            relu(P_BODY, WIDTH),
            relu(P_BODY + 1, WIDTH),
            relu(P_BODY + 2, WIDTH),
            with_noise(signed(P_SUM, WIDTH / 4), 1),
            relu(P_MID, 32),
            relu(P_MID + 1, 32),
            with_noise(signed(P_MID + 2, 4), 1),
            relu(P_FINE, 16),
        ];
        let layers = grow
            .convs
            .iter()
            .zip(inputs)
            .map(|(conv, (e, r))| {
                // Sums of integers below 2²⁴ are exact in any order, fused or not.
                let mut q = quantize(conv, &e, &r)?;
                q.conv = q.conv.with_fused(true);
                Ok(q)
            })
            .collect::<Result<_, _>>()?;
        Ok(Self { layers, exps: exps.to_vec() })
    }

    /// The largest sum any layer can form (below 2²⁴).
    pub fn bound(&self) -> f64 {
        self.layers.iter().map(|l| l.bound).fold(0.0, f64::max)
    }

    fn input_scales(&self) -> [f32; 6] {
        use crate::models::exact::pow2;
        let e = &self.exps;
        [pow2(-e[0]), pow2(-e[1]), pow2(-e[2]), pow2(-e[3]), pow2(-EXACT_NOISE_EXP), pow2(-EXACT_NOISE_EXP)]
    }

    /// One window, as [`GrowCpu::forward`]: the residual ((4·S)², units of
    /// [`HEIGHT_SCALE_M`]), a multiple of the tail's grid.
    pub fn forward(&self, x: &[f32], n64: &[f32], n32: &[f32], side: usize, s: &mut GrowScratch, threads: usize) -> Vec<f32> {
        self.run(x, n64, n32, side, s, threads, cpu::Kernels::chosen(), None)
    }

    /// [`GrowExact::forward`] on `kernels`; `record` gets each rounding point's largest
    /// |value| before rounding (real units).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn run(
        &self,
        x: &[f32],
        n64: &[f32],
        n32: &[f32],
        side: usize,
        s: &mut GrowScratch,
        threads: usize,
        kernels: cpu::Kernels,
        mut record: Option<&mut [f32]>,
    ) -> Vec<f32> {
        use crate::models::exact::{ACT_LEVELS, pow2};
        let (l, e) = (&self.layers, &self.exps);
        s.x.set_chw(x, 6, side, side);
        for p in 0..4 {
            if let Some(r) = record.as_deref_mut() {
                r[p] = largest(&s.x, |c| if c == p { 1.0 } else { 0.0 }, r[p]);
            }
        }
        cpu::requantize(&mut s.x, &self.input_scales(), EXACT_INPUT_LEVELS);
        fn slot<'a>(record: &'a mut Option<&mut [f32]>, p: usize) -> Option<&'a mut f32> {
            record.as_deref_mut().map(|r| &mut r[p])
        }
        // Layer `q` with its output on the grid 2^`out_exp` (clamped to ±`max`); with a
        // `note`, its largest value before rounding goes there, else each thread rounds the
        // rows it made.
        let layer = |q: &ExactConv, src: &Map, dst: &mut Map, post: Post, out_exp: i32, max: f32, note: Option<&mut f32>| {
            let scale = q.to_grid(out_exp);
            match note {
                Some(r) => {
                    cpu::conv_impl(&q.conv, src, dst, post, threads, kernels);
                    *r = largest(dst, |c| pow2(q.acc_exp[c]), *r);
                    cpu::requantize(dst, &scale, max);
                }
                None => cpu::conv_on_grid(&q.conv, src, dst, post, &scale, max, threads, kernels),
            }
        };
        let act = ACT_LEVELS;
        layer(&l[0], &s.x, &mut s.head, Post::None, e[P_HEAD], act, slot(&mut record, P_HEAD));
        layer(&l[1], &s.head, &mut s.a, Post::Relu, e[P_BODY], act, slot(&mut record, P_BODY));
        layer(&l[2], &s.a, &mut s.b, Post::Relu, e[P_BODY + 1], act, slot(&mut record, P_BODY + 1));
        layer(&l[3], &s.b, &mut s.a, Post::Relu, e[P_BODY + 2], act, slot(&mut record, P_BODY + 2));
        // The skip: the merge on the head's grid plus the head (integers, exact), then the
        // sum on its own grid.
        layer(&l[4], &s.a, &mut s.b, Post::None, e[P_HEAD], MERGE_LEVELS, None);
        for y in 0..s.b.height() {
            for xx in 0..s.b.width() {
                for (v, h) in s.b.pixel_mut(y, xx).iter_mut().zip(s.head.pixel(y, xx)) {
                    *v += h;
                }
            }
        }
        if let Some(r) = slot(&mut record, P_SUM) {
            *r = largest(&s.b, |_| pow2(e[P_HEAD]), *r);
        }
        cpu::requantize(&mut s.b, &[pow2(e[P_HEAD] - e[P_SUM]); WIDTH], act);
        let noise = pow2(-EXACT_NOISE_EXP);
        cpu::pixel_shuffle2(&s.b, &mut s.shuffled);
        with_channel(&s.shuffled, &on_grid(n64, noise, EXACT_INPUT_LEVELS), &mut s.cat);
        layer(&l[5], &s.cat, &mut s.a, Post::Relu, e[P_MID], act, slot(&mut record, P_MID));
        layer(&l[6], &s.a, &mut s.b, Post::Relu, e[P_MID + 1], act, slot(&mut record, P_MID + 1));
        layer(&l[7], &s.b, &mut s.a, Post::None, e[P_MID + 2], act, slot(&mut record, P_MID + 2));
        cpu::pixel_shuffle2(&s.a, &mut s.shuffled);
        with_channel(&s.shuffled, &on_grid(n32, noise, EXACT_INPUT_LEVELS), &mut s.cat);
        layer(&l[8], &s.cat, &mut s.a, Post::Relu, e[P_FINE], act, slot(&mut record, P_FINE));
        cpu::conv_impl(&l[9].conv, &s.a, &mut s.out, Post::None, threads, kernels);
        let (m, unit) = (4 * side, pow2(l[9].acc_exp[0]));
        (0..m * m).map(|p| s.out.pixel(p / m, p % m)[0] * unit).collect()
    }

    /// This network's integer weights in a burn network on `device` (for
    /// [`GrowExact::forward_burn`]).
    pub fn to_burn(&self, device: &Device) -> Result<Grow, crate::models::WeightError> {
        let convs: Vec<Conv3> = self.layers.iter().map(|l| l.conv.clone()).collect();
        crate::models::load_burnpack(Grow::new(device), &cpu::convs_to_burnpack(&conv_layers(), &convs))
    }

    /// [`GrowExact::forward`] on burn's backends: `m` from [`GrowExact::to_burn`], inputs as
    /// [`Grow::forward`]'s; returns the residual [B, 1, 4S, 4S], the same bits as the CPU
    /// kernels.
    pub fn forward_burn(&self, m: &Grow, x: Tensor<4>, n64: Tensor<4>, n32: Tensor<4>) -> Tensor<4> {
        self.forward_burn_rest(m, self.forward_burn_128m(m, x), n64, n32)
    }

    /// The first part of [`GrowExact::forward_burn`], its 128 m stage (head, body, merge):
    /// [B, [`WIDTH`], S, S] features for [`GrowExact::forward_burn_rest`]. A caller may wait
    /// for the device between the two (a page then draws a frame between them).
    pub fn forward_burn_128m(&self, m: &Grow, x: Tensor<4>) -> Tensor<4> {
        use crate::models::exact::{ACT_LEVELS, pow2};
        let (l, e) = (&self.layers, &self.exps);
        let grid = crate::models::exact::grid_burn;
        let x = grid(x, &self.input_scales(), EXACT_INPUT_LEVELS);
        let head = grid(m.head.forward(x), &l[0].to_grid(e[P_HEAD]), ACT_LEVELS);
        let mut b = head.clone();
        for (k, c) in m.body.iter().enumerate() {
            b = grid(relu(c.forward(b)), &l[1 + k].to_grid(e[P_BODY + k]), ACT_LEVELS);
        }
        let b = grid(m.merge.forward(b), &l[4].to_grid(e[P_HEAD]), MERGE_LEVELS) + head;
        grid(b, &[pow2(e[P_HEAD] - e[P_SUM]); WIDTH], ACT_LEVELS)
    }

    /// The rest of [`GrowExact::forward_burn`] from its 128 m stage's features `b`
    /// ([`GrowExact::forward_burn_128m`]): the 64 m and 32 m stages and the tail.
    pub fn forward_burn_rest(&self, m: &Grow, b: Tensor<4>, n64: Tensor<4>, n32: Tensor<4>) -> Tensor<4> {
        use crate::models::exact::{ACT_LEVELS, pow2};
        let (l, e) = (&self.layers, &self.exps);
        let grid = crate::models::exact::grid_burn;
        let noise = [pow2(-EXACT_NOISE_EXP)];
        let mid = Tensor::cat(vec![m.shuffle.forward(b), grid(n64, &noise, EXACT_INPUT_LEVELS)], 1);
        let mid = grid(relu(m.mid[0].forward(mid)), &l[5].to_grid(e[P_MID]), ACT_LEVELS);
        let mid = grid(relu(m.mid[1].forward(mid)), &l[6].to_grid(e[P_MID + 1]), ACT_LEVELS);
        let mid = grid(m.mid[2].forward(mid), &l[7].to_grid(e[P_MID + 2]), ACT_LEVELS);
        let f = Tensor::cat(vec![m.shuffle.forward(mid), grid(n32, &noise, EXACT_INPUT_LEVELS)], 1);
        let f = grid(relu(m.fine.forward(f)), &l[8].to_grid(e[P_FINE]), ACT_LEVELS);
        m.tail.forward(f) * pow2(l[9].acc_exp[0])
    }

    /// Grids for `grow` from inputs `inputs` ([`assemble`] on `side`² windows): point by point
    /// in running order, the coarsest power of two on which the point's largest |value| (with
    /// the grids already chosen before it) needs at most [`EXACT_INPUT_LEVELS`] (the features)
    /// or [`crate::models::exact::ACT_LEVELS`] levels.
    pub fn calibrate(grow: &GrowCpu, inputs: &[(Vec<f32>, Vec<f32>, Vec<f32>)], side: usize) -> Result<Vec<i32>, cpu::LayerError> {
        use crate::models::exact::{ACT_LEVELS, grid_exp};
        let mut exps = vec![0; EXACT_POINTS];
        let mut s = GrowScratch::default();
        let mut p = 0;
        while p < EXACT_POINTS {
            let net = Self::new(grow, &exps)?;
            let mut most = vec![0f32; EXACT_POINTS];
            for (x, n64, n32) in inputs {
                net.run(x, n64, n32, side, &mut s, cpu::default_threads(), cpu::Kernels::chosen(), Some(&mut most));
            }
            // The four features depend on nothing before them: one pass sets them all.
            let points = if p == 0 { 0..4 } else { p..p + 1 };
            for q in points {
                let levels = if q < 4 { EXACT_INPUT_LEVELS } else { ACT_LEVELS };
                exps[q] = grid_exp(most[q].max(f32::MIN_POSITIVE) as f64, levels as f64);
                p = q + 1;
            }
        }
        Ok(exps)
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

    /// The shipped ×4 step on integer grids ([`GrowExact`], its calibration) gives the same
    /// bits on the portable, AVX2 and widest CPU kernels at 1 and 2 threads, on burn's CPU
    /// backend and on burn's wgpu backend (lavapipe), for a batch of 2 windows; and its
    /// residual stays within 2 m (root mean square) of the float network's, which moves the
    /// bicubic base by tens of metres.
    #[cfg(feature = "train")]
    #[test]
    fn the_integer_exact_grow_gives_the_same_bits_on_every_cpu_kernel_and_on_burn_cpu_and_wgpu() {
        let bytes = std::fs::read(crate::repo_root().join("weights").join(crate::world::learned::GROW_FILE)).unwrap();
        let float = GrowCpu::from_burnpack(&bytes).unwrap();
        let exps = exact_calibration(&crate::models::weights_hash(&[&bytes])).expect("the shipped ×4 step has a calibration");
        let exact = GrowExact::new(&float, exps).unwrap();
        assert!(exact.bound() < crate::models::exact::F32_EXACT);
        let inputs: Vec<_> = (0..2)
            .map(|k| {
                let h: Vec<f32> = (0..WINDOW * WINDOW)
                    .map(|p| 1200.0 + 300.0 * ((p % WINDOW) as f32 * 0.23 + k as f32).sin() * ((p / WINDOW) as f32 * 0.17).cos() + 40.0 * ((p % 7) as f32))
                    .collect();
                assemble(&h, 9 + k, -30 + 64 * k as i64, 21)
            })
            .collect();
        let mut s = GrowScratch::default();
        let cpu_out: Vec<f32> = inputs.iter().flat_map(|(x, a, b)| exact.run(x, a, b, WINDOW, &mut s, 1, cpu::Kernels::Portable, None)).collect();
        for kernels in [cpu::Kernels::Avx2, cpu::Kernels::Best] {
            for threads in [1, 2] {
                let out: Vec<f32> = inputs.iter().flat_map(|(x, a, b)| exact.run(x, a, b, WINDOW, &mut s, threads, kernels, None)).collect();
                assert!(out.iter().zip(&cpu_out).all(|(a, b)| a.to_bits() == b.to_bits()), "{kernels:?}, {threads} threads");
            }
        }
        let float_out: Vec<f32> = inputs.iter().flat_map(|(x, a, b)| float.forward(x, a, b, WINDOW, &mut s, 1)).collect();
        let m = HEIGHT_SCALE_M as f64;
        let rms_m = (float_out.iter().zip(&cpu_out).map(|(a, b)| ((a - b) as f64).powi(2)).sum::<f64>() / cpu_out.len() as f64).sqrt() * m;
        let spread_m = (float_out.iter().map(|&v| (v as f64).powi(2)).sum::<f64>() / float_out.len() as f64).sqrt() * m;
        assert!(rms_m < 2.0 && spread_m > 10.0, "integer vs float {rms_m} m RMS, the float residual's {spread_m} m");
        let stack = |parts: Vec<&Vec<f32>>, side: usize, device: &Device| {
            Tensor::<4>::from_data(burn::tensor::TensorData::new(parts.into_iter().flatten().copied().collect::<Vec<f32>>(), [2, 1, side, side]), device)
        };
        for device in [Device::flex(), crate::models::native_gpu().expect("a Vulkan device (lavapipe)")] {
            let g = exact.to_burn(&device).unwrap();
            let x = Tensor::<4>::from_data(burn::tensor::TensorData::new(inputs.iter().flat_map(|i| i.0.clone()).collect::<Vec<f32>>(), [2, 6, WINDOW, WINDOW]), &device);
            let (n64, n32) = (stack(inputs.iter().map(|i| &i.1).collect(), 2 * WINDOW, &device), stack(inputs.iter().map(|i| &i.2).collect(), 4 * WINDOW, &device));
            let out: Vec<f32> = exact.forward_burn(&g, x, n64, n32).into_data().try_to_vec::<f32>().unwrap();
            let differ = out.iter().zip(&cpu_out).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
            assert_eq!(differ, 0, "{device:?}: {differ} of {} samples differ from the CPU kernels", out.len());
        }
        println!("integer-exact ×4 step: {rms_m:.3} m RMS from the float network (its residual {spread_m:.1} m RMS); largest sum {}", exact.bound());
    }
}
