//! CPU inference without a tensor framework: 3×3 convolutions with "same" zero padding on
//! channel-last activation maps, the kind of layer every model of the project is made of.
//!
//! Why not burn's CPU backend: for the TEM it was ~9× slower than ONNX Runtime (im2col into a
//! fresh buffer per layer, one operation at a time). Here each layer is one pass of a
//! register-blocked kernel: a few output pixels × output channels are accumulated in
//! registers over the 9 taps × input channels, with bias, ReLU or a skip connection applied
//! as the block is stored; activation buffers are reused between calls. Kernels: AVX2 + FMA
//! intrinsics natively (chosen at run time; [`BLOCK`] pixels × 32 channels), SIMD128
//! intrinsics in the page (4 pixels × 8 channels, any multiple of 8 channels), and portable
//! Rust elsewhere. Every kernel accumulates in the same order; the fused multiply-adds of the
//! AVX2 kernel round differently from the separate multiplies and adds of the others, so
//! native and page results differ in the last bits (0.24 mm on the TEM probe).

/// Output pixels one kernel call accumulates at once (per row).
pub const BLOCK: usize = 3;
/// Pixels after a map's last row that the kernels may read (and ignore).
const SLACK_PX: usize = 8;
/// Output channels of the x86 32-channel kernel (other multiples of 8 take the 8-channel one).
#[cfg(target_arch = "x86_64")]
const LANES: usize = 32;

