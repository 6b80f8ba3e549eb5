//! Integer-exact inference: a network's weights and activations on power-of-two integer grids,
//! carried in f32, so that every sum a convolution forms is an integer below 2²⁴ and therefore
//! exact. Then the order of the sums, fused multiply-adds, the CPU's vector width, the page's
//! SIMD128 or a GPU's convolution all give the same bits, where float inference differs in the
//! last bits and the world's drainage turns those bits into metres (issue 37).
//!
//! A layer ([`quantize`]) takes inputs on grids of 2^`in_exp[i]` (real value = integer ×
//! 2^exp) whose levels lie in `in_range[i]`. Each output channel `c` gets its own accumulator
//! grid 2^`acc_exp[c]`: the finest on which its weights, with the input grids folded in, need
//! at most [`WEIGHT_LEVELS`] levels, coarsened until every partial sum it can form (each
//! term's extremes by its sign over its input's range, plus the bias) stays below 2²⁴
//! ([`F32_EXACT`]). The output is rounded to
//! the layer's activation grid 2^`out_exp` and clamped to [`ACT_LEVELS`]
//! ([`crate::models::cpu::requantize`]): a multiplication by a power of two, an addition of ½
//! and a floor, each exact.

use crate::models::cpu::{Conv3, LayerError};

/// Every integer of magnitude below this is exact in f32 (2²⁴).
pub const F32_EXACT: f64 = 16_777_216.0;

/// Largest weight level (magnitude) of a quantized layer: 9-bit weights where the bound on the
/// sums allows (most channels of the wide layers get fewer).
pub const WEIGHT_LEVELS: f64 = 255.0;

/// Largest activation level after a ReLU: 10-bit activations.
pub const ACT_LEVELS: f32 = 1023.0;

/// 2^`k` in f32, exactly (normal range only).
pub fn pow2(k: i32) -> f32 {
    assert!((-126..=127).contains(&k), "2^{k} is outside f32's normal range");
    f32::from_bits(((127 + k) as u32) << 23)
}

/// The smallest `e` with `v` ≤ `levels` · 2^`e` (`v` > 0), by exact comparisons.
pub fn grid_exp(v: f64, levels: f64) -> i32 {
    let mut e = (v / levels).log2().ceil() as i32;
    while v > levels * 2f64.powi(e) {
        e += 1;
    }
    while v <= levels * 2f64.powi(e - 1) {
        e -= 1;
    }
    e
}

/// One quantized 3×3 convolution: integer weights and biases (as f32) and, per output channel,
/// its accumulator grid.
#[derive(Clone, Debug)]
pub struct ExactConv {
    /// The layer with integer weights and biases (accumulator units).
    pub conv: Conv3,
    /// Per output channel: the accumulator's grid exponent (real value = sum × 2^exp).
    pub acc_exp: Vec<i32>,
    /// The largest magnitude any partial sum of any output channel can reach (from the input
    /// ranges), below [`F32_EXACT`].
    pub bound: f64,
}

impl ExactConv {
    /// The factors that take each output channel's sums to the grid 2^`out_exp` (powers of
    /// two, for [`crate::models::cpu::requantize`]).
    pub fn to_grid(&self, out_exp: i32) -> Vec<f32> {
        self.acc_exp.iter().map(|&e| pow2(e - out_exp)).collect()
    }
}

/// ⌊v · scale[c] + ½⌋ per channel `c` of `v` [B, C, H, W], clamped to ±`max`: burn's twin
/// of [`crate::models::cpu::requantize`], exact for the powers of two used.
pub fn grid_burn(v: burn::tensor::Tensor<4>, scale: &[f32], max: f32) -> burn::tensor::Tensor<4> {
    let s = burn::tensor::Tensor::<1>::from_data(burn::tensor::TensorData::new(scale.to_vec(), [scale.len()]), &v.device()).reshape([1, scale.len(), 1, 1]);
    (v * s + 0.5).floor().clamp(-max, max)
}

/// The largest |value| × `unit(c)` of `map` (channel `c`), or `most` if larger: what a
/// calibration records at a rounding point (real units).
pub(crate) fn largest(map: &crate::models::cpu::Map, unit: impl Fn(usize) -> f32, most: f32) -> f32 {
    let mut m = most;
    for y in 0..map.height() {
        for x in 0..map.width() {
            for (c, &v) in map.pixel(y, x).iter().enumerate() {
                m = m.max(v.abs() * unit(c));
            }
        }
    }
    m
}

