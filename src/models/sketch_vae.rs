//! The sketch VAE: a variational autoencoder over sketches whose 128-number latent code lets
//! the page propose variants of a sketch (codes near its own) and slide between two sketches
//! (z = α·z₁ + (1 − α)·z₂), as the sketch paper's stage 1.
//!
//! Encoder: six stages of a 3×3 convolution + ReLU and 2×2 mean pooling ([`SKETCH_PX`]² → 4²,
//! [`ENC_WIDTHS`]), then a 3×3 convolution to the mean and log-variance of the code:
//! [`LATENT_CHANNELS`] × 4² = [`LATENT`] numbers. Decoder: a 3×3 convolution from the code, six
//! stages of ×2 nearest upsampling + 3×3 convolution + ReLU ([`DEC_WIDTHS`]) and a 3×3
//! convolution to the logits of the four bands, the ridge layer and the valley layer. Only
//! convolutions, so the project's CPU kernels run it; no normalisation layers (training and
//! inference compute the same function).

use burn::module::Module;
use burn::nn::conv::Conv2d;
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};

use crate::grid::mix64;
use crate::models::cpu::{self, Conv3, Map, Post};
use crate::models::tcm::{pool2, up2};
use crate::sketch::tidy::tidy;
use crate::sketch::{BANDS, INPUT_CHANNELS, SKETCH_PX, Sketch};

/// Side of the code's grid (pixels).
pub const CODE_PX: usize = 4;
/// Channels of the code.
pub const LATENT_CHANNELS: usize = 8;
/// Numbers in a code.
pub const LATENT: usize = LATENT_CHANNELS * CODE_PX * CODE_PX;
/// Encoder channels per stage (at 256², 128², … 8² before each pooling).
pub const ENC_WIDTHS: [usize; 6] = [16, 32, 64, 96, 128, 128];
/// Decoder channels per stage (at 8², 16², … 256² after each upsampling).
pub const DEC_WIDTHS: [usize; 6] = [128, 96, 64, 32, 16, 16];
/// Channels of the code's first decoder convolution (at 4²).
pub const DEC_IN: usize = 128;
/// Output channels: the four band logits, then the ridge and valley logits.
pub const OUT_CHANNELS: usize = BANDS + 2;
/// Name of the weight file in a weights folder.
pub const WEIGHT_FILE: &str = "sketch_vae.bpk";
/// Standard deviation (units of the prior) of the codes drawn around a sketch's own for
/// variants.
pub const VARIANT_SPREAD: f32 = 0.6;

/// A 3×3 convolution (zero padding) with He initialisation: the VAE is a plain stack of 15
/// ReLU layers without skips, and burn's default (PyTorch's) initialisation shrinks the
/// signal about six-fold per layer, so nothing would reach the decoder.
fn conv3(cin: usize, cout: usize, device: &Device) -> Conv2d {
    burn::nn::conv::Conv2dConfig::new([cin, cout], [3, 3])
        .with_padding(burn::nn::PaddingConfig2d::Same)
        .with_initializer(burn::nn::Initializer::KaimingNormal { gain: std::f64::consts::SQRT_2, fan_out_only: false })
        .init(device)
}

/// The sketch VAE.
#[derive(Module, Debug)]
pub struct SketchVae {
    enc: Vec<Conv2d>,
    head: Conv2d,
    from_code: Conv2d,
    dec: Vec<Conv2d>,
    out: Conv2d,
}

impl SketchVae {
    /// A VAE on `device` with every weight uniform in ±`amplitude` from `seed` (the layers of
    /// [`SketchVaeCpu::randomized`] before padding): a training run that starts the same
    /// every time (burn's own initialisation is seeded from the system's entropy).
    #[cfg(feature = "train")]
    pub fn seeded(device: &Device, seed: u64, amplitude: f32) -> Self {
        let mut m = Self::new(device);
        let convs = cpu::random_convs(&conv_layers(), seed, amplitude);
        let targets = m.enc.iter_mut().chain([&mut m.head, &mut m.from_code]).chain(m.dec.iter_mut()).chain([&mut m.out]);
        for (src, c) in convs.iter().zip(targets) {
            cpu::conv_into_burn(src, c);
        }
        m
    }