/// A uniform value in [−1, 1) from a 64-bit LCG state (random layers for tests and untrained
/// models).
pub(crate) fn unit(s: &mut u64) -> f32 {
    *s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    ((*s >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
}

/// The convolutions `layers` (name, output channels, input channels) with random weights
/// ([`Conv3::random`], a seed per layer from `seed`).
pub fn random_convs(layers: &[(String, usize, usize)], seed: u64, amplitude: f32) -> Vec<Conv3> {
    layers.iter().enumerate().map(|(k, (_, cout, cin))| Conv3::random(*cout, *cin, seed ^ ((k as u64) << 32), amplitude)).collect()
}

/// Errors building a layer from stored weights.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum LayerError {
    /// The weight or bias tensor has the wrong number of values.
    #[error("a {cout}×{cin}×3×3 convolution needs {want} weights and {cout} biases, got {got_w} and {got_b}")]
    Size {
        /// Output channels.
        cout: usize,
        /// Input channels.
        cin: usize,
        /// Weights expected.
        want: usize,
        /// Weights given.
        got_w: usize,
        /// Biases given.
        got_b: usize,
    },
    /// A weight or bias is NaN or infinite.
    #[error("a {cout}×{cin}×3×3 convolution has a non-finite weight")]
    NonFinite {
        /// Output channels.
        cout: usize,
        /// Input channels.
        cin: usize,
    },
}

/// One 3×3 convolution (stride 1, zero padding 1) with bias.
#[derive(Clone, Debug)]
pub struct Conv3 {
    cin: usize,
    cout: usize,
    /// Weights as [tap = 3·ky + kx][cin][cout].
    w: Vec<f32>,
    b: Vec<f32>,
}

impl Conv3 {
    /// Builds the layer from PyTorch/burn-ordered weights `[cout][cin][3][3]` and `cout`
    /// biases (`None`: zero).
    pub fn from_oihw(cout: usize, cin: usize, w: &[f32], b: Option<&[f32]>) -> Result<Self, LayerError> {
        let zeros = vec![0.0; cout];
        let b = b.unwrap_or(&zeros);
        if w.len() != cout * cin * 9 || b.len() != cout {
            return Err(LayerError::Size { cout, cin, want: cout * cin * 9, got_w: w.len(), got_b: b.len() });
        }
        if !w.iter().chain(b).all(|v| v.is_finite()) {
            return Err(LayerError::NonFinite { cout, cin });
        }
        let mut t = vec![0.0; w.len()];
        for o in 0..cout {
            for i in 0..cin {
                for tap in 0..9 {
                    t[(tap * cin + i) * cout + o] = w[(o * cin + i) * 9 + tap];
                }
            }
        }
        Ok(Self { cin, cout, w: t, b: b.to_vec() })
    }

    /// The weights back in `[cout][cin][3][3]` order, and the biases.
    pub fn to_oihw(&self) -> (Vec<f32>, Vec<f32>) {
        let (cin, cout) = (self.cin, self.cout);
        let mut w = vec![0.0; self.w.len()];
        for o in 0..cout {
            for i in 0..cin {
                for tap in 0..9 {
                    w[(o * cin + i) * 9 + tap] = self.w[(tap * cin + i) * cout + o];
                }
            }
        }
        (w, self.b.clone())
    }

    /// The same layer with zero output channels appended up to a multiple of the vectorised
    /// kernels' channel block (8): a layer whose outputs are not a multiple of 8 runs on the
    /// portable kernel, about 7× slower (the sketch VAE's 6-channel output: 48 ms → 7 ms at
    /// 256²). The first `cout` channels of its output are unchanged.
    pub fn padded_for_simd(&self) -> Self {
        if self.cout == 1 {
            return self.clone();
        }
        self.widened(self.cout.next_multiple_of(ROWS8_CH), self.cin)
    }

    /// The same layer with zero output channels appended up to `cout` and zero-weighted input
    /// channels appended up to `cin` (both at least the layer's own): a network whose widths
    /// are not multiples of 8 runs on the vectorised kernels with its channels widened, and
    /// the first channels of every output are unchanged.
    pub fn widened(&self, cout: usize, cin: usize) -> Self {
        assert!(cout >= self.cout && cin >= self.cin, "a layer is only widened");
        let (w, mut b) = self.to_oihw();
        let mut wide = vec![0.0; cout * cin * 9];
        for o in 0..self.cout {
            wide[o * cin * 9..][..self.cin * 9].copy_from_slice(&w[o * self.cin * 9..][..self.cin * 9]);
        }
        b.resize(cout, 0.0);
        Self::from_oihw(cout, cin, &wide, Some(&b)).expect("zero-padded weights are finite and sized")
    }

    /// A layer with every weight and bias uniform in ±`amplitude`, drawn from `seed` with
    /// integer arithmetic (tests: untrained networks that still compute something).
    pub fn random(cout: usize, cin: usize, seed: u64, amplitude: f32) -> Self {
        let mut k = seed;
        let w: Vec<f32> = (0..cout * cin * 9).map(|_| unit(&mut k) * amplitude).collect();
        let b: Vec<f32> = (0..cout).map(|_| unit(&mut k) * amplitude).collect();
        Self::from_oihw(cout, cin, &w, Some(&b)).expect("sizes match")
    }

    /// Input channels.
    pub fn cin(&self) -> usize {
        self.cin
    }

    /// Output channels.
    pub fn cout(&self) -> usize {
        self.cout
    }
}

/// A channel-last activation map of `h`×`w` pixels and `c` channels, stored with a one-pixel
/// zero border (the convolutions' padding) and some slack after the last row, so the blocked
/// kernel may read a few pixels past a row's end.
#[derive(Clone, Debug, Default)]
pub struct Map {
    h: usize,
    w: usize,
    c: usize,
    data: Vec<f32>,
}

impl Map {
    /// Reshapes the map to `h`×`w`×`c`, reusing its buffer: the border is zero; the interior
    /// is zero too unless the shape is unchanged (then it keeps old values, for callers
    /// that overwrite every pixel).
    pub fn reset(&mut self, h: usize, w: usize, c: usize) {
        if (h, w, c) == (self.h, self.w, self.c) && !self.data.is_empty() {
            // Every value is about to be overwritten but the border and the slack, which
            // nothing writes: no need to clear.
            self.data[(h + 1) * (w + 2) * c..].fill(0.0);
            return;
        }
        self.h = h;
        self.w = w;
        self.c = c;
        let len = ((h + 2) * (w + 2) + SLACK_PX) * c;
        self.data.clear();
        self.data.resize(len, 0.0);
    }

    /// Height (pixels).
    pub fn height(&self) -> usize {
        self.h
    }

    /// Width (pixels).
    pub fn width(&self) -> usize {
        self.w
    }

    /// Channels.
    pub fn channels(&self) -> usize {
        self.c
    }

    /// Index of channel 0 of pixel (`y`, `x`) (unpadded coordinates).
    fn at(&self, y: usize, x: usize) -> usize {
        ((y + 1) * (self.w + 2) + x + 1) * self.c
    }

    /// The `c` channels of pixel (`y`, `x`).
    pub fn pixel(&self, y: usize, x: usize) -> &[f32] {
        let i = self.at(y, x);
        &self.data[i..i + self.c]
    }

    /// Reshapes the map to `h`×`w`×`c` and fills it from a channel-first array
    /// (`src[(k·h + y)·w + x]`, the layout of burn's tensors).
    pub fn set_chw(&mut self, src: &[f32], c: usize, h: usize, w: usize) {
        assert_eq!(src.len(), c * h * w, "channel-first size");
        self.reset(h, w, c);
        for y in 0..h {
            for x in 0..w {
                for (k, v) in self.pixel_mut(y, x).iter_mut().enumerate() {
                    *v = src[(k * h + y) * w + x];
                }
            }
        }
    }

    /// The map as a channel-first array (the inverse of [`set_chw`](Self::set_chw)).
    pub fn to_chw(&self) -> Vec<f32> {
        let (h, w) = (self.h, self.w);
        let mut out = vec![0f32; self.c * h * w];
        for y in 0..h {
            for x in 0..w {
                for (k, v) in self.pixel(y, x).iter().enumerate() {
                    out[(k * h + y) * w + x] = *v;
                }
            }
        }
        out
    }

    /// The `c` channels of pixel (`y`, `x`), writable.
    pub fn pixel_mut(&mut self, y: usize, x: usize) -> &mut [f32] {
        let i = self.at(y, x);
        let c = self.c;
        &mut self.data[i..i + c]
    }
}

/// What happens to a convolution's output before it is stored.
#[derive(Clone, Copy, Debug)]
pub enum Post<'a> {
    /// Stored as is.
    None,
    /// max(0, ·).
    Relu,
    /// Plus the same pixel of another map of the same shape (a skip connection).
    Add(&'a Map),
}

/// Applies `layer` to `src` into `dst` (reshaped to `src`'s size and the layer's output
/// channels) using up to `threads` threads (rows are split between them; 1 = this thread).
pub fn conv(layer: &Conv3, src: &Map, dst: &mut Map, post: Post, threads: usize) {
    conv_impl(layer, src, dst, post, threads, false)
}

/// [`conv`], optionally on the portable kernels even where AVX2 + FMA exist (tests run both).
fn conv_impl(layer: &Conv3, src: &Map, dst: &mut Map, post: Post, threads: usize, portable: bool) {
    assert_eq!(src.c, layer.cin, "input channels");
    if let Post::Add(s) = post {
        assert!(s.h == src.h && s.w == src.w && s.c == layer.cout, "skip shape");
    }
    dst.reset(src.h, src.w, layer.cout);
    let row_len = (src.w + 2) * layer.cout;
    let (h, w) = (src.h, src.w);
    // Output rows 0..h are padded rows 1..=h of dst.
    let rows = &mut dst.data[row_len..row_len * (h + 1)];
    let threads = threads.clamp(1, h.max(1));
    if threads == 1 {
        conv_rows(layer, src, rows, 0, h, w, post, portable);
        return;
    }
    #[cfg(target_arch = "wasm32")]
    {
        conv_rows(layer, src, rows, 0, h, w, post, portable);
    }
    #[cfg(not(target_arch = "wasm32"))]
    {
        // On rayon's pool: its threads stay awake between the layers of a network, where
        // starting threads per layer cost ~70 µs a layer and half the second core's gain.
        use rayon::prelude::*;
        let per = h.div_ceil(threads);
        rows.par_chunks_mut(per * row_len).enumerate().for_each(|(k, chunk)| conv_rows(layer, src, chunk, k * per, chunk.len() / row_len, w, post, portable));
    }
}

/// Whether this CPU runs the AVX2 + FMA kernels.
#[cfg(target_arch = "x86_64")]
fn has_avx2_fma() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

/// Output rows `y0..y0 + n` (`out` holds exactly those padded rows).
#[allow(clippy::too_many_arguments)]
fn conv_rows(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, n: usize, w: usize, post: Post, portable: bool) {
    #[cfg(not(target_arch = "x86_64"))]
    let _ = portable; // only x86 has a choice of kernels
    #[cfg(all(target_arch = "wasm32", target_feature = "simd128"))]
    if layer.cout % simd128::CH == 0 {
        simd128::rows(layer, src, out, y0, n, w, post);
        return;
    }
    if layer.cout == 1 && layer.cin % 8 == 0 {
        #[cfg(target_arch = "x86_64")]
        if !portable && has_avx2_fma() && layer.cin == 8 {
            // SAFETY: the CPU has AVX2 and FMA (checked just above).
            unsafe { x86::rows_dot8(layer, src, out, y0, n, w, post) };
            return;
        }
        rows_dot(layer, src, out, y0, n, w, post);
    } else if layer.cout % ROWS8_CH == 0 {
        #[cfg(target_arch = "x86_64")]
        if !portable && has_avx2_fma() {
            // SAFETY: the CPU has AVX2 and FMA (checked just above).
            unsafe {
                if layer.cout == LANES {
                    x86::rows32(layer, src, out, y0, n, w, post);
                } else {
                    x86::rows8(layer, src, out, y0, n, w, post);
                }
            }
            return;
        }
        rows8(layer, src, out, y0, n, w, post);
    } else {
        rows_plain(layer, src, out, y0, n, w, post);
    }
}

/// The 32-channel kernel with AVX2 + FMA intrinsics: 3 pixels × 4 vectors of 8 channels are
/// 12 accumulator registers, plus 3 broadcast inputs and one weight vector: all 16 registers,
/// no spills (the compiler's own vectorisation of the portable [`rows8`] spilled, or stayed
/// scalar).
#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::{BLOCK, Conv3, LANES, Map, Post, ROWS8_PX};
    use std::arch::x86_64::*;

    /// Any multiple of 8 output channels with AVX2 + FMA: blocks of 4 pixels × 16 channels
    /// (8 accumulator registers; the last 8 channels of an odd multiple take a 4 × 8 block).
    /// The compiler left the portable loop scalar (2 GMAC/s against 43 for `rows32`).
    ///
    /// # Safety
    /// The CPU must support AVX2 and FMA.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn rows8(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, n: usize, w: usize, post: Post) {
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
                        unsafe { block::<2>(layer, src, out, y0, r, x0, c0, w, post) };
                        c0 += 16;
                    } else {
                        unsafe { block::<1>(layer, src, out, y0, r, x0, c0, w, post) };
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
    unsafe fn block<const V: usize>(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, r: usize, x0: usize, c0: usize, w: usize, post: Post) {
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
                            a[v] = _mm256_fmadd_ps(x, wv[v], a[v]);
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
    pub(super) unsafe fn rows32(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, n: usize, w: usize, post: Post) {
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
                            a00 = _mm256_fmadd_ps(v0, wv, a00);
                            a10 = _mm256_fmadd_ps(v1, wv, a10);
                            a20 = _mm256_fmadd_ps(v2, wv, a20);
                            let wv = _mm256_loadu_ps(w1);
                            a01 = _mm256_fmadd_ps(v0, wv, a01);
                            a11 = _mm256_fmadd_ps(v1, wv, a11);
                            a21 = _mm256_fmadd_ps(v2, wv, a21);
                            let wv = _mm256_loadu_ps(w2);
                            a02 = _mm256_fmadd_ps(v0, wv, a02);
                            a12 = _mm256_fmadd_ps(v1, wv, a12);
                            a22 = _mm256_fmadd_ps(v2, wv, a22);
                            let wv = _mm256_loadu_ps(w3);
                            a03 = _mm256_fmadd_ps(v0, wv, a03);
                            a13 = _mm256_fmadd_ps(v1, wv, a13);
                            a23 = _mm256_fmadd_ps(v2, wv, a23);
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
    /// at a time (four independent chains), then the 8 lanes added up.
    ///
    /// # Safety
    /// The CPU must support AVX2 and FMA.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn rows_dot8(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, n: usize, w: usize, post: Post) {
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
                            *a = _mm256_fmadd_ps(_mm256_loadu_ps(px[8 * p..].as_ptr()), *wv, *a);
                        }
                    }
                    for (p, a) in acc.iter().enumerate().take(4.min(w - x0)) {
                        let mut l = [0f32; 8];
                        _mm256_storeu_ps(l.as_mut_ptr(), *a);
                        let v = layer.b[0] + ((l[0] + l[4]) + (l[1] + l[5])) + ((l[2] + l[6]) + (l[3] + l[7]));
                        out[r * sw + x0 + p + 1] = match post {
                            Post::None => v,
                            Post::Relu => v.max(0.0),
                            Post::Add(s) => v + s.pixel(y, x0 + p)[0],
                        };
                    }
                    x0 += 4;
                }
            }
        }
    }
}

