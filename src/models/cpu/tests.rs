//! Tests of the module.

use super::*;

/// The average of two weight files is their midpoint, weight by weight; files of another
/// network (other shapes) or an empty list are refused.
#[test]
fn the_average_of_two_weight_files_is_their_midpoint_and_other_shapes_are_refused() {
    let layers: Vec<(String, usize, usize)> = vec![("a".into(), 8, 4), ("b".into(), 4, 8)];
    let (x, y) = (random_convs(&layers, 1, 0.5), random_convs(&layers, 2, 0.5));
    let avg = average_burnpacks(&[convs_to_burnpack(&layers, &x), convs_to_burnpack(&layers, &y)]).unwrap();
    let back = convs_from_burnpack(&avg, &layers).unwrap();
    for ((p, q), m) in x.iter().zip(&y).zip(&back) {
        let ((wp, bp), (wq, bq), (wm, bm)) = (p.to_oihw(), q.to_oihw(), m.to_oihw());
        for ((a, b), c) in wp.iter().chain(&bp).zip(wq.iter().chain(&bq)).zip(wm.iter().chain(&bm)) {
            assert!((c - (a + b) / 2.0).abs() < 1e-6, "{c} vs {a} and {b}");
        }
    }
    let other: Vec<(String, usize, usize)> = vec![("a".into(), 8, 4), ("b".into(), 4, 9)];
    let z = convs_to_burnpack(&other, &random_convs(&other, 3, 0.5));
    assert!(average_burnpacks(&[convs_to_burnpack(&layers, &x), z]).is_err());
    assert!(average_burnpacks(&[]).is_err());
}

/// Weight files round-trip: written as float32 they read back bit for bit; halved, every
/// weight and bias is within half a float16 step (relative 2⁻¹¹) of the original and the
/// file is at most 55 % of the float32 file's size. A float64 tensor is refused by name.
#[test]
fn weight_files_round_trip_in_float32_and_float16() {
    let layers: Vec<(String, usize, usize)> = vec![("a".into(), 64, 32), ("b".into(), 32, 64)];
    let convs = random_convs(&layers, 11, 0.5);
    let bytes = convs_to_burnpack(&layers, &convs);
    let back = convs_from_burnpack(&bytes, &layers).unwrap();
    for (x, y) in convs.iter().zip(&back) {
        assert_eq!(x.to_oihw(), y.to_oihw());
    }
    let half = to_half_burnpack(&bytes).unwrap();
    assert!(half.len() * 100 <= bytes.len() * 55, "{} of {} bytes", half.len(), bytes.len());
    let back = convs_from_burnpack(&half, &layers).unwrap();
    for (x, y) in convs.iter().zip(&back) {
        let ((w0, b0), (w1, b1)) = (x.to_oihw(), y.to_oihw());
        for (a, b) in w0.iter().chain(&b0).zip(w1.iter().chain(&b1)) {
            assert!((a - b).abs() <= a.abs() * 2f32.powi(-11) + 1e-7, "{a} vs {b}");
        }
    }
    let f64_file = burn_pack::Writer::new(vec![burn_pack::Tensor::new("a.weight".into(), burn_pack::DType::F64, vec![1], None, burn_pack::Bytes::from_bytes_vec(vec![0; 8]))])
        .into_bytes()
        .unwrap()
        .to_vec();
    let err = convs_from_burnpack(&f64_file, &layers[..1]).unwrap_err();
    assert!(matches!(&err, crate::models::WeightError::Type { name, dtype } if name == "a.weight" && dtype == "F64"), "{err}");
}

