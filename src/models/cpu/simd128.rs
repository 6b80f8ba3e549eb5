use super::{Conv3, Map, Post};
use core::arch::wasm32::*;

/// Pixels per block: the portable kernel's blocking.
pub(super) const PX: usize = super::ROWS8_PX;
/// Output channels per pass (two vectors).
pub(super) const CH: usize = super::ROWS8_CH;

/// Output rows `y0..y0 + n` of `layer` on `src` into `out` (see `conv_rows`).
pub(super) fn rows(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, n: usize, w: usize, post: Post) {
    let (cin, cout) = (layer.cin, layer.cout);
    let sw = src.w + 2;
    let row_len = sw * cout;
    // A block reads PX pixels from (y + ky, x + kx) for x < w: at most
    // (y0 + n + 1)·sw + w + 1 + PX pixels, inside the map thanks to its slack.
    assert!(src.data.len() >= ((y0 + n + 1) * sw + w + 2 + PX) * cin);
    assert!(cout % CH == 0 && layer.w.len() == 9 * cin * cout && layer.b.len() == cout && out.len() == n * row_len);
    let (sp, wp) = (src.data.as_ptr(), layer.w.as_ptr());
    let zero = f32x4_splat(0.0);
    for r in 0..n {
        let y = y0 + r;
        let mut x0 = 0;
        while x0 < w {
            for c0 in (0..cout).step_by(CH) {
                // SAFETY: c0 + 8 ≤ cout = layer.b.len().
                let bias = unsafe { [v128_load(layer.b.as_ptr().add(c0) as *const v128), v128_load(layer.b.as_ptr().add(c0 + 4) as *const v128)] };
                let mut acc = [bias; PX];
                for tap in 0..9 {
                    let (ky, kx) = (tap / 3, tap % 3);
                    let base = ((y + ky) * sw + x0 + kx) * cin;
                    let wbase = tap * cin * cout + c0;
                    for ci in 0..cin {
                        // SAFETY: weights: wbase + ci·cout + 8 ≤ 9·cin·cout; inputs: below
                        // the bound asserted above.
                        unsafe {
                            let w0 = v128_load(wp.add(wbase + ci * cout) as *const v128);
                            let w1 = v128_load(wp.add(wbase + ci * cout + 4) as *const v128);
                            for (p, a) in acc.iter_mut().enumerate() {
                                let v = f32x4_splat(*sp.add(base + p * cin + ci));
                                a[0] = f32x4_add(a[0], f32x4_mul(v, w0));
                                a[1] = f32x4_add(a[1], f32x4_mul(v, w1));
                            }
                        }
                    }
                }
                for (p, a) in acc.iter().enumerate().take(PX.min(w - x0)) {
                    let o = r * row_len + (x0 + p + 1) * cout + c0;
                    let [mut v0, mut v1] = *a;
                    match post {
                        Post::None => {}
                        Post::Relu => (v0, v1) = (f32x4_max(v0, zero), f32x4_max(v1, zero)),
                        Post::Add(s) => {
                            let si = s.at(y, x0 + p) + c0;
                            let sk = &s.data[si..si + CH];
                            // SAFETY: sk holds 8 values.
                            unsafe {
                                v0 = f32x4_add(v0, v128_load(sk.as_ptr() as *const v128));
                                v1 = f32x4_add(v1, v128_load(sk.as_ptr().add(4) as *const v128));
                            }
                        }
                    }
                    let dst = &mut out[o..o + CH];
                    // SAFETY: dst holds 8 values.
                    unsafe {
                        v128_store(dst.as_mut_ptr() as *mut v128, v0);
                        v128_store(dst.as_mut_ptr().add(4) as *mut v128, v1);
                    }
                }
            }
            x0 += PX;
        }
    }
}
