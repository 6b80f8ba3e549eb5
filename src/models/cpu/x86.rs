use super::{BLOCK, Conv3, LANES, Map, Post, ROWS8_PX, dot_output};
use std::arch::x86_64::*;

/// `a + x·w` on 8 lanes: one fused multiply-add where `$fused` (one rounding), else a multiply,
/// then an add, rounded as the portable and the page's kernels round them.
macro_rules! madd {
    ($fused:expr, $a:expr, $x:expr, $w:expr) => {
        if $fused { _mm256_fmadd_ps($x, $w, $a) } else { _mm256_add_ps($a, _mm256_mul_ps($x, $w)) }
    };
}

/// Any multiple of 8 output channels with AVX2 + FMA (with `F` fused multiply-adds, else a
/// multiply, then an add, the portable kernel's bits): blocks of 4 pixels × 16 channels
/// (8 accumulator registers; the last 8 channels of an odd multiple take a 4 × 8 block).
/// The compiler left the portable loop scalar (2 GMAC/s against 43 for `rows32`).
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn rows8<const F: bool>(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, n: usize, w: usize, post: Post) {
    let (cin, cout) = (layer.cin, layer.cout);
    let sw = src.w + 2;
    assert!(src.data.len() >= ((y0 + n + 1) * sw + w + 2 + ROWS8_PX) * cin);
    assert!(cout % 8 == 0 && layer.w.len() == 9 * cin * cout && layer.b.len() == cout && out.len() == n * sw * cout);
    for r in 0..n {
        let mut x0 = 0;
        while x0 < w {
            let mut c0 = 0;
            while c0 < cout {
                // SAFETY: the CPU has AVX2 and FMA (this function's contract); reads and
                // writes are inside the bounds asserted above.
                if c0 + 16 <= cout {
                    unsafe { block::<2, F>(layer, src, out, y0, r, x0, c0, w, post) };
                    c0 += 16;
                } else {
                    unsafe { block::<1, F>(layer, src, out, y0, r, x0, c0, w, post) };
                    c0 += 8;
                }
            }
            x0 += ROWS8_PX;
        }
    }
}

/// One block of [`rows8`]: `ROWS8_PX` pixels from `x0` × `V` vectors of 8 channels from
/// `c0`, output row `r` (image row `y0 + r`).
///
/// # Safety
/// AVX2 + FMA, and the bounds asserted by [`rows8`].
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
#[inline]
unsafe fn block<const V: usize, const F: bool>(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, r: usize, x0: usize, c0: usize, w: usize, post: Post) {
    let (cin, cout) = (layer.cin, layer.cout);
    let sw = src.w + 2;
    let y = y0 + r;
    // SAFETY (pointer arithmetic below): inside the data, by the caller's asserts.
    unsafe {
        let bias: [__m256; V] = std::array::from_fn(|v| _mm256_loadu_ps(layer.b.as_ptr().add(c0 + 8 * v)));
        let mut acc = [bias; ROWS8_PX];
        let (sp, wp) = (src.data.as_ptr(), layer.w.as_ptr());
        for tap in 0..9 {
            let (ky, kx) = (tap / 3, tap % 3);
            let base = ((y + ky) * sw + x0 + kx) * cin;
            let wbase = tap * cin * cout + c0;
            for ci in 0..cin {
                let wv: [__m256; V] = std::array::from_fn(|v| _mm256_loadu_ps(wp.add(wbase + ci * cout + 8 * v)));
                for (p, a) in acc.iter_mut().enumerate() {
                    let x = _mm256_broadcast_ss(&*sp.add(base + p * cin + ci));
                    for v in 0..V {
                        a[v] = madd!(F, a[v], x, wv[v]);
                    }
                }
            }
        }
        let zero = _mm256_setzero_ps();
        for (p, a) in acc.iter().enumerate().take(ROWS8_PX.min(w - x0)) {
            let o = r * sw * cout + (x0 + p + 1) * cout + c0;
            for v in 0..V {
                let val = match post {
                    Post::None => a[v],
                    Post::Relu => _mm256_max_ps(a[v], zero),
                    Post::Add(s) => _mm256_add_ps(a[v], _mm256_loadu_ps(s.data.as_ptr().add(s.at(y, x0 + p) + c0 + 8 * v))),
                };
                _mm256_storeu_ps(out.as_mut_ptr().add(o + 8 * v), val);
            }
        }
    }
}

