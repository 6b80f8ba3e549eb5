//! The terrain enhancement module (TEM): a ×2 super-resolution CNN of 47,497 parameters. It
//! takes one quadrant (h × h heights, metres) and returns the full-resolution tile (2h × 2h,
//! metres): a learned residual added to the bicubic upsampling of its input. Five of them make
//! the 32 → 16 → 8 → 4 → 2 → 1 m ladder.
//!
//! Architecture (SPEC.md): head conv3×3 4→32; body 4 × (conv3×3 32→32 + ReLU) + conv3×3 32→32
//! with a skip from the head; tail PixelShuffle(2) then conv3×3 8→1. Inputs: height, gradient
//! along x, gradient along z and |gx| + |gz|, after subtracting the patch mean and dividing by
//! 40 m (gradients ×10).

use burn::module::Module;
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{PixelShuffle, PixelShuffleConfig};
use burn::tensor::activation::relu;
use burn::tensor::module::interpolate;
use burn::tensor::ops::{InterpolateMode, InterpolateOptions};
use burn::tensor::{Device, Tensor};

/// Heights are divided by this after subtracting the patch mean (metres).
pub const HEIGHT_SCALE_M: f32 = 40.0;
/// Gain applied to gradients of normalised heights.
pub const GRADIENT_GAIN: f32 = 10.0;
/// Number of TEM levels.
pub const LEVELS: usize = 5;
/// Output spacing of each level (metres per pixel): level k turns 2·s into s.
pub const LEVEL_SPACING_M: [f64; LEVELS] = [16.0, 8.0, 4.0, 2.0, 1.0];
/// Channels of the body.
const WIDTH: usize = 32;

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
    /// A freshly initialised model on `device`.
    pub fn new(device: &Device) -> Self {
        Self {
            head: conv(4, WIDTH, device),
            body: (0..4).map(|_| conv(WIDTH, WIDTH, device)).collect(),
            merge: conv(WIDTH, WIDTH, device),
            shuffle: PixelShuffleConfig::new(2).init(),
            tail: conv(WIDTH / 4, 1, device),
        }
    }

    /// Enhances a batch of patches: `x` is [B, 1, h, w] heights in metres, the result
    /// [B, 1, 2h, 2w] heights in metres at half the spacing.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let [_, _, h, w] = x.dims();
        let mean = x.clone().mean_dim(3).mean_dim(2);
        let xn = (x - mean.clone()) / HEIGHT_SCALE_M;
        self.forward_normalised(xn, [2 * h, 2 * w]) * HEIGHT_SCALE_M + mean
    }

    /// The network on normalised heights (mean 0, units of 40 m): returns the normalised
    /// enhanced patch of size `out`.
    pub fn forward_normalised(&self, xn: Tensor<4>, out: [usize; 2]) -> Tensor<4> {
        let feats = features(xn.clone());
        let head = self.head.forward(feats);
        let mut b = head.clone();
        for c in &self.body {
            b = relu(c.forward(b));
        }
        let b = self.merge.forward(b) + head;
        let residual = self.tail.forward(self.shuffle.forward(b));
        let base = interpolate(xn, InterpolateOptions::new(InterpolateMode::Bicubic).with_align_corners(false).with_output_size(out));
        base + residual
    }
}

/// The four input channels from normalised heights [B, 1, h, w]: height, ∂/∂x, ∂/∂z (central
/// differences, edges replicated, ×10) and |∂/∂x| + |∂/∂z|.
pub fn features(xn: Tensor<4>) -> Tensor<4> {
    let [_, _, h, w] = xn.dims();
    let shift = |t: &Tensor<4>, dim: usize, n: usize| {
        let prev = Tensor::cat(vec![t.clone().narrow(dim, 0, 1), t.clone().narrow(dim, 0, n - 1)], dim);
        let next = Tensor::cat(vec![t.clone().narrow(dim, 1, n - 1), t.clone().narrow(dim, n - 1, 1)], dim);
        (next - prev) * (0.5 * GRADIENT_GAIN)
    };
    let gx = shift(&xn, 3, w);
    let gz = shift(&xn, 2, h);
    let mag = gx.clone().abs() + gz.clone().abs();
    Tensor::cat(vec![xn, gx, gz, mag], 1)
}

#[cfg(all(test, feature = "train"))]
mod tests {
    use super::*;
    use burn::tensor::TensorData;

    #[test]
    fn has_the_papers_parameter_count() {
        let m = Tem::new(&Device::flex());
        assert_eq!(m.num_params(), 47_497);
    }

    #[test]
    fn doubles_the_size_and_keeps_the_mean_level() {
        let device = Device::flex();
        let m = Tem::new(&device);
        let data: Vec<f32> = (0..2 * 16 * 16).map(|k| 1500.0 + (k % 16) as f32 * 3.0 + (k / 256) as f32 * 200.0).collect();
        let x = Tensor::<4>::from_data(TensorData::new(data, [2, 1, 16, 16]), &device);
        let y = m.forward(x);
        assert_eq!(y.dims(), [2, 1, 32, 32]);
        let v: Vec<f32> = y.into_data().try_to_vec::<f32>().unwrap();
        let mean0 = v[..1024].iter().sum::<f32>() / 1024.0;
        let mean1 = v[1024..].iter().sum::<f32>() / 1024.0;
        // An untrained residual is small next to the 200 m offset between the two patches.
        assert!((mean1 - mean0 - 200.0).abs() < 40.0, "{mean0} {mean1}");
    }

    #[test]
    fn gradient_features_see_a_ramp() {
        let device = Device::flex();
        let x = Tensor::<4>::from_data(TensorData::new((0..16).map(|k| (k % 4) as f32 * 0.1).collect::<Vec<_>>(), [1, 1, 4, 4]), &device);
        let f: Vec<f32> = features(x).into_data().try_to_vec::<f32>().unwrap();
        // channel 1 (∂/∂x) inside: (0.2 − 0.0)/2 × 10 = 1.0; channel 2 (∂/∂z) is 0.
        assert!((f[16 + 1] - 1.0).abs() < 1e-5, "{}", f[17]);
        assert!(f[32..48].iter().all(|v| v.abs() < 1e-6));
        assert!((f[48 + 1] - 1.0).abs() < 1e-5);
    }
}