/// The page's kernel with SIMD128 intrinsics for any multiple of 8 output channels: blocks of
/// [`simd128::PX`] pixels × 8 channels, 8 vector accumulators, which stay in a browser's 16
/// vector registers (the compiler left the portable kernel scalar for wasm, ~15× slower than
/// native). Multiplies and adds in the same order as the portable kernel.
#[cfg(all(target_arch = "wasm32", target_feature = "simd128"))]
mod simd128 {
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
}

/// Pixels per block of [`rows8`].
const ROWS8_PX: usize = 4;
/// Output channels per pass of [`rows8`].
const ROWS8_CH: usize = 8;

/// Any multiple of 8 output channels (the portable kernel; natively the tests' reference for
/// the AVX2 kernels): blocks of [`ROWS8_PX`] pixels × 8 channels, the same blocking and order
/// as the page's SIMD128 kernel.
#[inline(always)]
fn rows8(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, n: usize, w: usize, post: Post) {
    let (cin, cout) = (layer.cin, layer.cout);
    let sw = src.w + 2;
    let row_len = sw * cout;
    assert!(src.data.len() >= ((y0 + n + 1) * sw + w + 2 + ROWS8_PX) * cin);
    assert!(cout % ROWS8_CH == 0 && layer.w.len() == 9 * cin * cout && layer.b.len() == cout && out.len() == n * row_len);
    for r in 0..n {
        let y = y0 + r;
        let mut x0 = 0;
        while x0 < w {
            for c0 in (0..cout).step_by(ROWS8_CH) {
                let bias: [f32; ROWS8_CH] = layer.b[c0..c0 + ROWS8_CH].try_into().expect("8 biases");
                let mut acc = [bias; ROWS8_PX];
                for tap in 0..9 {
                    let (ky, kx) = (tap / 3, tap % 3);
                    let base = ((y + ky) * sw + x0 + kx) * cin;
                    let wbase = tap * cin * cout + c0;
                    for ci in 0..cin {
                        let wv: &[f32; ROWS8_CH] = layer.w[wbase + ci * cout..][..ROWS8_CH].try_into().expect("8 weights");
                        for (p, a) in acc.iter_mut().enumerate() {
                            // SAFETY: below the bound asserted above.
                            let v = unsafe { *src.data.get_unchecked(base + p * cin + ci) };
                            for c in 0..ROWS8_CH {
                                a[c] += v * wv[c];
                            }
                        }
                    }
                }
                for (p, a) in acc.iter().enumerate().take(ROWS8_PX.min(w - x0)) {
                    let o = r * row_len + (x0 + p + 1) * cout + c0;
                    let dst = &mut out[o..o + ROWS8_CH];
                    for c in 0..ROWS8_CH {
                        dst[c] = match post {
                            Post::None => a[c],
                            Post::Relu => a[c].max(0.0),
                            Post::Add(s) => a[c] + s.data[s.at(y, x0 + p) + c0 + c],
                        };
                    }
                }
            }
            x0 += ROWS8_PX;
        }
    }
}