    /// A freshly initialised VAE on `device`.
    pub fn new(device: &Device) -> Self {
        let enc = (0..6).map(|k| conv3(if k == 0 { INPUT_CHANNELS } else { ENC_WIDTHS[k - 1] }, ENC_WIDTHS[k], device)).collect();
        let dec = (0..6).map(|k| conv3(if k == 0 { DEC_IN } else { DEC_WIDTHS[k - 1] }, DEC_WIDTHS[k], device)).collect();
        Self {
            enc,
            head: conv3(ENC_WIDTHS[5], 2 * LATENT_CHANNELS, device),
            from_code: conv3(LATENT_CHANNELS, DEC_IN, device),
            dec,
            out: conv3(DEC_WIDTHS[5], OUT_CHANNELS, device),
        }
    }

    /// Number of learned parameters.
    pub fn parameters(&self) -> usize {
        self.num_params()
    }

    /// (mean, log-variance) of the codes ([B, [`LATENT_CHANNELS`], 4, 4] each) of sketches `x`
    /// ([B, [`INPUT_CHANNELS`], 256, 256] from [`Sketch::channels`]).
    pub fn encode(&self, x: Tensor<4>) -> (Tensor<4>, Tensor<4>) {
        let mut h = x;
        for c in &self.enc {
            h = pool2(relu(c.forward(h)));
        }
        let out = self.head.forward(h);
        (out.clone().narrow(1, 0, LATENT_CHANNELS), out.narrow(1, LATENT_CHANNELS, LATENT_CHANNELS).clamp(-12.0, 6.0))
    }

    /// Logits ([B, [`OUT_CHANNELS`], 256, 256]) of the sketches of codes `z`.
    pub fn decode(&self, z: Tensor<4>) -> Tensor<4> {
        let mut h = relu(self.from_code.forward(z));
        for c in &self.dec {
            h = relu(c.forward(up2(h)));
        }
        self.out.forward(h)
    }
}

/// Names and shapes (name, output channels, input channels) of the VAE's convolutions in the
/// order of [`SketchVaeCpu`]: encoder, head, code, decoder, output.
pub fn conv_layers() -> Vec<(String, usize, usize)> {
    let mut v = Vec::new();
    for k in 0..6 {
        v.push((format!("enc.{k}"), ENC_WIDTHS[k], if k == 0 { INPUT_CHANNELS } else { ENC_WIDTHS[k - 1] }));
    }
    v.push(("head".into(), 2 * LATENT_CHANNELS, ENC_WIDTHS[5]));
    v.push(("from_code".into(), DEC_IN, LATENT_CHANNELS));
    for k in 0..6 {
        v.push((format!("dec.{k}"), DEC_WIDTHS[k], if k == 0 { DEC_IN } else { DEC_WIDTHS[k - 1] }));
    }
    v.push(("out".into(), OUT_CHANNELS, DEC_WIDTHS[5]));
    v
}

/// A code: [`LATENT`] numbers, channel-first ([`LATENT_CHANNELS`] × 4²).
pub type Code = Vec<f32>;

/// The VAE on the project's CPU kernels (the CLI and the page's worker).
#[derive(Clone, Debug)]
pub struct SketchVaeCpu {
    convs: Vec<Conv3>,
}

/// Reused buffers of [`SketchVaeCpu`].
#[derive(Default)]
pub struct VaeScratch {
    a: Map,
    b: Map,
}

impl SketchVaeCpu {
    /// The network from its layers in the order of [`conv_layers`]; the 6-channel output
    /// layer is padded for the vectorised kernels ([`Conv3::padded_for_simd`]).
    fn from_convs(mut convs: Vec<Conv3>) -> Self {
        if let Some(out) = convs.last_mut() {
            *out = out.padded_for_simd();
        }
        Self { convs }
    }

    /// Every layer random (uniform ±`amplitude`, from `seed`), for tests.
    pub fn randomized(seed: u64, amplitude: f32) -> Self {
        Self::from_convs(cpu::random_convs(&conv_layers(), seed, amplitude))
    }

    /// Reads a VAE weight file (burnpack, as training writes it).
    pub fn from_burnpack(bytes: &[u8]) -> Result<Self, crate::models::WeightError> {
        Ok(Self::from_convs(cpu::convs_from_burnpack(bytes, &conv_layers())?))
    }

