//! CPU inference without a tensor framework: 3×3 convolutions with "same" zero padding on
//! channel-last activation maps, the kind of layer every model of the project is made of.
//!
//! Why not burn's CPU backend: for the TEM it was ~9× slower than ONNX Runtime (im2col into a
//! fresh buffer per layer, one operation at a time). Here each layer is one pass of a
//! register-blocked kernel: a few output pixels × output channels are accumulated in
//! registers over the 9 taps × input channels, with bias, ReLU or a skip connection applied
//! as the block is stored; activation buffers are reused between calls. Kernels: AVX-512 or
//! AVX2 + FMA intrinsics natively (chosen at run time, the widest the CPU has; AVX-512: 6–8
//! pixels × up to 64 channels, or 16 pixels × 24 channels, AVX2: [`BLOCK`] pixels × 32 channels), SIMD128
//! intrinsics in the page (4 pixels × 8 channels, any multiple of 8 channels), and portable
//! Rust elsewhere. Every kernel accumulates in the same order, and by default each step is a
//! multiply, then an add, so every kernel on every machine, the page's included, gives the same
//! bits: a learned tile is a pure function of (seed, weights, tile), and a last-bit
//! difference cannot flip a drainage choice downstream. A layer made [`Conv3::with_fused`] (the
//! TEM's, whose output nothing downstream amplifies, and the sketch generator's, except where
//! its terrain is pinned into the world: `SketchGenCpu::exact`) lets the x86 kernels fuse the two
//! into one FMA instead: 25–35 % faster natively, and the page's results then differ in the
//! last bits (0.24 mm on the TEM probe).

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
    /// Whether the x86 kernels fuse each multiply and add into one FMA for this layer: one
    /// rounding instead of two, 25–35 % faster on AVX-512, but results that differ in the last
    /// bits from the portable kernels and the page's. Off by default, so a layer gives the same
    /// bits on every machine and in the page ([`Conv3::with_fused`]).
    fused: bool,
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
        Ok(Self { cin, cout, w: t, b: b.to_vec(), fused: false })
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
        Self::from_oihw(cout, cin, &wide, Some(&b)).expect("zero-padded weights are finite and sized").with_fused(self.fused)
    }

    /// The same layer with one zero-weighted input channel inserted before input `at` (`at` =
    /// the layer's inputs: appended): the same function of the other inputs, whatever the new
    /// one holds.
    pub fn with_zero_input(&self, at: usize) -> Self {
        assert!(at <= self.cin, "input {at} of a layer with {} inputs", self.cin);
        let (w, b) = self.to_oihw();
        let cin = self.cin + 1;
        let mut wide = vec![0.0; self.cout * cin * 9];
        for o in 0..self.cout {
            for i in 0..self.cin {
                let to = if i < at { i } else { i + 1 };
                wide[(o * cin + to) * 9..][..9].copy_from_slice(&w[(o * self.cin + i) * 9..][..9]);
            }
        }
        Self::from_oihw(self.cout, cin, &wide, Some(&b)).expect("zero-padded weights are finite and sized").with_fused(self.fused)
    }

    /// A layer with every weight and bias uniform in ±`amplitude`, drawn from `seed` with
    /// integer arithmetic (tests: untrained networks that still compute something).
    pub fn random(cout: usize, cin: usize, seed: u64, amplitude: f32) -> Self {
        let mut k = seed;
        let w: Vec<f32> = (0..cout * cin * 9).map(|_| unit(&mut k) * amplitude).collect();
        let b: Vec<f32> = (0..cout).map(|_| unit(&mut k) * amplitude).collect();
        Self::from_oihw(cout, cin, &w, Some(&b)).expect("sizes match")
    }

    /// The same layer, with the x86 kernels allowed to fuse each multiply and add into one
    /// FMA (`true`: one rounding instead of two, 25–35 % faster on AVX-512, but results that
    /// differ in the last bits from the portable kernels and the page's) or not (`false`, every
    /// layer's default: the same bits on every machine and in the page).
    pub fn with_fused(mut self, fused: bool) -> Self {
        self.fused = fused;
        self
    }

    /// Whether the x86 kernels fuse this layer's multiply-adds ([`Conv3::with_fused`]).
    pub fn is_fused(&self) -> bool {
        self.fused
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
    /// Reshapes the map to `h`×`w`×`c`, reusing its buffer: the border and the slack are zero;
    /// the interior holds whatever the buffer held (every caller overwrites every pixel).
    /// Clearing the whole buffer on every change of shape was 2–5 % of the sketch generator's
    /// time (perf): a UNet's maps change shape at every layer.
    pub fn reset(&mut self, h: usize, w: usize, c: usize) {
        let len = ((h + 2) * (w + 2) + SLACK_PX) * c;
        if (h, w, c) != (self.h, self.w, self.c) || self.data.len() != len {
            self.h = h;
            self.w = w;
            self.c = c;
            // Shrinking keeps the buffer; growing zero-fills only the new part.
            self.data.resize(len, 0.0);
        }
        let row = (w + 2) * c;
        self.data[..row].fill(0.0);
        self.data[(h + 1) * row..].fill(0.0);
        for y in 1..=h {
            self.data[y * row..][..c].fill(0.0);
            self.data[(y + 1) * row - c..][..c].fill(0.0);
        }
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
    conv_impl(layer, src, dst, post, threads, Kernels::chosen())
}

/// Which kernels a convolution may use: the best this CPU has, or (tests, benchmarks) a
/// narrower set even where wider ones exist.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernels {
    /// AVX-512 where present, else AVX2 + FMA where present, else portable (natively; the page
    /// has its SIMD128 kernel).
    Best,
    /// AVX2 + FMA where present, else portable: never AVX-512.
    Avx2,
    /// The portable kernels only.
    Portable,
}