/// One output channel from a multiple of 8 input channels (the TEM's 8 → 1 tail): per pixel,
/// 8 partial sums over the taps, added up in a fixed order.
#[inline(always)]
fn rows_dot(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, n: usize, w: usize, post: Post) {
    let cin = layer.cin;
    let sw = src.w + 2;
    let (wrows, _) = layer.w.as_chunks::<8>();
    for r in 0..n {
        let y = y0 + r;
        for x in 0..w {
            let mut acc = [0f32; 8];
            for tap in 0..9 {
                let (ky, kx) = (tap / 3, tap % 3);
                let (px, _) = src.data[((y + ky) * sw + x + kx) * cin..][..cin].as_chunks::<8>();
                for (v, wv) in px.iter().zip(&wrows[tap * cin / 8..(tap + 1) * cin / 8]) {
                    for l in 0..8 {
                        acc[l] += v[l] * wv[l];
                    }
                }
            }
            let a = layer.b[0] + ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]));
            out[r * sw + x + 1] = match post {
                Post::None => a,
                Post::Relu => a.max(0.0),
                Post::Add(s) => a + s.pixel(y, x)[0],
            };
        }
    }
}

/// Any channel count: one output pixel at a time.
fn rows_plain(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, n: usize, w: usize, post: Post) {
    let (cin, cout) = (layer.cin, layer.cout);
    let sw = src.w + 2;
    let row_len = sw * cout;
    let mut acc = vec![0f32; cout];
    for r in 0..n {
        let y = y0 + r;
        for x in 0..w {
            acc.copy_from_slice(&layer.b);
            for tap in 0..9 {
                let (ky, kx) = (tap / 3, tap % 3);
                let px = &src.data[((y + ky) * sw + x + kx) * cin..][..cin];
                let wt = &layer.w[tap * cin * cout..(tap + 1) * cin * cout];
                for (ci, v) in px.iter().enumerate() {
                    for (a, wv) in acc.iter_mut().zip(&wt[ci * cout..(ci + 1) * cout]) {
                        *a += v * wv;
                    }
                }
            }
            let o = r * row_len + (x + 1) * cout;
            for (co, a) in acc.iter().enumerate() {
                out[o + co] = match post {
                    Post::None => *a,
                    Post::Relu => a.max(0.0),
                    Post::Add(s) => a + s.pixel(y, x)[co],
                };
            }
        }
    }
}