    /// Copies a burn VAE's weights.
    pub fn from_model(m: &SketchVae) -> Result<Self, String> {
        let convs = m.enc.iter().chain([&m.head, &m.from_code]).chain(&m.dec).chain([&m.out]);
        Ok(Self::from_convs(convs.map(cpu::conv_from_burn).collect::<Result<_, _>>()?))
    }

    /// (mean, log-variance) of the code of `sketch`.
    pub fn encode(&self, sketch: &Sketch, s: &mut VaeScratch, threads: usize) -> (Code, Code) {
        s.a.set_chw(&sketch.channels(), INPUT_CHANNELS, SKETCH_PX, SKETCH_PX);
        for k in 0..6 {
            cpu::conv(&self.convs[k], &s.a, &mut s.b, Post::Relu, threads);
            cpu::pool2(&s.b, &mut s.a, threads);
        }
        cpu::conv(&self.convs[6], &s.a, &mut s.b, Post::None, threads);
        let out = s.b.to_chw();
        let n = LATENT;
        (out[..n].to_vec(), out[n..2 * n].iter().map(|v| v.clamp(-12.0, 6.0)).collect())
    }

    /// The decoder's reading of code `z` as a [`Soft`] sketch.
    pub fn soft(&self, z: &[f32], s: &mut VaeScratch, threads: usize) -> Soft {
        s.a.set_chw(z, LATENT_CHANNELS, CODE_PX, CODE_PX);
        cpu::conv(&self.convs[7], &s.a, &mut s.b, Post::Relu, threads);
        for k in 0..6 {
            cpu::up2(&s.b, &mut s.a);
            cpu::conv(&self.convs[8 + k], &s.a, &mut s.b, Post::Relu, threads);
        }
        cpu::conv(&self.convs[14], &s.b, &mut s.a, Post::None, threads);
        let n = SKETCH_PX * SKETCH_PX;
        let mut out = Soft { band: Vec::with_capacity(n), likeliest: Vec::with_capacity(n), ridge: Vec::with_capacity(n), valley: Vec::with_capacity(n) };
        for p in 0..n {
            let l = s.a.pixel(p / SKETCH_PX, p % SKETCH_PX);
            let top = l[..BANDS].iter().copied().fold(f32::NEG_INFINITY, f32::max);
            let e: Vec<f32> = l[..BANDS].iter().map(|v| (v - top).exp()).collect();
            let sum: f32 = e.iter().sum();
            out.band.push(e.iter().enumerate().map(|(k, w)| k as f32 * w).sum::<f32>() / sum);
            out.likeliest.push((0..BANDS).max_by(|&a, &b| l[a].total_cmp(&l[b])).unwrap_or(0) as u8);
            out.ridge.push(l[BANDS]);
            out.valley.push(l[BANDS + 1]);
        }
        out
    }

    /// The sketch of code `z` on its own: the likeliest band per pixel, and as many ridge and
    /// valley pixels as `strokes` asks for at the highest stroke logits (the stroke layers
    /// score a rare class and seldom pass one half, so a fixed threshold would draw none).
    /// Validation scores reconstructions with it.
    pub fn decode(&self, z: &[f32], strokes: StrokeCount, s: &mut VaeScratch, threads: usize) -> Sketch {
        let soft = self.soft(z, s, threads);
        Sketch { band: soft.likeliest, ridge: strongest(&soft.ridge, strokes.ridge), valley: strongest(&soft.valley, strokes.valley) }
    }

    /// `n` variants of `sketch`: codes around its own (its mean plus [`VARIANT_SPREAD`] ×
    /// seeded normal noise), each applied as the change the decoder sees between the new code
    /// and the sketch's own ([`edit`]), so a variant keeps the sketch's detail — its strokes
    /// and band borders — wherever the code's change does not reach; then tidied
    /// ([`crate::sketch::tidy::tidy`]): no band island or stroke speck the sketch does not
    /// have. The same seed gives the same variants.
    pub fn variants(&self, sketch: &Sketch, n: usize, seed: u64, s: &mut VaeScratch, threads: usize) -> Vec<Sketch> {
        self.untidied_variants(sketch, n, seed, s, threads).iter().map(|v| tidy(v, &[sketch])).collect()
    }

