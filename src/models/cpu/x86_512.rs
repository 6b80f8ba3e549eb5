use super::{Conv3, Map, Post};
use std::arch::x86_64::*;

/// Output pixels per block at most: 8 pixels × 3 vectors of 16 channels are 24 of AVX-512's 32
/// vector registers, beside 3 weight vectors and the broadcast input (blocks of 4 vectors take
/// 6 pixels; the AVX2 kernels have 16 registers, so 3 or 4 pixels). Its reads past a row's end
/// stay in a map's slack.
pub(super) const PX: usize = 8;

/// The lanes of a vector of 16 channels from `c` that are channels below `cout`.
fn lanes(c: usize, cout: usize) -> __mmask16 {
    let n = cout.saturating_sub(c).min(16);
    ((1u32 << n) - 1) as __mmask16
}

/// Any number of output channels with AVX-512: blocks of 6 to [`PX`] pixels ([`block_px`]) × 1
/// to 4 vectors of 16 channels ([`block_vectors`]), the last vector masked to the channels
/// there are; a layer of 24 output channels on [`rows_pixels`] instead. Each output is the bias
/// plus the taps and input channels in the same order as every other kernel; with `F` (a
/// [`Conv3::with_fused`] layer) each step is one fused multiply-add, as in the AVX2 kernels, else a
/// multiply, then an add, as in the portable and the page's kernels: either way the AVX2
/// kernels' bits.
///
/// # Safety
/// The CPU must support AVX-512F.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn rows<const F: bool>(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, n: usize, w: usize, post: Post) {
    if layer.cout == PIXEL_CHANNELS {
        // SAFETY: AVX-512F (this function's contract) and 24 output channels.
        return unsafe { rows_pixels::<F>(layer, src, out, y0, n, w, post) };
    }
    let (cin, cout) = (layer.cin, layer.cout);
    let sw = src.w + 2;
    assert!(src.data.len() >= ((y0 + n + 1) * sw + w + 2 + PX) * cin);
    assert!(layer.w.len() == 9 * cin * cout && layer.b.len() == cout && out.len() == n * sw * cout);
    if let Post::Add(s) = post {
        assert!(s.data.len() >= ((y0 + n + 1) * sw) * cout);
    }
    // SAFETY: the caller's, and the bounds asserted above.
    unsafe {
        match block_px(w) {
            6 => rows_of::<6, F>(layer, src, out, y0, n, w, post),
            7 => rows_of::<7, F>(layer, src, out, y0, n, w, post),
            _ => rows_of::<PX, F>(layer, src, out, y0, n, w, post),
        }
    }
}

/// The pixels per block for rows `w` pixels wide: [`PX`], or 6 or 7 where blocks of 8 would
/// leave more of the last block empty (17 pixels: 3 blocks of 6 instead of 3 of 8, 29 % of
/// the work on pixels that are not there; 34: 5 of 7 instead of 5 of 8).
fn block_px(w: usize) -> usize {
    [PX, 7, 6].into_iter().min_by_key(|&p| w.div_ceil(p) * p).expect("three sizes")
}

/// Vectors of 16 channels in the next block from channel `c0` of `cout`: 3 (48 channels,
/// 24 accumulators) where 3 or more are left, 4 where that would leave one alone (64: one
/// block of 4 instead of 3 and a lone vector, whose 8 pixels need 8 broadcasts for 8 products),
/// else what is left. A block of more vectors shares each broadcast input among more products.
fn block_vectors(c0: usize, cout: usize) -> usize {
    match (cout - c0).div_ceil(16) {
        n @ 4.. if n % 3 == 1 => 4,
        3.. => 3,
        n => n,
    }
}