/// A 16 → 6 layer padded to 8 outputs gives the same first 6 channels on every pixel of
/// a 40×40 map (bit for bit on the portable kernel, within 1e-5 on AVX2), and zeros in
/// the 2 added ones.
#[test]
fn padding_the_output_channels_keeps_the_outputs() {
    let layer = Conv3::random(6, 16, 3, 0.3);
    let padded = layer.padded_for_simd();
    assert_eq!((padded.cin, padded.cout), (16, 8));
    let mut src = Map::default();
    let input: Vec<f32> = (0..16 * 40 * 40).map(|k| ((k * 7919) % 1000) as f32 / 500.0 - 1.0).collect();
    src.set_chw(&input, 16, 40, 40);
    for kernels in [Kernels::Portable, Kernels::Avx2, Kernels::Best] {
        let portable = kernels == Kernels::Portable;
        let (mut a, mut b) = (Map::default(), Map::default());
        conv_impl(&layer, &src, &mut a, Post::None, 1, kernels);
        conv_impl(&padded, &src, &mut b, Post::None, 1, kernels);
        let tol = if portable { 0.0 } else { 1e-5 };
        for p in 0..40 * 40 {
            let (x, y) = (a.pixel(p / 40, p % 40), b.pixel(p / 40, p % 40));
            for c in 0..6 {
                assert!((x[c] - y[c]).abs() <= tol, "pixel {p} channel {c}: {} vs {}", x[c], y[c]);
            }
            assert_eq!(&y[6..], &[0.0, 0.0]);
        }
    }
}

use super::unit as lcg;

/// Direct evaluation of the definition (NCHW, zero padding) for comparison.
fn naive(w: &[f32], b: &[f32], cout: usize, cin: usize, x: &[f32], h: usize, wd: usize) -> Vec<f32> {
    let mut y = vec![0f32; cout * h * wd];
    for o in 0..cout {
        for r in 0..h {
            for c in 0..wd {
                let mut acc = b[o] as f64;
                for i in 0..cin {
                    for ky in 0..3 {
                        for kx in 0..3 {
                            let (rr, cc) = (r as i64 + ky as i64 - 1, c as i64 + kx as i64 - 1);
                            if rr >= 0 && cc >= 0 && (rr as usize) < h && (cc as usize) < wd {
                                acc += (w[((o * cin + i) * 3 + ky) * 3 + kx] * x[(i * h + rr as usize) * wd + cc as usize]) as f64;
                            }
                        }
                    }
                }
                y[(o * h + r) * wd + c] = acc as f32;
            }
        }
    }
    y
}

fn map_from_nchw(x: &[f32], c: usize, h: usize, w: usize) -> Map {
    let mut m = Map::default();
    m.reset(h, w, c);
    for i in 0..c {
        for r in 0..h {
            for q in 0..w {
                m.pixel_mut(r, q)[i] = x[(i * h + r) * w + q];
            }
        }
    }
    m
}

/// Every kernel (32 output channels blocked — AVX-512, AVX2 and portable —, 1 from 8 or 16 as
/// dot products, 3 plain), fused or not, widths that are and are not a
/// multiple of BLOCK, 1 and 3 threads, with ReLU and a skip: every output within 1e-4 of
/// the definition evaluated in f64, and the zero border stays zero.
#[test]
fn convolutions_match_the_definition_for_every_kernel_and_thread_count() {
    let mut seed = 7;
    for (cout, cin, h, w) in [(32, 4, 9, 13), (32, 32, 6, 8), (3, 5, 7, 6), (32, 8, 5, 5), (1, 16, 7, 9), (1, 8, 6, 11), (24, 7, 9, 10), (48, 24, 5, 7), (16, 13, 6, 6)] {
        let wt: Vec<f32> = (0..cout * cin * 9).map(|_| lcg(&mut seed)).collect();
        let b: Vec<f32> = (0..cout).map(|_| lcg(&mut seed)).collect();
        let x: Vec<f32> = (0..cin * h * w).map(|_| lcg(&mut seed)).collect();
        let skip_v: Vec<f32> = (0..cout * h * w).map(|_| lcg(&mut seed)).collect();
        let want = naive(&wt, &b, cout, cin, &x, h, w);
        let src = map_from_nchw(&x, cin, h, w);
        let skip = map_from_nchw(&skip_v, cout, h, w);
        for (threads, kernels, fused) in
            [1, 3].into_iter().flat_map(|t| [Kernels::Best, Kernels::Avx2, Kernels::Portable].into_iter().flat_map(move |k| [(t, k, false), (t, k, true)]))
        {
            let layer = Conv3::from_oihw(cout, cin, &wt, Some(&b)).unwrap().with_fused(fused);
            for post in [Post::None, Post::Relu, Post::Add(&skip)] {
                let mut dst = Map::default();
                conv_impl(&layer, &src, &mut dst, post, threads, kernels);
                let mut worst = 0f32;
                for o in 0..cout {
                    for r in 0..h {
                        for q in 0..w {
                            let k = (o * h + r) * w + q;
                            let e = match post {
                                Post::None => want[k],
                                Post::Relu => want[k].max(0.0),
                                Post::Add(_) => want[k] + skip_v[k],
                            };
                            worst = worst.max((dst.pixel(r, q)[o] - e).abs());
                        }
                    }
                }
                assert!(worst < 1e-4, "{cout}x{cin} {h}x{w} threads {threads} {kernels:?} fused {fused} {post:?}: off by {worst}");
                let border: f32 = (0..w + 2).map(|q| dst.data[q * cout..(q + 1) * cout].iter().map(|v| v.abs()).sum::<f32>()).sum();
                assert_eq!(border, 0.0, "top border written");
            }
        }
    }
}