/// Quantizes `layer` for inputs on grids 2^`in_exp[i]` whose levels lie in `in_range[i]`
/// (lowest, highest) per input channel (see the module documentation). Deterministic on every
/// platform: powers of two, exact comparisons and round-half-even only.
pub fn quantize(layer: &Conv3, in_exp: &[i32], in_range: &[(f32, f32)]) -> Result<ExactConv, LayerError> {
    let (cin, cout) = (layer.cin(), layer.cout());
    assert!(in_exp.len() == cin && in_range.len() == cin, "one grid and range per input channel");
    let (w, b) = layer.to_oihw();
    let mut wq = vec![0f32; w.len()];
    let mut bq = vec![0f32; cout];
    let mut acc_exp = vec![0; cout];
    let mut bound = 0f64;
    for o in 0..cout {
        let real = |i: usize, t: usize| w[(o * cin + i) * 9 + t] as f64 * 2f64.powi(in_exp[i]);
        let largest = (0..cin).flat_map(|i| (0..9).map(move |t| (i, t))).map(|(i, t)| real(i, t).abs()).fold(0f64, f64::max);
        let largest = if largest > 0.0 { largest } else { (b[o] as f64).abs().max(f64::MIN_POSITIVE) };
        let mut e = grid_exp(largest, WEIGHT_LEVELS);
        loop {
            let step = 2f64.powi(e);
            // Every partial sum, in any order, lies between the sum of the terms' (and the
            // bias's) negative extremes and the sum of their positive ones.
            let bias = (b[o] as f64 / step).round_ties_even();
            let (mut lo, mut hi) = (bias.min(0.0), bias.max(0.0));
            for (i, &(a, z)) in in_range.iter().enumerate() {
                for t in 0..9 {
                    let w = (real(i, t) / step).round_ties_even();
                    let (p, q) = (w * a as f64, w * z as f64);
                    lo += p.min(q).min(0.0);
                    hi += p.max(q).max(0.0);
                }
            }
            let sum = hi.max(-lo);
            if sum < F32_EXACT {
                for i in 0..cin {
                    for t in 0..9 {
                        wq[(o * cin + i) * 9 + t] = (real(i, t) / step).round_ties_even() as f32;
                    }
                }
                bq[o] = (b[o] as f64 / step).round_ties_even() as f32;
                bound = bound.max(sum);
                acc_exp[o] = e;
                break;
            }
            e += 1;
        }
    }
    Ok(ExactConv { conv: Conv3::from_oihw(cout, cin, &wq, Some(&bq))?, acc_exp, bound })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::models::cpu::{self, Kernels, Map, Post};

    #[test]
    fn pow2_and_grid_exp_are_exact() {
        assert_eq!(pow2(0), 1.0);
        assert_eq!(pow2(-8), 1.0 / 256.0);
        assert_eq!(pow2(10), 1024.0);
        assert_eq!(grid_exp(127.0, 127.0), 0);
        assert_eq!(grid_exp(127.5, 127.0), 1);
        assert_eq!(grid_exp(63.5, 127.0), -1);
        assert_eq!(grid_exp(63.6, 127.0), 0);
    }

    /// A random layer quantized for 1023-level inputs keeps every possible sum below 2²⁴, its
    /// weights within 127 levels and within half a step of the real weights; and on integer
    /// inputs the portable and the widest kernels (fused multiply-adds included) give the same
    /// bits.
    #[test]
    fn a_quantized_layer_sums_below_2_pow_24_and_gives_the_same_bits_on_every_kernel() {
        let layer = Conv3::random(48, 224, 3, 0.2);
        let q = quantize(&layer, &vec![-4; 224], &vec![(-ACT_LEVELS, ACT_LEVELS); 224]).unwrap();
        assert!(q.bound < F32_EXACT, "{}", q.bound);
        let (w, _) = layer.to_oihw();
        let (wq, _) = q.conv.to_oihw();
        for o in 0..48 {
            let step = 2f64.powi(q.acc_exp[o]);
            for k in 0..224 * 9 {
                let (real, int) = (w[o * 224 * 9 + k] as f64 / 16.0, wq[o * 224 * 9 + k] as f64);
                assert!(int.abs() <= WEIGHT_LEVELS && int.fract() == 0.0, "{int}");
                assert!((real - int * step).abs() <= step / 2.0 + 1e-12, "{real} {int} {step}");
            }
        }
        // The largest possible input everywhere: sums reach their bound's order.
        let mut s = 7u64;
        let x: Vec<f32> = (0..224 * 20 * 20).map(|_| (cpu::unit(&mut s) * ACT_LEVELS).floor()).collect();
        let mut src = Map::default();
        src.set_chw(&x, 224, 20, 20);
        let run = |conv: &Conv3, k: Kernels| {
            let mut dst = Map::default();
            cpu::conv_impl(conv, &src, &mut dst, Post::None, 1, k);
            dst.to_chw()
        };
        let portable = run(&q.conv, Kernels::Portable);
        assert!(portable.iter().all(|v| v.fract() == 0.0));
        assert_eq!(portable, run(&q.conv, Kernels::Best));
        assert_eq!(portable, run(&q.conv.clone().with_fused(true), Kernels::Best));
        assert_eq!(portable, run(&q.conv.clone().with_fused(true), Kernels::Avx2));
    }
}