impl Kernels {
    /// What [`conv`] uses: [`Kernels::Best`], or [`Kernels::Avx2`] / [`Kernels::Portable`]
    /// when the environment variable `TERRAIN_CPU_KERNELS` is `avx2` / `portable` (read once;
    /// for comparing them in benchmarks; every one gives the same bits, except for a layer
    /// made [`Conv3::with_fused`], which the x86 kernels fuse).
    pub fn chosen() -> Self {
        #[cfg(not(target_arch = "wasm32"))]
        {
            static CHOSEN: std::sync::OnceLock<Kernels> = std::sync::OnceLock::new();
            *CHOSEN.get_or_init(|| match std::env::var("TERRAIN_CPU_KERNELS").as_deref() {
                Ok("avx2") => Kernels::Avx2,
                Ok("portable") => Kernels::Portable,
                _ => Kernels::Best,
            })
        }
        #[cfg(target_arch = "wasm32")]
        Kernels::Best
    }

    /// The name of the widest kernels these allow on this CPU ("avx512", "avx2+fma",
    /// "simd128" or "portable"), for benchmarks' output.
    pub fn widest(self) -> &'static str {
        #[cfg(target_arch = "x86_64")]
        {
            if self == Kernels::Best && has_avx512() {
                return "avx512";
            }
            if self != Kernels::Portable && has_avx2_fma() {
                return "avx2+fma";
            }
        }
        #[cfg(all(target_arch = "wasm32", target_feature = "simd128"))]
        return "simd128";
        #[allow(unreachable_code)]
        "portable"
    }
}

/// [`conv`] on the given set of kernels (tests run each).
pub(crate) fn conv_impl(layer: &Conv3, src: &Map, dst: &mut Map, post: Post, threads: usize, kernels: Kernels) {
    conv_then(layer, src, dst, post, threads, kernels, |_| {});
}