    /// [`Self::variants`] as the edit makes them, before tidying (to measure what tidying
    /// changes).
    pub fn untidied_variants(&self, sketch: &Sketch, n: usize, seed: u64, s: &mut VaeScratch, threads: usize) -> Vec<Sketch> {
        let (mu, _) = self.encode(sketch, s, threads);
        let own = self.soft(&mu, s, threads);
        (0..n)
            .map(|k| {
                let z: Code = mu.iter().enumerate().map(|(i, m)| m + VARIANT_SPREAD * crate::models::tcm::gauss(mix64(seed ^ mix64((k * LATENT + i) as u64 + 1)))).collect();
                edit(&[(sketch, 1.0)], &[(&self.soft(&z, s, threads), 1.0), (&own, -1.0)])
            })
            .collect()
    }

    /// The sketch between `a` (α = 1, exactly `a`) and `b` (α = 0, exactly `b`): the
    /// α-blend of the two sketches plus the change the decoder sees between the code
    /// α·z_a + (1 − α)·z_b and the α-blend of the two codes' own readings ([`edit`]), tidied
    /// ([`crate::sketch::tidy::tidy`]): no band island or stroke speck that neither has.
    pub fn interpolate(&self, a: &Sketch, b: &Sketch, alpha: f32, s: &mut VaeScratch, threads: usize) -> Sketch {
        let alpha = alpha.clamp(0.0, 1.0);
        let (za, _) = self.encode(a, s, threads);
        let (zb, _) = self.encode(b, s, threads);
        let z: Code = za.iter().zip(&zb).map(|(x, y)| alpha * x + (1.0 - alpha) * y).collect();
        let (ra, rb, rz) = (self.soft(&za, s, threads), self.soft(&zb, s, threads), self.soft(&z, s, threads));
        tidy(&edit(&[(a, alpha), (b, 1.0 - alpha)], &[(&rz, 1.0), (&ra, -alpha), (&rb, alpha - 1.0)]), &[a, b])
    }
}

/// A decoded code before rounding: per pixel ([`SKETCH_PX`]², row-major) the expected band
/// (0–3, the softmax-weighted mean), the likeliest band, and the ridge and valley logits.
#[derive(Clone, Debug)]
pub struct Soft {
    /// Expected band (0.0–3.0).
    pub band: Vec<f32>,
    /// Likeliest band.
    pub likeliest: Vec<u8>,
    /// Ridge logit.
    pub ridge: Vec<f32>,
    /// Valley logit.
    pub valley: Vec<f32>,
}

/// A weighted sum of sketches plus a weighted sum of decoder readings, rounded back to a
/// sketch: per pixel the band is Σ wᵢ·bandᵢ + Σ vⱼ·expected bandⱼ, rounded and kept in 0–3;
/// a stroke is drawn where Σ wᵢ·strokeᵢ (1 or 0) + Σ vⱼ·probabilityⱼ reaches one half (halfway
/// through a blend both sketches' strokes show). The
/// readings' weights sum to zero in every use, so an unchanged code leaves the sketches'
/// blend as it is.
pub fn edit(sketches: &[(&Sketch, f32)], readings: &[(&Soft, f32)]) -> Sketch {
    let n = SKETCH_PX * SKETCH_PX;
    let sigmoid = |x: f32| 1.0 / (1.0 + (-x).exp());
    let mut out = Sketch::filled(0);
    for p in 0..n {
        let mut band = 0.0;
        let (mut ridge, mut valley) = (0.0, 0.0);
        for (sk, w) in sketches {
            band += w * sk.band[p] as f32;
            ridge += if sk.ridge[p] { *w } else { 0.0 };
            valley += if sk.valley[p] { *w } else { 0.0 };
        }
        for (r, v) in readings {
            band += v * r.band[p];
            ridge += v * sigmoid(r.ridge[p]);
            valley += v * sigmoid(r.valley[p]);
        }
        out.band[p] = band.round().clamp(0.0, (BANDS - 1) as f32) as u8;
        out.ridge[p] = ridge >= 0.5;
        out.valley[p] = valley >= 0.5;
    }
    out
}