/// Rearranges `src` (`c`·4 channels) into a map of twice the size with `c` channels:
/// output channel k of pixel (2y + dy, 2x + dx) is input channel 4k + 2dy + dx of (y, x)
/// (PyTorch's and burn's PixelShuffle with factor 2).
pub fn pixel_shuffle2(src: &Map, dst: &mut Map) {
    assert_eq!(src.c % 4, 0, "channels must be a multiple of 4");
    let c = src.c / 4;
    dst.reset(2 * src.h, 2 * src.w, c);
    for y in 0..src.h {
        for x in 0..src.w {
            let i = src.at(y, x);
            for dy in 0..2 {
                for dx in 0..2 {
                    let o = dst.at(2 * y + dy, 2 * x + dx);
                    for k in 0..c {
                        dst.data[o + k] = src.data[i + 4 * k + 2 * dy + dx];
                    }
                }
            }
        }
    }
}

/// 2×2 mean pooling: `dst` becomes `src` at half the size (odd last rows/columns dropped).
pub fn pool2(src: &Map, dst: &mut Map) {
    let (h, w, c) = (src.h / 2, src.w / 2, src.c);
    dst.reset(h, w, c);
    for y in 0..h {
        for x in 0..w {
            let o = dst.at(y, x);
            let (a, b, d, e) = (src.at(2 * y, 2 * x), src.at(2 * y, 2 * x + 1), src.at(2 * y + 1, 2 * x), src.at(2 * y + 1, 2 * x + 1));
            for k in 0..c {
                // The same order as a mean over a [2, 2] block: the pair of each row, then rows.
                let top = (src.data[a + k] + src.data[b + k]) * 0.5;
                let bottom = (src.data[d + k] + src.data[e + k]) * 0.5;
                dst.data[o + k] = (top + bottom) * 0.5;
            }
        }
    }
}