/// [`rows`] with blocks of `P` pixels (at most [`PX`]; blocks of 4 vectors at most 6).
///
/// # Safety
/// AVX-512F, and the bounds asserted by [`rows`].
#[target_feature(enable = "avx512f")]
unsafe fn rows_of<const P: usize, const F: bool>(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, n: usize, w: usize, post: Post) {
    let cout = layer.cout;
    for r in 0..n {
        let mut c0 = 0;
        while c0 < cout {
            let v = block_vectors(c0, cout);
            let mut x0 = 0;
            while x0 < w {
                // SAFETY: AVX-512F is present (this function's contract); unmasked lanes stay
                // inside the bounds asserted by `rows`.
                unsafe {
                    match v {
                        4 => {
                            block::<4, 6, F>(layer, src, out, y0, r, x0, c0, w, post);
                            x0 += 6;
                        }
                        3 => {
                            block::<3, P, F>(layer, src, out, y0, r, x0, c0, w, post);
                            x0 += P;
                        }
                        2 => {
                            block::<2, P, F>(layer, src, out, y0, r, x0, c0, w, post);
                            x0 += P;
                        }
                        _ => {
                            block::<1, P, F>(layer, src, out, y0, r, x0, c0, w, post);
                            x0 += P;
                        }
                    }
                }
            }
            c0 += 16 * v;
        }
    }
}

/// One block of [`rows`]: `P` pixels from `x0` × `V` vectors of 16 channels from `c0`,
/// output row `r` (image row `y0 + r`).
///
/// # Safety
/// AVX-512F, and the bounds asserted by [`rows`].
#[target_feature(enable = "avx512f")]
#[allow(clippy::too_many_arguments)]
#[inline]
unsafe fn block<const V: usize, const P: usize, const F: bool>(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, r: usize, x0: usize, c0: usize, w: usize, post: Post) {
    let (cin, cout) = (layer.cin, layer.cout);
    let sw = src.w + 2;
    let y = y0 + r;
    let masks: [__mmask16; V] = std::array::from_fn(|v| lanes(c0 + 16 * v, cout));
    // SAFETY (pointer arithmetic below): masked-off lanes are neither read nor written; the
    // others are inside the data, by the caller's asserts.
    unsafe {
        let bias: [__m512; V] = std::array::from_fn(|v| _mm512_maskz_loadu_ps(masks[v], layer.b.as_ptr().add(c0 + 16 * v)));
        let mut acc = [bias; P];
        let (sp, wp) = (src.data.as_ptr(), layer.w.as_ptr());
        for tap in 0..9 {
            let (ky, kx) = (tap / 3, tap % 3);
            let base = ((y + ky) * sw + x0 + kx) * cin;
            let wbase = tap * cin * cout + c0;
            for ci in 0..cin {
                let wv: [__m512; V] = std::array::from_fn(|v| _mm512_maskz_loadu_ps(masks[v], wp.add(wbase + ci * cout + 16 * v)));
                for (p, a) in acc.iter_mut().enumerate() {
                    let x = _mm512_set1_ps(*sp.add(base + p * cin + ci));
                    for v in 0..V {
                        a[v] = if F { _mm512_fmadd_ps(x, wv[v], a[v]) } else { _mm512_add_ps(a[v], _mm512_mul_ps(x, wv[v])) };
                    }
                }
            }
        }
        let zero = _mm512_setzero_ps();
        for (p, a) in acc.iter().enumerate().take(P.min(w - x0)) {
            let o = r * sw * cout + (x0 + p + 1) * cout + c0;
            for v in 0..V {
                let val = match post {
                    Post::None => a[v],
                    Post::Relu => _mm512_max_ps(a[v], zero),
                    Post::Add(s) => _mm512_add_ps(a[v], _mm512_maskz_loadu_ps(masks[v], s.data.as_ptr().add(s.at(y, x0 + p) + c0 + 16 * v))),
                };
                _mm512_mask_storeu_ps(out.as_mut_ptr().add(o + 16 * v), masks[v], val);
            }
        }
    }
}

/// Output channels of [`rows_pixels`]: 24 (the sketch generator's second scale). With 12 or
/// 16 channels it was slower than the channel-vector blocks of [`rows`] on Zen 4 (the sketch
/// generator's full-size layers: 8.3 → 9.0 ms and 2.6 → 3.8 ms).
const PIXEL_CHANNELS: usize = 24;

/// Pixels of a row per vector of [`rows_pixels`].
const PIXEL_LANES: usize = 16;