/// How many ridge and valley pixels a decoded sketch gets (validation reconstructs a sketch
/// with its own counts).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct StrokeCount {
    /// Ridge pixels.
    pub ridge: usize,
    /// Valley pixels.
    pub valley: usize,
}

impl StrokeCount {
    /// The stroke pixels of `sketch`.
    pub fn of(sketch: &Sketch) -> Self {
        let count = |v: &[bool]| v.iter().filter(|&&x| x).count();
        Self { ridge: count(&sketch.ridge), valley: count(&sketch.valley) }
    }
}

/// The `k` pixels with the highest `scores` (ties by position), as a mask.
fn strongest(scores: &[f32], k: usize) -> Vec<bool> {
    let mut mask = vec![false; scores.len()];
    let mut order: Vec<usize> = (0..scores.len()).collect();
    let k = k.min(scores.len());
    if k > 0 {
        order.select_nth_unstable_by(k - 1, |&a, &b| scores[b].total_cmp(&scores[a]).then(a.cmp(&b)));
        for &p in &order[..k] {
            mask[p] = true;
        }
    }
    mask
}

/// The sketch models the page and `terrain sketch-variants` use together: the generator, the
/// VAE and the hash that names them.
#[derive(Clone, Debug)]
pub struct SketchModels {
    /// The sketch → terrain generator.
    pub generator: crate::models::sketch::SketchGenCpu,
    /// The VAE (variants, blends).
    pub vae: SketchVaeCpu,
    /// Short hash of both weight files ([`crate::models::weights_hash`]).
    pub hash: String,
}