/// `src` upsampled ×2 (nearest): `dst` becomes twice the size with the same channels.
pub fn up2(src: &Map, dst: &mut Map) {
    let c = src.c;
    dst.reset(2 * src.h, 2 * src.w, c);
    for y in 0..2 * src.h {
        for x in 0..2 * src.w {
            let (o, i) = (dst.at(y, x), src.at(y / 2, x / 2));
            dst.data[o..o + c].copy_from_slice(&src.data[i..i + c]);
        }
    }
}

/// The `side`² centre of `coarse` upsampled ×2 (nearest) followed by the `side`² centre of
/// `skip`, as one map of `coarse.c + skip.c` channels (a UNet decoder's input).
pub fn up2_concat(coarse: &Map, skip: &Map, side: usize, dst: &mut Map) {
    let (cu, cs) = (coarse.c, skip.c);
    dst.reset(side, side, cu + cs);
    let (ou, os) = ((2 * coarse.h - side) / 2, (skip.h - side) / 2);
    for y in 0..side {
        for x in 0..side {
            let o = dst.at(y, x);
            let u = coarse.at((y + ou) / 2, (x + ou) / 2);
            dst.data[o..o + cu].copy_from_slice(&coarse.data[u..u + cu]);
            let k = skip.at(y + os, x + os);
            dst.data[o + cu..o + cu + cs].copy_from_slice(&skip.data[k..k + cs]);
        }
    }
}

/// Copies a burn 3×3 convolution's weights and bias.
pub fn conv_from_burn(c: &burn::nn::conv::Conv2d) -> Result<Conv3, String> {
    let w = c.weight.val();
    let [cout, cin, _, _] = w.dims();
    let w: Vec<f32> = w.into_data().try_to_vec::<f32>().map_err(|e| format!("{e:?}"))?;
    let b: Option<Vec<f32>> = match &c.bias {
        Some(b) => Some(b.val().into_data().try_to_vec::<f32>().map_err(|e| format!("{e:?}"))?),
        None => None,
    };
    Conv3::from_oihw(cout, cin, &w, b.as_deref()).map_err(|e| e.to_string())
}

/// Writes `src`'s weights and bias into a burn 3×3 convolution of the same shape (the start of
/// a training run from weights the CPU kernels read); the parameters keep their
/// gradient-tracking state.
#[cfg(feature = "train")]
pub fn conv_into_burn(src: &Conv3, c: &mut burn::nn::conv::Conv2d) {
    use burn::tensor::{Tensor, TensorData};
    let (w, b) = src.to_oihw();
    let (cout, cin) = (src.cout, src.cin);
    c.weight = c.weight.clone().map(|t| {
        assert_eq!(t.dims(), [cout, cin, 3, 3], "conv_into_burn: shapes differ");
        let grad = t.is_require_grad();
        Tensor::<4>::from_data(TensorData::new(w, [cout, cin, 3, 3]), &t.device()).set_require_grad(grad)
    });
    if let Some(bias) = c.bias.take() {
        c.bias = Some(bias.map(|t| {
            let grad = t.is_require_grad();
            Tensor::<1>::from_data(TensorData::new(b, [cout]), &t.device()).set_require_grad(grad)
        }));
    }
}

