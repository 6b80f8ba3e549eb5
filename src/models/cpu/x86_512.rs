use super::{Conv3, Map, Post};
use std::arch::x86_64::*;

/// Output pixels per block: 8 pixels × 2 vectors of 16 channels are 16 of AVX-512's 32 vector
/// registers, beside 2 weight vectors and the broadcast input (the AVX2 kernels have 16
/// registers, so 3 or 4 pixels). Its reads past a row's end stay in a map's slack.
pub(super) const PX: usize = 8;

/// The lanes of a vector of 16 channels from `c` that are channels below `cout`.
fn lanes(c: usize, cout: usize) -> __mmask16 {
    let n = cout.saturating_sub(c).min(16);
    ((1u32 << n) - 1) as __mmask16
}

/// Any number of output channels with AVX-512: blocks of [`PX`] pixels × 32 channels (16 where
/// fewer are left), the last vector masked to the channels there are. Each output is the bias
/// plus the taps and input channels in the same order as every other kernel; with `F` (a
/// [`Conv3::with_fused`] layer) each step is one fused multiply-add, as in the AVX2 kernels, else a
/// multiply, then an add, as in the portable and the page's kernels: either way the AVX2
/// kernels' bits.
///
/// # Safety
/// The CPU must support AVX-512F.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn rows<const F: bool>(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, n: usize, w: usize, post: Post) {
    let (cin, cout) = (layer.cin, layer.cout);
    let sw = src.w + 2;
    assert!(src.data.len() >= ((y0 + n + 1) * sw + w + 2 + PX) * cin);
    assert!(layer.w.len() == 9 * cin * cout && layer.b.len() == cout && out.len() == n * sw * cout);
    if let Post::Add(s) = post {
        assert!(s.data.len() >= ((y0 + n + 1) * sw) * cout);
    }
    for r in 0..n {
        let mut x0 = 0;
        while x0 < w {
            let mut c0 = 0;
            while c0 < cout {
                // SAFETY: AVX-512F is present (this function's contract); unmasked lanes stay
                // inside the bounds asserted above.
                if cout - c0 > 16 {
                    unsafe { block::<2, F>(layer, src, out, y0, r, x0, c0, w, post) };
                    c0 += 32;
                } else {
                    unsafe { block::<1, F>(layer, src, out, y0, r, x0, c0, w, post) };
                    c0 += 16;
                }
            }
            x0 += PX;
        }
    }
}

/// One block of [`rows`]: [`PX`] pixels from `x0` × `V` vectors of 16 channels from `c0`,
/// output row `r` (image row `y0 + r`).
///
/// # Safety
/// AVX-512F, and the bounds asserted by [`rows`].
#[target_feature(enable = "avx512f")]
#[allow(clippy::too_many_arguments)]
#[inline]
unsafe fn block<const V: usize, const F: bool>(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, r: usize, x0: usize, c0: usize, w: usize, post: Post) {
    let (cin, cout) = (layer.cin, layer.cout);
    let sw = src.w + 2;
    let y = y0 + r;
    let masks: [__mmask16; V] = std::array::from_fn(|v| lanes(c0 + 16 * v, cout));
    // SAFETY (pointer arithmetic below): masked-off lanes are neither read nor written; the
    // others are inside the data, by the caller's asserts.
    unsafe {
        let bias: [__m512; V] = std::array::from_fn(|v| _mm512_maskz_loadu_ps(masks[v], layer.b.as_ptr().add(c0 + 16 * v)));
        let mut acc = [bias; PX];
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
        for (p, a) in acc.iter().enumerate().take(PX.min(w - x0)) {
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