/// [`conv_impl`], then `finish` on each run of output rows (padded rows of `dst`) in the
/// thread that made it.
fn conv_then(layer: &Conv3, src: &Map, dst: &mut Map, post: Post, threads: usize, kernels: Kernels, finish: impl Fn(&mut [f32]) + Sync) {
    assert_eq!(src.c, layer.cin, "input channels");
    if let Post::Add(s) = post {
        assert!(s.h == src.h && s.w == src.w && s.c == layer.cout, "skip shape");
    }
    dst.reset(src.h, src.w, layer.cout);
    let row_len = (src.w + 2) * layer.cout;
    let (h, w) = (src.h, src.w);
    // Output rows 0..h are padded rows 1..=h of dst.
    let rows = &mut dst.data[row_len..row_len * (h + 1)];
    for_row_runs(rows, row_len, threads, |y0, run| {
        conv_rows(layer, src, run, y0, run.len() / row_len, w, post, kernels);
        finish(run);
    });
}

/// Whether this CPU runs the AVX2 + FMA kernels.
#[cfg(target_arch = "x86_64")]
fn has_avx2_fma() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

/// Whether this CPU runs the AVX-512 kernel.
#[cfg(target_arch = "x86_64")]
fn has_avx512() -> bool {
    std::arch::is_x86_feature_detected!("avx512f")
}

/// Whether `kernels` run any number of output channels (2 and more) vectorised here: the
/// AVX-512 kernel masks its last vector, where the AVX2 and the page's kernels take multiples
/// of 8 only (others run on the scalar kernel, ~7× slower).
fn any_channels(kernels: Kernels) -> bool {
    #[cfg(target_arch = "x86_64")]
    return kernels == Kernels::Best && has_avx512();
    #[allow(unreachable_code)]
    {
        let _ = kernels;
        false
    }
}

/// Whether [`conv`] runs layers of any number of output channels (2 and more) on vectorised
/// kernels on this machine (AVX-512 chosen): a network need not be widened to multiples of 8
/// channels, whose zero channels cost as much as real ones.
pub fn runs_any_channels() -> bool {
    any_channels(Kernels::chosen())
}