#[test]
fn pixel_shuffle_moves_channel_4k_plus_2dy_plus_dx_to_the_subpixel() {
    let mut src = Map::default();
    src.reset(2, 3, 8);
    for y in 0..2 {
        for x in 0..3 {
            for c in 0..8 {
                src.pixel_mut(y, x)[c] = (100 * y + 10 * x + c) as f32;
            }
        }
    }
    let mut dst = Map::default();
    pixel_shuffle2(&src, &mut dst);
    assert_eq!((dst.height(), dst.width(), dst.channels()), (4, 6, 2));
    // pixel (3, 4) = (2·1 + 1, 2·2 + 0): input (1, 2), channels 4k + 2.
    assert_eq!(dst.pixel(3, 4), &[122.0, 126.0]);
    assert_eq!(dst.pixel(0, 1), &[1.0, 5.0]);
}

#[test]
fn wrong_sizes_and_non_finite_weights_are_refused() {
    assert!(matches!(Conv3::from_oihw(2, 2, &[0.0; 35], None), Err(LayerError::Size { want: 36, got_w: 35, .. })));
    assert!(matches!(Conv3::from_oihw(1, 1, &[0.0; 9], Some(&[0.0, 1.0])), Err(LayerError::Size { got_b: 2, .. })));
    let mut w = [0.0; 9];
    w[4] = f32::NAN;
    assert_eq!(Conv3::from_oihw(1, 1, &w, None).unwrap_err(), LayerError::NonFinite { cout: 1, cin: 1 });
}

/// A layer as loaded (not made [`Conv3::with_fused`]) gives the portable kernel's bits on every kernel
/// (AVX-512, AVX2, the one-channel dot kernels), so natively a tile is the page's bits (its
/// SIMD128 kernel multiplies, then adds, in the portable kernel's order); a fused layer gives
/// the same bits on AVX-512 as on AVX2 + FMA (where both vectorise it), and differs from the
/// portable kernel somewhere.
/// 1 to 112 output channels, widths that end inside a block of 8 pixels (or of 6, 7 or 16:
/// the AVX-512 kernels' other blocks), ReLU and a skip.
/// (Where the CPU has no AVX-512 the best kernels are the AVX2 ones; the test says which ran.)
#[test]
fn unfused_layers_give_the_portable_bits_on_every_kernel_and_fused_ones_the_same_bits_on_avx512_and_avx2() {
    let mut seed = 11;
    eprintln!("widest kernels here: {}", Kernels::Best.widest());
    let mut fused_differs = 0;
    for (cout, cin, h, w) in [
        (32, 4, 9, 13),
        (32, 32, 6, 8),
        (8, 5, 7, 6),
        (24, 7, 9, 10),
        (24, 36, 4, 37),
        (48, 24, 5, 17),
        (64, 16, 3, 34),
        (112, 96, 3, 12),
        (80, 8, 3, 20),
        (96, 8, 2, 13),
        (16, 13, 6, 6),
        (1, 8, 6, 11),
        (1, 16, 5, 9),
        (3, 5, 4, 7),
    ] {
        let wt: Vec<f32> = (0..cout * cin * 9).map(|_| lcg(&mut seed)).collect();
        let b: Vec<f32> = (0..cout).map(|_| lcg(&mut seed)).collect();
        let x: Vec<f32> = (0..cin * h * w).map(|_| lcg(&mut seed)).collect();
        let skip_v: Vec<f32> = (0..cout * h * w).map(|_| lcg(&mut seed)).collect();
        let (src, skip) = (map_from_nchw(&x, cin, h, w), map_from_nchw(&skip_v, cout, h, w));
        for fused in [false, true] {
            let layer = Conv3::from_oihw(cout, cin, &wt, Some(&b)).unwrap().with_fused(fused);
            for post in [Post::None, Post::Relu, Post::Add(&skip)] {
                let [best, avx2, portable] = [Kernels::Best, Kernels::Avx2, Kernels::Portable].map(|k| {
                    let mut m = Map::default();
                    conv_impl(&layer, &src, &mut m, post, 2, k);
                    m
                });
                let differ = |a: &Map, c: &Map| a.data.iter().zip(&c.data).filter(|(p, q)| p.to_bits() != q.to_bits()).count();
                // A fused layer of 3 channels runs fused on AVX-512 only (AVX2 takes multiples of 8).
                if !fused || cout == 1 || cout % 8 == 0 {
                    assert_eq!(differ(&best, &avx2), 0, "{cout}x{cin} {h}x{w} fused {fused} {post:?}: best vs AVX2");
                }
                if fused {
                    fused_differs += differ(&best, &portable);
                } else {
                    assert_eq!(differ(&best, &portable), 0, "{cout}x{cin} {h}x{w} {post:?}: best vs portable");
                }
            }
        }
    }
    #[cfg(target_arch = "x86_64")]
    if Kernels::Best.widest() != "portable" {
        assert!(fused_differs > 0, "fused multiply-adds never rounded differently: the fused kernels did not run");
    }
    let _ = fused_differs;
}