/// Reads the 3×3 convolutions `layers` (name, output channels, input channels) from a
/// burnpack weight file (as burn writes it: `{name}.weight` [cout, cin, 3, 3] and
/// `{name}.bias` [cout], float32, or float16 as [`to_half_burnpack`] writes it) without a
/// tensor framework. Anything missing, misshapen or
/// non-finite is an error naming the tensor.
pub fn convs_from_burnpack(bytes: &[u8], layers: &[(String, usize, usize)]) -> Result<Vec<Conv3>, crate::models::WeightError> {
    let reader = burn_pack::Reader::from_bytes(burn_pack::Bytes::from_bytes_vec(bytes.to_vec())).map_err(|e| crate::models::WeightError::NotWeightFile(e.to_string()))?;
    let tensors = reader.into_tensors().map_err(|e| crate::models::WeightError::Unreadable(e.to_string()))?;
    let mut by_name = std::collections::HashMap::new();
    for t in tensors {
        let (name, dtype, shape, _, data) = t.into_parts().map_err(|e| crate::models::WeightError::Unreadable(e.to_string()))?;
        by_name.insert(name, (dtype, shape, data));
    }
    let mut get = |name: &str| -> Result<(Vec<usize>, Vec<f32>), crate::models::WeightError> {
        let (dtype, shape, data) = by_name.remove(name).ok_or_else(|| crate::models::WeightError::Missing(vec![name.to_string()]))?;
        let (size, decode): (usize, fn(&[u8]) -> f32) = match dtype {
            burn_pack::DType::F32 => (4, |c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])),
            burn_pack::DType::F16 => (2, |c| half::f16::from_le_bytes([c[0], c[1]]).to_f32()),
            _ => return Err(crate::models::WeightError::Type { name: name.to_string(), dtype: format!("{dtype:?}") }),
        };
        let dims = shape.to_vec();
        if data.len() != dims.iter().product::<usize>() * size {
            return Err(crate::models::WeightError::Size { name: name.to_string(), bytes: data.len(), shape: dims });
        }
        let values = data.chunks_exact(size).map(decode).collect();
        Ok((dims, values))
    };
    let mut convs = Vec::new();
    for (name, cout, cin) in layers {
        let (cout, cin) = (*cout, *cin);
        let (wd, w) = get(&format!("{name}.weight"))?;
        if wd != [cout, cin, 3, 3] {
            return Err(crate::models::WeightError::Shape { name: format!("{name}.weight"), got: wd, want: vec![cout, cin, 3, 3] });
        }
        let (_, b) = get(&format!("{name}.bias"))?;
        convs.push(Conv3::from_oihw(cout, cin, &w, Some(&b)).map_err(|source| crate::models::WeightError::Layer { name: name.clone(), source })?);
    }
    Ok(convs)
}

/// Named 3×3 convolutions as a JSON object (`{name: {"shape": [cout, cin, 3, 3], "w": […],
/// "b": […]}}`, weights row-major in that shape), for reference runtimes that rebuild a
/// network (tools/tem_vs_onnx.py, tools/sketch_vs_onnx.py).
pub fn convs_json<'a>(named: impl IntoIterator<Item = (String, &'a Conv3)>) -> serde_json::Value {
    let m: serde_json::Map<String, serde_json::Value> = named
        .into_iter()
        .map(|(name, c)| {
            let (w, b) = c.to_oihw();
            (name, serde_json::json!({ "shape": [c.cout, c.cin, 3, 3], "w": w, "b": b }))
        })
        .collect();
    serde_json::Value::Object(m)
}

/// Writes the 3×3 convolutions `convs` under the names of `layers` as a burnpack weight file
/// (float32 `{name}.weight` [cout, cin, 3, 3] and `{name}.bias` [cout]), the inverse of
/// [`convs_from_burnpack`].
pub fn convs_to_burnpack(layers: &[(String, usize, usize)], convs: &[Conv3]) -> Vec<u8> {
    let le = |v: &[f32]| burn_pack::Bytes::from_bytes_vec(v.iter().flat_map(|x| x.to_le_bytes()).collect());
    let mut tensors = Vec::new();
    for ((name, _, _), c) in layers.iter().zip(convs) {
        let (w, b) = c.to_oihw();
        tensors.push(burn_pack::Tensor::new(format!("{name}.weight"), burn_pack::DType::F32, vec![c.cout, c.cin, 3, 3], None, le(&w)));
        tensors.push(burn_pack::Tensor::new(format!("{name}.bias"), burn_pack::DType::F32, vec![c.cout], None, le(&b)));
    }
    burn_pack::Writer::new(tensors).into_bytes().expect("an in-memory weight file").to_vec()
}

/// One tensor of a weight file: (name, dtype, shape, id, data).
type TensorParts = (String, burn_pack::DType, burn_pack::Shape, Option<u64>, burn_pack::Bytes);

/// The tensors of weight file `bytes` (burnpack), for the functions that rewrite weight files.
fn tensor_parts(bytes: &[u8]) -> Result<Vec<TensorParts>, String> {
    let reader = burn_pack::Reader::from_bytes(burn_pack::Bytes::from_bytes_vec(bytes.to_vec())).map_err(|e| format!("not a weight file ({e})"))?;
    reader.into_tensors().map_err(|e| format!("unreadable tensors ({e})"))?.into_iter().map(|t| t.into_parts().map_err(|e| format!("unreadable tensor ({e})"))).collect()
}

/// The weight file `bytes` (burnpack) with every float32 tensor stored as float16 (IEEE half,
/// rounded to nearest): half the download of every shipped network, whose outputs move by
/// about 1e-3 of their range. [`convs_from_burnpack`] reads it back to float32, and so does
/// burn with a float-cast adapter (the TEM on WebGPU). Other tensors are kept as they are.
pub fn to_half_burnpack(bytes: &[u8]) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    for (name, dtype, shape, id, data) in tensor_parts(bytes)? {
        let t = if dtype == burn_pack::DType::F32 {
            let half: Vec<u8> = data.chunks_exact(4).flat_map(|c| half::f16::from_f32(f32::from_le_bytes([c[0], c[1], c[2], c[3]])).to_le_bytes()).collect();
            burn_pack::Tensor::new(name, burn_pack::DType::F16, shape, id, burn_pack::Bytes::from_bytes_vec(half))
        } else {
            burn_pack::Tensor::new(name, dtype, shape, id, data)
        };
        out.push(t);
    }
    Ok(burn_pack::Writer::new(out).into_bytes().map_err(|e| format!("writing the weight file: {e}"))?.to_vec())
}