/// Output rows `y0..y0 + n` (`out` holds exactly those padded rows).
#[allow(clippy::too_many_arguments)]
fn conv_rows(layer: &Conv3, src: &Map, out: &mut [f32], y0: usize, n: usize, w: usize, post: Post, kernels: Kernels) {
    #[cfg(not(target_arch = "x86_64"))]
    let _ = kernels; // only x86 has a choice of kernels
    #[cfg(target_arch = "x86_64")]
    let portable = kernels == Kernels::Portable;
    #[cfg(all(target_arch = "wasm32", target_feature = "simd128"))]
    if layer.cout.is_multiple_of(simd128::CH) {
        simd128::rows(layer, src, out, y0, n, w, post);
        return;
    }
    if layer.cout == 1 && layer.cin.is_multiple_of(8) {
        #[cfg(target_arch = "x86_64")]
        if !portable && has_avx2_fma() {
            // SAFETY: the CPU has AVX2 and FMA (checked just above).
            unsafe {
                if layer.cin == 8 && layer.fused {
                    x86::rows_dot8::<true>(layer, src, out, y0, n, w, post);
                } else if layer.cin == 8 {
                    x86::rows_dot8::<false>(layer, src, out, y0, n, w, post);
                } else {
                    x86::rows_dot(layer, src, out, y0, n, w, post);
                }
            }
            return;
        }
        rows_dot(layer, src, out, y0, n, w, post);
    } else if layer.cout.is_multiple_of(ROWS8_CH) || any_channels(kernels) {
        // A fused layer of 32 output channels takes the AVX2 kernel even where AVX-512 is
        // present, with the same bits: its 3 × 32 block ran the TEM 7 % faster on Zen 4
        // (9.4 against 10.1 ms a quad, every level). Unfused, the AVX-512 kernel is faster
        // (the ×4 step: 13.7 against 16.1 ms a tile). The AVX-512 kernel runs a layer of 24
        // output channels along the pixels, every lane working (its channel vectors would mask
        // a quarter): the sketch generator's 24-channel layers 25–30 % faster.
        #[cfg(target_arch = "x86_64")]
        if kernels == Kernels::Best && has_avx512() && !(layer.cout == LANES && layer.fused && has_avx2_fma()) {
            // SAFETY: the CPU has AVX-512F (checked just above).
            unsafe {
                if layer.fused {
                    x86_512::rows::<true>(layer, src, out, y0, n, w, post);
                } else {
                    x86_512::rows::<false>(layer, src, out, y0, n, w, post);
                }
            }
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if !portable && has_avx2_fma() {
            // SAFETY: the CPU has AVX2 and FMA (checked just above).
            unsafe {
                match (layer.cout == LANES, layer.fused) {
                    (true, true) => x86::rows32::<true>(layer, src, out, y0, n, w, post),
                    (true, false) => x86::rows32::<false>(layer, src, out, y0, n, w, post),
                    (false, true) => x86::rows8::<true>(layer, src, out, y0, n, w, post),
                    (false, false) => x86::rows8::<false>(layer, src, out, y0, n, w, post),
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
mod x86;

/// Any number of output channels with AVX-512F where the CPU has it: 6–8 pixels × up to 64
/// channels per block in up to 24 of its 32 vector registers (24 channels: 24 vectors of 16
/// pixels, every lane used), the same sums in the same order as the AVX2 kernels.
#[cfg(target_arch = "x86_64")]
mod x86_512;

/// The page's kernel with SIMD128 intrinsics for any multiple of 8 output channels: blocks of
/// [`simd128::PX`] pixels × 8 channels, 8 vector accumulators, which stay in a browser's 16
/// vector registers (the compiler left the portable kernel scalar for wasm, ~15× slower than
/// native). Multiplies and adds in the same order as the portable kernel.
#[cfg(all(target_arch = "wasm32", target_feature = "simd128"))]
mod simd128;

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

/// A one-channel output of pixel (`y`, `x`) from its 8 partial sums `l`: the bias `b` plus
/// the sums added up in the one fixed order every one-channel kernel uses, then `post`.
#[inline(always)]
fn dot_output(b: f32, l: &[f32; 8], post: Post, y: usize, x: usize) -> f32 {
    let v = b + ((l[0] + l[4]) + (l[1] + l[5])) + ((l[2] + l[6]) + (l[3] + l[7]));
    match post {
        Post::None => v,
        Post::Relu => v.max(0.0),
        Post::Add(s) => v + s.pixel(y, x)[0],
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
            out[r * sw + x + 1] = dot_output(layer.b[0], &acc, post, y, x);
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

/// 2×2 mean pooling: `dst` becomes `src` at half the size (odd last rows/columns dropped),
/// rows split between up to `threads` threads.
pub fn pool2(src: &Map, dst: &mut Map, threads: usize) {
    let (h, w, c) = (src.h / 2, src.w / 2, src.c);
    dst.reset(h, w, c);
    let row_len = (w + 2) * c;
    for_row_runs(&mut dst.data[row_len..row_len * (h + 1)], row_len, threads, |y0, run| {
        for (y, row) in run.chunks_exact_mut(row_len).enumerate().map(|(i, row)| (y0 + i, row)) {
            for x in 0..w {
                let o = (x + 1) * c;
                let (a, b, d, e) = (src.at(2 * y, 2 * x), src.at(2 * y, 2 * x + 1), src.at(2 * y + 1, 2 * x), src.at(2 * y + 1, 2 * x + 1));
                for k in 0..c {
                    // The same order as a mean over a [2, 2] block: the pair of each row, then rows.
                    let top = (src.data[a + k] + src.data[b + k]) * 0.5;
                    let bottom = (src.data[d + k] + src.data[e + k]) * 0.5;
                    row[o + k] = (top + bottom) * 0.5;
                }
            }
        }
    });
}

/// Calls `f(y0, run)` for runs of consecutive padded rows of `rows` (interior rows from 0, each
/// `row_len` values including its two border pixels, which `f` leaves alone; `y0` the first
/// row of the run): the whole of `rows` on the calling thread where `threads` is 1 and in the
/// page, else up to `threads` runs side by side on rayon's pool, whose threads stay awake
/// between the layers of a network (starting threads per layer cost ~70 µs a layer and half
/// the second core's gain).
fn for_row_runs(rows: &mut [f32], row_len: usize, threads: usize, f: impl Fn(usize, &mut [f32]) + Sync) {
    #[cfg(not(target_arch = "wasm32"))]
    {
        let h = rows.len().checked_div(row_len).unwrap_or(0);
        let threads = threads.clamp(1, h.max(1));
        if threads > 1 {
            use rayon::prelude::*;
            let per = h.div_ceil(threads);
            rows.par_chunks_mut(per * row_len).enumerate().for_each(|(k, run)| f(k * per, run));
            return;
        }
    }
    #[cfg(target_arch = "wasm32")]
    let _ = (row_len, threads);
    f(0, rows);
}

/// Rounds every interior value of `map` to its channel's integer grid: channel `k`'s value `v`
/// becomes ⌊v · `scale[k]` + ½⌋ clamped to ±`max`.
/// With each `scale[k]` a power of two and |v · scale[k]| < 2²³, every step is exact in f32,
/// so every machine, kernel and backend gives the same bits ([`crate::models::exact`]).
pub fn requantize(map: &mut Map, scale: &[f32], max: f32) {
    assert_eq!(scale.len(), map.c, "one scale per channel");
    let (h, w, c) = (map.h, map.w, map.c);
    let row_len = (w + 2) * c;
    requantize_rows(&mut map.data[row_len..row_len * (h + 1)], w, c, scale, max);
}

/// [`conv_impl`], then every output value on its channel's integer grid as [`requantize`]
/// rounds it, each thread rounding the rows it made (the same bits as the two calls).
#[allow(clippy::too_many_arguments)]
pub(crate) fn conv_on_grid(layer: &Conv3, src: &Map, dst: &mut Map, post: Post, scale: &[f32], max: f32, threads: usize, kernels: Kernels) {
    assert_eq!(scale.len(), layer.cout, "one scale per channel");
    conv_then(layer, src, dst, post, threads, kernels, |run| requantize_rows(run, src.w, layer.cout, scale, max));
}

/// [`requantize`] on whole padded rows (`w` pixels of `c` channels between one padding pixel
/// on each side).
fn requantize_rows(rows: &mut [f32], w: usize, c: usize, scale: &[f32], max: f32) {
    let row_len = (w + 2) * c;
    for row in rows.chunks_exact_mut(row_len) {
        for px in row[c..(w + 1) * c].chunks_exact_mut(c) {
            for (v, &k) in px.iter_mut().zip(scale) {
                // ⌊·⌋ by truncation and a correction: exact below 2³¹, and vectorised where
                // f32::floor is a library call (x86-64 without SSE4.1).
                let x = *v * k + 0.5;
                let t = x as i32 as f32;
                *v = if t > x { t - 1.0 } else { t }.clamp(-max, max);
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
/// `skip`, as one map of `coarse.c + skip.c` channels (a UNet decoder's input), rows split
/// between up to `threads` threads.
pub fn up2_concat(coarse: &Map, skip: &Map, side: usize, dst: &mut Map, threads: usize) {
    let (cu, cs) = (coarse.c, skip.c);
    dst.reset(side, side, cu + cs);
    let (ou, os) = ((2 * coarse.h - side) / 2, (skip.h - side) / 2);
    let row_len = (side + 2) * (cu + cs);
    for_row_runs(&mut dst.data[row_len..row_len * (side + 1)], row_len, threads, |y0, run| {
        for (y, row) in run.chunks_exact_mut(row_len).enumerate().map(|(i, row)| (y0 + i, row)) {
            for (x, o) in row.chunks_exact_mut(cu + cs).skip(1).take(side).enumerate() {
                let u = coarse.at((y + ou) / 2, (x + ou) / 2);
                o[..cu].copy_from_slice(&coarse.data[u..u + cu]);
                let k = skip.at(y + os, x + os);
                o[cu..].copy_from_slice(&skip.data[k..k + cs]);
            }
        }
    });
}

mod weights;
pub use weights::*;

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
mod tests;