/// See the module.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn rows32<const F: bool>(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, n: usize, w: usize, post: Post) {
    const _: () = assert!(BLOCK == 3 && LANES == 32);
    let cin = layer.cin;
    let sw = src.w + 2;
    let row_len = sw * LANES;
    assert!(src.data.len() >= ((y0 + n + 1) * sw + w + 2 + BLOCK) * cin);
    assert!(layer.w.len() == 9 * cin * LANES && layer.b.len() == LANES && out.len() == n * row_len);
    let zero = _mm256_setzero_ps();
    // SAFETY (all pointer reads below): inside src.data and layer.w by the asserts above.
    unsafe {
        let bias = [0, 8, 16, 24].map(|o| _mm256_loadu_ps(layer.b.as_ptr().add(o)));
        for r in 0..n {
            let y = y0 + r;
            let mut x0 = 0;
            while x0 < w {
                let [mut a00, mut a01, mut a02, mut a03] = bias;
                let [mut a10, mut a11, mut a12, mut a13] = bias;
                let [mut a20, mut a21, mut a22, mut a23] = bias;
                for tap in 0..9 {
                    let (ky, kx) = (tap / 3, tap % 3);
                    // Slices and iterators: one bounds check per tap, none per channel
                    // (the tests' build keeps debug assertions, which check every
                    // pointer offset).
                    let base = ((y + ky) * sw + x0 + kx) * cin;
                    let (p0, rest) = src.data[base..base + 3 * cin].split_at(cin);
                    let (p1, p2) = rest.split_at(cin);
                    let (wrows, _) = layer.w[tap * cin * LANES..(tap + 1) * cin * LANES].as_chunks::<LANES>();
                    for (((wr, x0v), x1v), x2v) in wrows.iter().zip(p0).zip(p1).zip(p2) {
                        let v0 = _mm256_set1_ps(*x0v);
                        let v1 = _mm256_set1_ps(*x1v);
                        let v2 = _mm256_set1_ps(*x2v);
                        let (w0, w1, w2, w3) = (wr[..8].as_ptr(), wr[8..16].as_ptr(), wr[16..24].as_ptr(), wr[24..].as_ptr());
                        let wv = _mm256_loadu_ps(w0);
                        a00 = madd!(F, a00, v0, wv);
                        a10 = madd!(F, a10, v1, wv);
                        a20 = madd!(F, a20, v2, wv);
                        let wv = _mm256_loadu_ps(w1);
                        a01 = madd!(F, a01, v0, wv);
                        a11 = madd!(F, a11, v1, wv);
                        a21 = madd!(F, a21, v2, wv);
                        let wv = _mm256_loadu_ps(w2);
                        a02 = madd!(F, a02, v0, wv);
                        a12 = madd!(F, a12, v1, wv);
                        a22 = madd!(F, a22, v2, wv);
                        let wv = _mm256_loadu_ps(w3);
                        a03 = madd!(F, a03, v0, wv);
                        a13 = madd!(F, a13, v1, wv);
                        a23 = madd!(F, a23, v2, wv);
                    }
                }
                let acc = [[a00, a01, a02, a03], [a10, a11, a12, a13], [a20, a21, a22, a23]];
                for (p, a) in acc.iter().enumerate().take(BLOCK.min(w - x0)) {
                    let o = r * row_len + (x0 + p + 1) * LANES;
                    let dst = &mut out[o..o + LANES];
                    for (j, v) in a.iter().enumerate() {
                        let v = match post {
                            Post::None => *v,
                            Post::Relu => _mm256_max_ps(*v, zero),
                            Post::Add(s) => _mm256_add_ps(*v, _mm256_loadu_ps(s.pixel(y, x0 + p)[8 * j..].as_ptr())),
                        };
                        _mm256_storeu_ps(dst[8 * j..].as_mut_ptr(), v);
                    }
                }
                x0 += BLOCK;
            }
        }
    }
}