/// The element-wise mean of weight files (burnpack) of one network, e.g. the checkpoints at
/// the end of a training run (weight averaging: a smoother model than any one of them).
/// Every file must hold the same float32 tensors (names and shapes) in the same order.
pub fn average_burnpacks(files: &[Vec<u8>]) -> Result<Vec<u8>, String> {
    let Some((first, rest)) = files.split_first() else { return Err("no weight file to average".into()) };
    let mut sum: Vec<_> = tensor_parts(first)?
        .into_iter()
        .map(|(name, dtype, shape, id, data)| {
            if dtype != burn_pack::DType::F32 {
                return Err(format!("tensor {name} is {dtype:?}, not float32"));
            }
            let v: Vec<f64> = data.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f64).collect();
            Ok((name, shape, id, v))
        })
        .collect::<Result<_, _>>()?;
    for (k, file) in rest.iter().enumerate() {
        let tensors = tensor_parts(file)?;
        if tensors.len() != sum.len() {
            return Err(format!("file {} has {} tensors, the first {}", k + 2, tensors.len(), sum.len()));
        }
        for ((name, dtype, shape, _, data), (n0, s0, _, acc)) in tensors.into_iter().zip(sum.iter_mut()) {
            if name != *n0 || shape != *s0 || dtype != burn_pack::DType::F32 {
                return Err(format!("file {}: tensor {name} {shape:?} {dtype:?} does not match {n0} {s0:?} float32", k + 2));
            }
            for (a, c) in acc.iter_mut().zip(data.chunks_exact(4)) {
                *a += f32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f64;
            }
        }
    }
    let n = files.len() as f64;
    let out = sum
        .into_iter()
        .map(|(name, shape, id, acc)| {
            let bytes: Vec<u8> = acc.iter().flat_map(|v| ((v / n) as f32).to_le_bytes()).collect();
            burn_pack::Tensor::new(name, burn_pack::DType::F32, shape, id, burn_pack::Bytes::from_bytes_vec(bytes))
        })
        .collect();
    Ok(burn_pack::Writer::new(out).into_bytes().map_err(|e| format!("writing the weight file: {e}"))?.to_vec())
}

/// Runs `a` and `b` and returns both results: side by side on the kernels' thread pool where
/// `parallel` (natively), else one after the other (and always so in the page).
pub fn join<A: Send, B: Send>(parallel: bool, a: impl FnOnce() -> A + Send, b: impl FnOnce() -> B + Send) -> (A, B) {
    #[cfg(not(target_arch = "wasm32"))]
    if parallel {
        return rayon::join(a, b);
    }
    let _ = parallel;
    (a(), b())
}

/// Threads the CPU path uses by default: every core natively, one in the page.
pub fn default_threads() -> usize {
    #[cfg(target_arch = "wasm32")]
    {
        1
    }
    #[cfg(not(target_arch = "wasm32"))]
    {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    }
}

#[cfg(test)]
mod tests {
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
        let f64_file = burn_pack::Writer::new(vec![burn_pack::Tensor::new("a.weight".into(), burn_pack::DType::F64, vec![1], None, burn_pack::Bytes::from_bytes_vec(vec![0; 8]))]).into_bytes().unwrap().to_vec();
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
        for portable in [true, false] {
            let (mut a, mut b) = (Map::default(), Map::default());
            conv_impl(&layer, &src, &mut a, Post::None, 1, portable);
            conv_impl(&padded, &src, &mut b, Post::None, 1, portable);
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

    /// Every kernel (32 output channels blocked — AVX2 + FMA and portable —, 1 from 8 or 16 as dot
    /// products, 3 plain), widths that are and are not a
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
            let layer = Conv3::from_oihw(cout, cin, &wt, Some(&b)).unwrap();
            let src = map_from_nchw(&x, cin, h, w);
            let skip = map_from_nchw(&skip_v, cout, h, w);
            for (threads, portable) in [(1, false), (3, false), (1, true), (3, true)] {
                for post in [Post::None, Post::Relu, Post::Add(&skip)] {
                    let mut dst = Map::default();
                    conv_impl(&layer, &src, &mut dst, post, threads, portable);
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
                    assert!(worst < 1e-4, "{cout}x{cin} {h}x{w} threads {threads} portable {portable} {post:?}: off by {worst}");
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
}