impl SketchModels {
    /// Reads both weight files (burnpack bytes); a broken file is an error naming it.
    pub fn from_bytes(generator: &[u8], vae: &[u8]) -> Result<Self, crate::models::WeightError> {
        let g = crate::models::sketch::SketchGenCpu::from_burnpack(generator).map_err(|e| e.in_file(crate::models::sketch::WEIGHT_FILE))?;
        let v = SketchVaeCpu::from_burnpack(vae).map_err(|e| e.in_file(WEIGHT_FILE))?;
        Ok(Self { generator: g, vae: v, hash: crate::models::weights_hash(&[generator, vae]) })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A broken weight file is an error naming it: the generator's when it is broken, the
    /// VAE's when the generator's is whole and the VAE's is broken.
    #[test]
    fn a_broken_generator_or_vae_file_is_named() {
        let err = SketchModels::from_bytes(b"not weights", b"not weights").unwrap_err();
        assert!(err.to_string().starts_with(crate::models::sketch::WEIGHT_FILE), "{err}");
        let generator = std::fs::read(crate::repo_root().join("weights").join(crate::models::sketch::WEIGHT_FILE)).unwrap();
        let err = SketchModels::from_bytes(&generator, b"not weights").unwrap_err();
        assert!(err.to_string().starts_with(WEIGHT_FILE) && WEIGHT_FILE != crate::models::sketch::WEIGHT_FILE, "{err}");
    }

    #[test]
    fn strongest_marks_exactly_the_k_highest_scores_and_none_for_k_0() {
        let scores = [0.3, -2.0, 5.0, 0.31, -0.5, 5.0];
        let pick = |k| strongest(&scores, k).iter().enumerate().filter(|&(_, &m)| m).map(|(i, _)| i).collect::<Vec<_>>();
        assert_eq!(pick(0), Vec::<usize>::new());
        assert_eq!(pick(2), vec![2, 5]);
        assert_eq!(pick(3), vec![2, 3, 5]);
        assert_eq!(pick(99).len(), 6);
    }

    fn test_sketch() -> Sketch {
        let mut sk = Sketch::filled(1);
        for p in 0..sk.band.len() {
            sk.band[p] = ((p % SKETCH_PX) / 64) as u8;
            sk.ridge[p] = (p / SKETCH_PX) % 50 == 7 && p % SKETCH_PX < 100;
            sk.valley[p] = p % SKETCH_PX == 30;
        }
        sk
    }

    #[test]
    fn a_blend_is_exactly_sketch_a_at_alpha_1_and_exactly_b_at_alpha_0() {
        let vae = SketchVaeCpu::randomized(5, 0.05);
        let a = test_sketch();
        let mut b = Sketch::filled(2);
        b.valley[SKETCH_PX * 9 + 9] = true;
        let mut s = VaeScratch::default();
        assert_eq!(vae.interpolate(&a, &b, 1.0, &mut s, 2), a);
        assert_eq!(vae.interpolate(&a, &b, 0.0, &mut s, 2), b);
        // Halfway, both sketches' strokes show.
        let mid = vae.interpolate(&a, &b, 0.5, &mut s, 2);
        assert!(mid.ridge[7 * SKETCH_PX] && mid.valley[SKETCH_PX * 9 + 9] && mid.valley[30]);
    }

    #[test]
    fn an_edit_by_a_reading_one_band_higher_raises_every_band_by_one_up_to_3_and_adds_strokes_where_likely() {
        let sk = test_sketch();
        let n = SKETCH_PX * SKETCH_PX;
        let flat = Soft { band: vec![1.0; n], likeliest: vec![1; n], ridge: vec![-9.0; n], valley: vec![-9.0; n] };
        let mut up = flat.clone();
        up.band = vec![2.0; n];
        up.ridge[5] = 9.0;
        assert_eq!(edit(&[(&sk, 1.0)], &[(&flat, 1.0), (&flat, -1.0)]), sk);
        let e = edit(&[(&sk, 1.0)], &[(&up, 1.0), (&flat, -1.0)]);
        for p in 0..n {
            assert_eq!(e.band[p], (sk.band[p] + 1).min(3));
        }
        assert!(e.ridge[5] && !sk.ridge[5]);
        assert_eq!(StrokeCount::of(&e), StrokeCount { ridge: 501, valley: 256 });
    }

    /// Codes have 128 numbers; the VAE stays under 1 M parameters; the CPU kernels compute the
    /// burn encoder and decoder (random weights ±0.1: means within 1e-4, and the decoded
    /// sketch equal to the argmax/threshold of burn's logits on all but tie pixels).
    #[cfg(feature = "train")]
    #[test]
    fn cpu_encode_decode_equal_burn() {
        use burn::tensor::TensorData;
        assert_eq!(LATENT, 128);
        let device = Device::flex();
        let m = crate::models::random_weights(SketchVae::new(&device), &device, 21, 0.1);
        assert!(m.parameters() <= 1_000_000, "{} parameters", m.parameters());
        let c = SketchVaeCpu::from_model(&m).unwrap();
        let mut sk = Sketch::filled(1);
        for p in 0..sk.band.len() {
            sk.band[p] = ((p % SKETCH_PX) / 64) as u8;
            sk.ridge[p] = (p / SKETCH_PX) % 50 == 7;
        }
        let x = Tensor::<4>::from_data(TensorData::new(sk.channels(), [1, INPUT_CHANNELS, SKETCH_PX, SKETCH_PX]), &device);
        let (mu, logvar) = m.encode(x);
        let mu_b: Vec<f32> = mu.clone().into_data().try_to_vec().unwrap();
        let lv_b: Vec<f32> = logvar.into_data().try_to_vec().unwrap();
        let mut s = VaeScratch::default();
        let (mu_c, lv_c) = c.encode(&sk, &mut s, 2);
        let worst = mu_b.iter().chain(&lv_b).zip(mu_c.iter().chain(&lv_c)).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-4, "encoder differs by {worst}");
        let logits: Vec<f32> = m.decode(mu).into_data().try_to_vec().unwrap();
        let n = SKETCH_PX * SKETCH_PX;
        // As many stroke pixels as burn's logits have above zero: the same pixels.
        let positive = |layer: usize| (0..n).filter(|&p| logits[layer * n + p] > 0.0).count();
        let dec = c.decode(&mu_c, StrokeCount { ridge: positive(BANDS), valley: positive(BANDS + 1) }, &mut s, 1);
        let mut differ = 0;
        for p in 0..n {
            let band = (0..BANDS).max_by(|&a, &b| logits[a * n + p].total_cmp(&logits[b * n + p])).unwrap() as u8;
            if band != dec.band[p] || (logits[BANDS * n + p] > 0.0) != dec.ridge[p] || (logits[(BANDS + 1) * n + p] > 0.0) != dec.valley[p] {
                differ += 1;
            }
        }
        assert!(differ <= n / 1000, "{differ} pixels differ");
    }
}