/// A layer of 24 output channels with AVX-512, its vectors along the pixels instead of the
/// channels: each of 24 accumulators holds one output channel of 16 pixels of a row, so every
/// lane works (the channel-vector kernel [`rows`] masks a quarter of its lanes for 24
/// channels), and each product is a vector of 16 input pixels times one weight. The input
/// rows are copied channel-first as they are reached. Each output is the bias plus the taps
/// and input channels in the same order as every other kernel (with `F` fused multiply-adds,
/// else a multiply, then an add): the same bits as [`rows`]. The sketch generator's
/// 24-channel layers: 18.4 → 12.0 ms on 1 thread (Zen 4).
///
/// # Safety
/// The CPU must support AVX-512F; the layer has [`PIXEL_CHANNELS`] outputs.
#[target_feature(enable = "avx512f")]
unsafe fn rows_pixels<const F: bool>(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, n: usize, w: usize, post: Post) {
    const C: usize = PIXEL_CHANNELS;
    const L: usize = PIXEL_LANES;
    let cin = layer.cin;
    let sw = src.w + 2;
    assert!(layer.cout == C && layer.w.len() == 9 * cin * C && layer.b.len() == C && out.len() == n * sw * C);
    assert!(src.data.len() >= (y0 + n + 2) * sw * cin);
    // The three padded input rows an output row reads, channel-first, in a ring of three
    // slots: padded row k (from y0) is slot k mod 3, t[(slot · cin + ci) · tw + x], with zero
    // pixels after each row so a vector read from any pixel of a row stays in it. One new row
    // is copied per output row, so the rows read stay in the cache (a copy of all the rows
    // first was read back from memory: 24 % slower).
    let tw = sw + L;
    let mut t = vec![0f32; 3 * cin * tw];
    let copy_row = |t: &mut [f32], k: usize| {
        let s = &src.data[(y0 + k) * sw * cin..][..sw * cin];
        for ci in 0..cin {
            for (x, v) in t[((k % 3) * cin + ci) * tw..][..sw].iter_mut().enumerate() {
                *v = s[x * cin + ci];
            }
        }
    };
    copy_row(&mut t, 0);
    copy_row(&mut t, 1);
    let mut lanes_out = [[0f32; L]; C];
    for r in 0..n {
        copy_row(&mut t, r + 2);
        let y = y0 + r;
        let mut x0 = 0;
        while x0 < w {
            // SAFETY: every read below is inside `t` (x0 + 2 + L ≤ tw) or the layer's
            // weights; AVX-512F is present (this function's contract).
            unsafe {
                let mut acc: [__m512; C] = std::array::from_fn(|o| _mm512_set1_ps(layer.b[o]));
                let (tp, wp) = (t.as_ptr(), layer.w.as_ptr());
                for tap in 0..9 {
                    let (ky, kx) = (tap / 3, tap % 3);
                    for ci in 0..cin {
                        let xv = _mm512_loadu_ps(tp.add((((r + ky) % 3) * cin + ci) * tw + x0 + kx));
                        let wr = wp.add((tap * cin + ci) * C);
                        for (o, a) in acc.iter_mut().enumerate() {
                            let wv = _mm512_set1_ps(*wr.add(o));
                            *a = if F { _mm512_fmadd_ps(xv, wv, *a) } else { _mm512_add_ps(*a, _mm512_mul_ps(xv, wv)) };
                        }
                    }
                }
                let zero = _mm512_setzero_ps();
                for (o, a) in acc.iter().enumerate() {
                    let v = if matches!(post, Post::Relu) { _mm512_max_ps(*a, zero) } else { *a };
                    _mm512_storeu_ps(lanes_out[o].as_mut_ptr(), v);
                }
            }
            for p in 0..L.min(w - x0) {
                let o = r * sw * C + (x0 + p + 1) * C;
                let dst = &mut out[o..o + C];
                match post {
                    Post::Add(s) => {
                        let skip = s.pixel(y, x0 + p);
                        for c in 0..C {
                            dst[c] = lanes_out[c][p] + skip[c];
                        }
                    }
                    _ => {
                        for c in 0..C {
                            dst[c] = lanes_out[c][p];
                        }
                    }
                }
            }
            x0 += L;
        }
    }
}