/// One output channel from 8 input channels: one 8-wide product per tap, four pixels
/// at a time (four independent chains), then the 8 lanes added up; with `F` fused
/// multiply-adds, else the portable [`super::rows_dot`]'s bits.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn rows_dot8<const F: bool>(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, n: usize, w: usize, post: Post) {
    let sw = src.w + 2;
    assert!(layer.cin == 8 && layer.cout == 1 && layer.w.len() == 72);
    assert!(src.data.len() >= ((y0 + n + 1) * sw + w + 2 + 4) * 8 && out.len() == n * sw);
    // SAFETY: AVX2 and FMA are present (the caller's contract); loads and stores stay
    // inside checked slices.
    unsafe {
        let (taps, _) = layer.w.as_chunks::<8>();
        let taps: [__m256; 9] = std::array::from_fn(|t| _mm256_loadu_ps(taps[t].as_ptr()));
        for r in 0..n {
            let y = y0 + r;
            let mut x0 = 0;
            while x0 < w {
                let mut acc = [_mm256_setzero_ps(); 4];
                for (tap, wv) in taps.iter().enumerate() {
                    let (ky, kx) = (tap / 3, tap % 3);
                    let base = ((y + ky) * sw + x0 + kx) * 8;
                    let px = &src.data[base..base + 32];
                    for (p, a) in acc.iter_mut().enumerate() {
                        *a = madd!(F, *a, _mm256_loadu_ps(px[8 * p..].as_ptr()), *wv);
                    }
                }
                for (p, a) in acc.iter().enumerate().take(4.min(w - x0)) {
                    let mut l = [0f32; 8];
                    _mm256_storeu_ps(l.as_mut_ptr(), *a);
                    out[r * sw + x0 + p + 1] = dot_output(layer.b[0], &l, post, y, x0 + p);
                }
                x0 += 4;
            }
        }
    }
}

/// Pixels [`rows_dot`] sums side by side (independent chains of adds).
const DOT_PX: usize = 8;

/// One output channel from a multiple of 8 input channels with AVX (the sketch generator's
/// 16 → 1 tail): the portable kernel's sums exactly — per pixel 8 partial sums (input channel
/// mod 8) of products, each a multiply then an add, over the taps and blocks of 8 channels,
/// then added up in its order — with the 8 partial sums in one vector and [`DOT_PX`] pixels
/// side by side, so both give the same bits. The portable loop stayed scalar (2.7 GMAC/s: 3.5
/// of the generator's ~42 ms at 256²).
///
/// # Safety
/// The CPU must support AVX2 and FMA (the dispatch's test; only AVX is used).
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn rows_dot(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, n: usize, w: usize, post: Post) {
    let cin = layer.cin;
    let sw = src.w + 2;
    assert!(cin.is_multiple_of(8) && layer.cout == 1 && layer.w.len() == 9 * cin);
    assert!(src.data.len() >= ((y0 + n + 1) * sw + w + 2 + DOT_PX) * cin && out.len() == n * sw);
    let blocks = cin / 8;
    // SAFETY: AVX is present (the caller's contract); loads stay inside the bound asserted
    // above (pixels past a row's end read the next row or the slack, and are not stored).
    unsafe {
        let (sp, wp) = (src.data.as_ptr(), layer.w.as_ptr());
        for r in 0..n {
            let y = y0 + r;
            let mut x0 = 0;
            while x0 < w {
                let mut acc = [_mm256_setzero_ps(); DOT_PX];
                for tap in 0..9 {
                    let (ky, kx) = (tap / 3, tap % 3);
                    let base = ((y + ky) * sw + x0 + kx) * cin;
                    for b in 0..blocks {
                        let wv = _mm256_loadu_ps(wp.add((tap * cin) + 8 * b));
                        for (p, a) in acc.iter_mut().enumerate() {
                            let x = _mm256_loadu_ps(sp.add(base + p * cin + 8 * b));
                            *a = _mm256_add_ps(*a, _mm256_mul_ps(x, wv));
                        }
                    }
                }
                for (p, a) in acc.iter().enumerate().take(DOT_PX.min(w - x0)) {
                    let mut l = [0f32; 8];
                    _mm256_storeu_ps(l.as_mut_ptr(), *a);
                    out[r * sw + x0 + p + 1] = dot_output(layer.b[0], &l, post, y, x0 + p);
                }
                x0 += DOT_PX;
            }
        }
    }
}