/// The vectorised kernel for one output channel from 16 or 24 input channels gives the
/// portable kernel's bits (the same products and sums in the same order), for widths that end
/// inside a block of 8 pixels, with ReLU and a skip: the sketch generator's output does not
/// depend on which of the two ran.
#[test]
fn one_output_channel_from_16_or_24_gives_the_portable_kernels_bits() {
    let mut seed = 13;
    for (cin, h, w) in [(16, 7, 9), (24, 5, 17), (16, 3, 8)] {
        let wt: Vec<f32> = (0..cin * 9).map(|_| lcg(&mut seed)).collect();
        let x: Vec<f32> = (0..cin * h * w).map(|_| lcg(&mut seed)).collect();
        let skip_v: Vec<f32> = (0..h * w).map(|_| lcg(&mut seed)).collect();
        let layer = Conv3::from_oihw(1, cin, &wt, Some(&[0.3])).unwrap();
        let (src, skip) = (map_from_nchw(&x, cin, h, w), map_from_nchw(&skip_v, 1, h, w));
        for post in [Post::None, Post::Relu, Post::Add(&skip)] {
            let (mut a, mut c) = (Map::default(), Map::default());
            conv_impl(&layer, &src, &mut a, post, 2, Kernels::Best);
            conv_impl(&layer, &src, &mut c, post, 2, Kernels::Portable);
            let differ = a.data.iter().zip(&c.data).filter(|(p, q)| p.to_bits() != q.to_bits()).count();
            assert_eq!(differ, 0, "1x{cin} {h}x{w} {post:?}: {differ} values differ");
        }
    }
}

/// A map reshaped to a new size keeps a zero border (the convolutions' padding) however dirty
/// its buffer was.
#[test]
fn a_reshaped_map_has_a_zero_border_whatever_its_buffer_held() {
    let mut m = Map::default();
    m.reset(6, 7, 3);
    m.data.fill(9.0);
    for (h, w, c) in [(4, 5, 3), (6, 7, 3), (5, 9, 2), (8, 8, 4)] {
        m.reset(h, w, c);
        for y in 0..h + 2 {
            for x in 0..w + 2 {
                if y == 0 || x == 0 || y == h + 1 || x == w + 1 {
                    let i = (y * (w + 2) + x) * c;
                    assert!(m.data[i..i + c].iter().all(|&v| v == 0.0), "{h}x{w}x{c}: border pixel ({y}, {x})");
                }
            }
        }
        assert!(m.data[(h + 2) * (w + 2) * c..].iter().all(|&v| v == 0.0), "{h}x{w}x{c}: slack");
        m.data[(w + 2) * c..(h + 1) * (w + 2) * c].fill(9.0);
    }
}
