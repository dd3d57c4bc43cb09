//! Dense 2-D convolution of one channels-last image with explicit zero padding and any kernel
//! size and stride, as matrix products ([`super::pointwise`]): a 1×1 stride-1 unpadded layer
//! multiplies the pixel rows in place; any other gathers the `kh·kw·C_in` values under each
//! output pixel (zeros off the image) into a per-thread block of rows first (with AVX2, reads
//! them in place through a table of tap pointers instead). The weight is TFLite's
//! `[C_out][kh][kw][C_in]`, whose rows are already in the gathered order. Two shapes have
//! kernels of their own with AVX2/FMA: a network's first convolution over the 3-channel RGB
//! image (the output vectors of a few pixels in registers, each input value broadcast), and
//! convolutions with at most 4 output channels (vectorised over pixels, input channels in
//! the lanes).

use std::cell::RefCell;

use super::nhwc::{Epilogue, Padding, Shape};
use super::parallel;
use super::pointwise::{rows_per_task, PackedGemm};

/// Floats of gathered rows per block (128 KiB).
const GATHER_FLOATS: usize = 1 << 15;

thread_local! {
    /// Each thread's gather buffer, kept between calls.
    static GATHER: RefCell<Vec<f32>> = const { RefCell::new(Vec::new()) };
    /// Each thread's row of zeros that padding taps point at.
    static ZEROS: RefCell<Vec<f32>> = const { RefCell::new(Vec::new()) };
}

/// Output channels up to which a layer runs as dot products over contiguous input runs.
const DOT_MAX_OUT: usize = 4;

/// Input channels of the layers that take [`ConvNhwc::rgb_rows`].
const RGB_IN: usize = 3;

/// A packed `kh×kw` convolution with a stride.
#[derive(Debug, Clone)]
pub struct ConvNhwc {
    gemm: PackedGemm,
    /// The weight as given (`[C_out][kh][kw][C_in]`), kept for layers of few outputs.
    rows: Option<Vec<f32>>,
    bias: Vec<f32>,
    kernel: (usize, usize),
    stride: (usize, usize),
    c_in: usize,
    /// For 3 input channels and up to 32 outputs in multiples of 8 (a network's first
    /// convolution over the RGB image): the weight as `[kh][kw][3][C_out]`.
    rgb: Option<Vec<f32>>,
}

impl ConvNhwc {
    /// Packs `weight [C_out][kh][kw][C_in]` and `bias [C_out]`; `stride` is (rows, columns).
    pub fn new(
        weight: &[f32],
        bias: &[f32],
        c_out: usize,
        kernel: (usize, usize),
        c_in: usize,
        stride: (usize, usize),
    ) -> Self {
        assert!(stride.0 > 0 && stride.1 > 0, "conv: zero stride");
        let k = kernel.0 * kernel.1 * c_in;
        let rgb = (c_in == RGB_IN && c_out % 8 == 0 && (8..=32).contains(&c_out)).then(|| {
            let mut packed = vec![0.0; k * c_out];
            for o in 0..c_out {
                for t in 0..k {
                    packed[t * c_out + o] = weight[o * k + t];
                }
            }
            packed
        });
        Self {
            gemm: PackedGemm::from_rows(weight, k, c_out, bias),
            rows: (c_out <= DOT_MAX_OUT).then(|| weight.to_vec()),
            rgb,
            bias: bias.to_vec(),
            kernel,
            stride,
            c_in,
        }
    }

    /// Input channels.
    pub fn in_channels(&self) -> usize {
        self.c_in
    }

    /// Output channels.
    pub fn out_channels(&self) -> usize {
        self.gemm.n()
    }

    /// Kernel (rows, columns).
    pub fn kernel(&self) -> (usize, usize) {
        self.kernel
    }

    /// Stride (rows, columns).
    pub fn stride(&self) -> (usize, usize) {
        self.stride
    }

    /// The output shape for an input shape and padding.
    pub fn out_shape(&self, input: Shape, pad: Padding) -> Shape {
        Shape::new(
            Padding::out_side(
                input.height,
                pad.top,
                pad.bottom,
                self.kernel.0,
                self.stride.0,
            ),
            Padding::out_side(
                input.width,
                pad.left,
                pad.right,
                self.kernel.1,
                self.stride.1,
            ),
            self.gemm.n(),
        )
    }

    /// `out = epi(conv(input padded by pad) + bias)`; `epi.residual` has the output's shape.
    pub fn run(&self, input: &[f32], shape: Shape, pad: Padding, epi: Epilogue, out: &mut [f32]) {
        assert_eq!(shape.channels, self.c_in, "conv: input channels");
        assert_eq!(input.len(), shape.len(), "conv: input length");
        let os = self.out_shape(shape, pad);
        assert_eq!(out.len(), os.len(), "conv: output length");
        let m = os.pixels();
        if m == 0 {
            return;
        }
        let direct = self.kernel == (1, 1) && self.stride == (1, 1) && pad == Padding::default();
        if direct {
            self.gemm.run(input, self.c_in, m, epi, out);
            return;
        }
        let n = self.gemm.n();
        #[cfg(target_arch = "x86_64")]
        if self.rgb.is_some() && super::gemm_avx2::available() {
            let macs = m * n * self.gemm.k();
            let per = parallel::items_per_task(os.height, macs, 1 << 18, 1);
            let k3s2 = self.kernel == (3, 3) && self.stride == (2, 2);
            parallel::for_each_chunk(out, per * os.width * n, |t, chunk| {
                let first = t * per;
                let job = RgbJob {
                    conv: self,
                    input,
                    shape,
                    pad,
                    os,
                    first_row: first,
                    epi,
                };
                #[cfg(lhmpp_bf16_intrinsics)]
                if k3s2 && rgb_avx512::available() {
                    // SAFETY: the CPU has AVX-512F/VL, AVX2 and FMA (checked).
                    unsafe {
                        match n / 8 {
                            1 => rgb_avx512::rows::<1, 12>(&job, chunk),
                            2 => rgb_avx512::rows::<2, 12>(&job, chunk),
                            3 => rgb_avx512::rows::<3, 8>(&job, chunk),
                            _ => rgb_avx512::rows::<4, 6>(&job, chunk),
                        }
                    }
                    return;
                }
                if k3s2 {
                    // SAFETY: the CPU has AVX2 and FMA (checked above).
                    unsafe {
                        match n / 8 {
                            1 => rgb_k3s2_avx2::<1, 8>(&job, chunk),
                            2 => rgb_k3s2_avx2::<2, 6>(&job, chunk),
                            3 => rgb_k3s2_avx2::<3, 4>(&job, chunk),
                            _ => rgb_k3s2_avx2::<4, 3>(&job, chunk),
                        }
                    }
                    return;
                }
                // SAFETY: the CPU has AVX2 and FMA (checked above).
                unsafe {
                    match n / 8 {
                        1 => self.rgb_rows::<1, 8>(input, shape, pad, os, first, epi, chunk),
                        2 => self.rgb_rows::<2, 6>(input, shape, pad, os, first, epi, chunk),
                        3 => self.rgb_rows::<3, 4>(input, shape, pad, os, first, epi, chunk),
                        _ => self.rgb_rows::<4, 3>(input, shape, pad, os, first, epi, chunk),
                    }
                }
            });
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if self.rows.is_some()
            && self.c_in % 8 == 0
            && self.kernel.0 == self.kernel.1
            && self.stride.0 == self.stride.1
            && matches!((self.kernel.0, self.stride.0), (3, 1) | (3, 2))
            && super::gemm_avx2::available()
        {
            let macs = m * n * self.gemm.k();
            let per = parallel::items_per_task(os.height, macs, 1 << 18, 1);
            parallel::for_each_chunk(out, per * os.width * n, |t, chunk| {
                // SAFETY: the CPU has AVX2 and FMA (checked above).
                unsafe {
                    match self.stride.0 {
                        1 => self.few_out_rows::<3, 1>(input, shape, pad, os, t * per, epi, chunk),
                        _ => self.few_out_rows::<3, 2>(input, shape, pad, os, t * per, epi, chunk),
                    }
                }
            });
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if self.rows.is_none()
            && m <= 12
            && parallel::threads() > 1
            && self.gemm.panel_count() >= 2
            && m * n * self.gemm.k() >= 1 << 16
            && super::gemm_avx2::available()
        {
            // a few output pixels (a head's last layers): tasks split the column panels
            let tasks = self.gemm.panel_count().min(2 * parallel::threads());
            let (ptr, len) = (parallel::SendPtr(out.as_mut_ptr()), out.len());
            parallel::for_each(tasks, |t| {
                let out = super::gemm_avx2::OutPtr {
                    ptr: ptr.get(),
                    len,
                };
                self.run_indirect(input, shape, pad, os, 0, epi, out, Some((t, tasks)));
            });
            return;
        }
        let rows = rows_per_task(m, m * n * self.gemm.k());
        #[cfg(target_arch = "x86_64")]
        if super::gemm_avx2::available() {
            parallel::for_each_chunk(out, rows * n, |t, chunk| {
                let first = t * rows;
                if self.rows.is_some() && self.c_in % 8 == 0 {
                    self.run_dots8(input, shape, pad, os, first, epi, chunk);
                } else if self.rows.is_some() {
                    self.run_dots(input, shape, pad, os, first, epi, chunk);
                } else {
                    let out = super::gemm_avx2::OutPtr::new(chunk);
                    self.run_indirect(input, shape, pad, os, first, epi, out, None);
                }
            });
            return;
        }
        self.run_gathered(input, shape, pad, os, rows, epi, out);
    }

    /// The output pixels of `chunk` (from `first`) as products over input rows read in place
    /// through a table of tap pointers (padding taps read a row of zeros); with `task`, only
    /// that task's column panels (tasks sharing `chunk` write disjoint columns).
    #[cfg(target_arch = "x86_64")]
    #[allow(clippy::too_many_arguments)]
    fn run_indirect(
        &self,
        input: &[f32],
        shape: Shape,
        pad: Padding,
        os: Shape,
        first: usize,
        epi: Epilogue,
        chunk: super::gemm_avx2::OutPtr,
        task: Option<(usize, usize)>,
    ) {
        let (kh, kw) = self.kernel;
        let c = self.c_in;
        let n = self.gemm.n();
        let count = chunk.len / n;
        ZEROS.with(|z| {
            let mut z = z.borrow_mut();
            if z.len() < c {
                z.resize(c, 0.0);
            }
            let zero = z.as_ptr();
            let mut taps = vec![[zero; 12]; kh * kw];
            let mut q = 0;
            while q < count {
                let m = 12.min(count - q);
                self.fill_taps(input, shape, pad, os, first + q, m, zero, &mut taps);
                let e = Epilogue {
                    residual: epi
                        .residual
                        .map(|x| &x[(first + q) * n..(first + q + m) * n]),
                    ..epi
                };
                // SAFETY: AVX2/FMA are present (checked by the caller); every table entry
                // points at `c` values of `input` or of the zero row, both alive here; the
                // chunk's rows `q..q + m` are this call's (its panels' columns, with `task`).
                unsafe {
                    self.gemm
                        .run_indirect(&taps, c, m, 0, e, chunk.skip(q * n), task);
                }
                q += m;
            }
        });
    }

    /// Points `taps[ky·kw + kx][r]` at the input row under output pixel `first + r`, `r < m`
    /// (at `zero` where the tap falls on padding).
    #[cfg(target_arch = "x86_64")]
    #[allow(clippy::too_many_arguments, clippy::needless_range_loop)]
    fn fill_taps(
        &self,
        input: &[f32],
        shape: Shape,
        pad: Padding,
        os: Shape,
        first: usize,
        m: usize,
        zero: *const f32,
        taps: &mut [[*const f32; 12]],
    ) {
        let (kh, kw) = self.kernel;
        let c = self.c_in;
        let (h, w) = (shape.height as isize, shape.width as isize);
        let base = input.as_ptr();
        let (mut oy, mut ox) = (first / os.width, first % os.width);
        for r in 0..m {
            let y0 = (oy * self.stride.0) as isize - pad.top as isize;
            let x0 = (ox * self.stride.1) as isize - pad.left as isize;
            if y0 >= 0 && x0 >= 0 && y0 + kh as isize <= h && x0 + kw as isize <= w {
                // every tap inside the image
                let corner = (y0 * w + x0) as usize * c;
                for ky in 0..kh {
                    for kx in 0..kw {
                        let at = corner + (ky * shape.width + kx) * c;
                        taps[ky * kw + kx][r] = base.wrapping_add(at);
                    }
                }
            } else {
                for ky in 0..kh {
                    let iy = y0 + ky as isize;
                    for kx in 0..kw {
                        let ix = x0 + kx as isize;
                        taps[ky * kw + kx][r] = if iy >= 0 && iy < h && ix >= 0 && ix < w {
                            base.wrapping_add((iy * w + ix) as usize * c)
                        } else {
                            zero
                        };
                    }
                }
            }
            ox += 1;
            if ox == os.width {
                ox = 0;
                oy += 1;
            }
        }
        debug_assert!(input.len() >= shape.len());
    }

    /// Three input channels (the RGB image) and `8·NV` output channels: output rows
    /// `first_row..` of `chunk`, `P` pixels of a row at a time with their `P × NV` output
    /// vectors in registers; per tap, each pixel's three input values are broadcast against
    /// the tap's `3 × NV` weight vectors (taps on padding read zeros). The gathered products
    /// of the general path spend more on the tap table and the 27-long inner loop than on
    /// the multiply-adds at this size.
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    #[allow(clippy::too_many_arguments)]
    unsafe fn rgb_rows<const NV: usize, const P: usize>(
        &self,
        input: &[f32],
        shape: Shape,
        pad: Padding,
        os: Shape,
        first_row: usize,
        epi: Epilogue,
        chunk: &mut [f32],
    ) {
        use std::arch::x86_64::*;
        let packed = self
            .rgb
            .as_deref()
            .expect("rgb layers keep their packed weight");
        let n = NV * 8;
        let (kh, kw) = self.kernel;
        let (sh, sw) = self.stride;
        let (h, w, ow) = (shape.height, shape.width, os.width);
        assert!(self.c_in == RGB_IN && self.gemm.n() == n && packed.len() == kh * kw * RGB_IN * n);
        assert!(input.len() >= h * w * RGB_IN && self.bias.len() == n);
        assert!(chunk.len() % (ow * n) == 0 && (first_row + chunk.len() / (ow * n)) <= os.height);
        if let Some(r) = epi.residual {
            assert!(r.len() >= os.len());
        }
        let (lo1, hi1) = epi.pre.bounds();
        let (lo2, hi2) = epi.post.bounds();
        let (lo1, hi1, lo2, hi2) = (
            _mm256_set1_ps(lo1),
            _mm256_set1_ps(hi1),
            _mm256_set1_ps(lo2),
            _mm256_set1_ps(hi2),
        );
        let bias: [__m256; NV] =
            std::array::from_fn(|v| _mm256_loadu_ps(self.bias.as_ptr().add(v * 8)));
        let zero = [0.0f32; RGB_IN];
        let base = input.as_ptr();
        for r in 0..chunk.len() / (ow * n) {
            let oy = first_row + r;
            let y0 = (oy * sh) as isize - pad.top as isize;
            let mut ox = 0;
            while ox < ow {
                let count = P.min(ow - ox);
                // the bias is added after the sums, as in the general path (same rounding)
                let mut acc = [[_mm256_setzero_ps(); NV]; P];
                for ky in 0..kh {
                    let iy = y0 + ky as isize;
                    if iy < 0 || iy >= h as isize {
                        continue;
                    }
                    let line = base.add(iy as usize * w * RGB_IN);
                    for kx in 0..kw {
                        let px: [*const f32; P] = std::array::from_fn(|p| {
                            let ix = ((ox + p) * sw + kx) as isize - pad.left as isize;
                            if p < count && ix >= 0 && (ix as usize) < w {
                                line.wrapping_add(ix as usize * RGB_IN)
                            } else {
                                zero.as_ptr()
                            }
                        });
                        let wt = packed.as_ptr().add((ky * kw + kx) * RGB_IN * n);
                        for ci in 0..RGB_IN {
                            let wv: [__m256; NV] =
                                std::array::from_fn(|v| _mm256_loadu_ps(wt.add(ci * n + v * 8)));
                            for (acc, &x) in acc.iter_mut().zip(&px) {
                                let x = _mm256_broadcast_ss(&*x.add(ci));
                                for (acc, &wv) in acc.iter_mut().zip(&wv) {
                                    *acc = _mm256_fmadd_ps(x, wv, *acc);
                                }
                            }
                        }
                    }
                }
                for (p, acc) in acc.iter().enumerate().take(count) {
                    let at = (r * ow + ox + p) * n;
                    let q = (oy * ow + ox + p) * n;
                    for (v, &a) in acc.iter().enumerate() {
                        let a = _mm256_add_ps(a, bias[v]);
                        let mut y = _mm256_min_ps(_mm256_max_ps(a, lo1), hi1);
                        if let Some(res) = epi.residual {
                            y = _mm256_add_ps(y, _mm256_loadu_ps(res.as_ptr().add(q + v * 8)));
                            y = _mm256_min_ps(_mm256_max_ps(y, lo2), hi2);
                        }
                        _mm256_storeu_ps(chunk.as_mut_ptr().add(at + v * 8), y);
                    }
                }
                ox += P;
            }
        }
    }

    /// Few output channels, a square `K×K` kernel with stride `S` and `C_in` a multiple of 8
    /// (BlazePose's segmentation head, 8 → 1 at 256×256): output rows `first_row..` of
    /// `chunk`, [`super::gemm_avx2::ROW_PIXELS`] pixels of a row at a time. Vectorised over
    /// pixels rather than output channels: per output channel, eight accumulators (one per
    /// pixel, lanes = 8 input channels) take each kernel row through
    /// [`super::gemm_avx2::row_taps`] (each input column loaded once for all its taps), then
    /// are summed across lanes into the eight pixels' values.
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    #[allow(clippy::too_many_arguments)]
    unsafe fn few_out_rows<const K: usize, const S: usize>(
        &self,
        input: &[f32],
        shape: Shape,
        pad: Padding,
        os: Shape,
        first_row: usize,
        epi: Epilogue,
        chunk: &mut [f32],
    ) {
        use super::gemm_avx2::{hsum8, row_taps, ROW_PIXELS};
        use std::arch::x86_64::*;
        const P: usize = ROW_PIXELS;
        let weight = self
            .rows
            .as_deref()
            .expect("dot layers keep their weight rows");
        let (c, n) = (self.c_in, self.gemm.n());
        let (h, w, ow) = (shape.height, shape.width, os.width);
        assert!(self.kernel == (K, K) && self.stride == (S, S) && c % 8 == 0);
        assert!(input.len() >= h * w * c && weight.len() >= n * K * K * c);
        assert!(chunk.len() % (ow * n) == 0 && (first_row + chunk.len() / (ow * n)) <= os.height);
        if let Some(r) = epi.residual {
            assert!(r.len() >= os.len());
        }
        let (lo1, hi1) = epi.pre.bounds();
        let (lo2, hi2) = epi.post.bounds();
        let zero = [0.0f32; 8];
        let left = pad.left as isize;
        for r in 0..chunk.len() / (ow * n) {
            let oy = first_row + r;
            let y0 = (oy * S) as isize - pad.top as isize;
            let ky_lo = (-y0).max(0) as usize;
            let ky_hi = ((h as isize - y0).max(0) as usize).min(K);
            let mut ox = 0;
            while ox < ow {
                let x0 = (ox * S) as isize - left;
                let inside = x0 >= 0 && x0 as usize + (P - 1) * S + K <= w;
                let count = P.min(ow - ox);
                for o in 0..n {
                    let mut acc = [_mm256_setzero_ps(); P];
                    for ky in ky_lo..ky_hi {
                        let line = input.as_ptr().add((y0 + ky as isize) as usize * w * c);
                        let wrow = weight.as_ptr().add((o * K + ky) * K * c);
                        for c0 in (0..c).step_by(8) {
                            let wk: [__m256; K] =
                                std::array::from_fn(|kx| _mm256_loadu_ps(wrow.add(kx * c + c0)));
                            let line = line.add(c0);
                            if inside {
                                row_taps::<K, S, false>(
                                    &mut acc,
                                    &wk,
                                    line,
                                    x0,
                                    w,
                                    c,
                                    zero.as_ptr(),
                                );
                            } else {
                                row_taps::<K, S, true>(
                                    &mut acc,
                                    &wk,
                                    line,
                                    x0,
                                    w,
                                    c,
                                    zero.as_ptr(),
                                );
                            }
                        }
                    }
                    let sums8 = hsum8(&acc);
                    if n == 1 && count == P {
                        // one output channel: the eight pixels are contiguous
                        let at = r * ow + ox;
                        let q = oy * ow + ox;
                        let b = _mm256_set1_ps(self.bias[0]);
                        let mut y = _mm256_add_ps(sums8, b);
                        y = _mm256_min_ps(
                            _mm256_max_ps(y, _mm256_set1_ps(lo1)),
                            _mm256_set1_ps(hi1),
                        );
                        if let Some(res) = epi.residual {
                            y = _mm256_add_ps(y, _mm256_loadu_ps(res[q..q + P].as_ptr()));
                            let (lo2, hi2) = (_mm256_set1_ps(lo2), _mm256_set1_ps(hi2));
                            y = _mm256_min_ps(_mm256_max_ps(y, lo2), hi2);
                        }
                        _mm256_storeu_ps(chunk[at..at + P].as_mut_ptr(), y);
                        continue;
                    }
                    let mut sums = [0.0f32; P];
                    _mm256_storeu_ps(sums.as_mut_ptr(), sums8);
                    for (p, &sum) in sums.iter().enumerate().take(count) {
                        let q = oy * ow + ox + p;
                        let mut y = (sum + self.bias[o]).max(lo1).min(hi1);
                        if let Some(res) = epi.residual {
                            y = (y + res[q * n + o]).max(lo2).min(hi2);
                        }
                        chunk[(r * ow + ox + p) * n + o] = y;
                    }
                }
                ox += P;
            }
        }
    }

    /// Few output channels with `C_in` a multiple of 8: eight output pixels at a time, each
    /// output channel's eight sums accumulated in vector lanes over the tap table.
    #[cfg(target_arch = "x86_64")]
    #[allow(clippy::too_many_arguments)]
    fn run_dots8(
        &self,
        input: &[f32],
        shape: Shape,
        pad: Padding,
        os: Shape,
        first: usize,
        epi: Epilogue,
        chunk: &mut [f32],
    ) {
        let weight = self
            .rows
            .as_deref()
            .expect("dot layers keep their weight rows");
        let (kh, kw) = self.kernel;
        let (c, n) = (self.c_in, self.gemm.n());
        let count = chunk.len() / n;
        let (lo1, hi1) = epi.pre.bounds();
        let (lo2, hi2) = epi.post.bounds();
        ZEROS.with(|z| {
            let mut z = z.borrow_mut();
            if z.len() < c {
                z.resize(c, 0.0);
            }
            let zero = z.as_ptr();
            let mut taps = vec![[zero; 12]; kh * kw];
            let per_out = kh * kw * c;
            let mut q = 0;
            while q < count {
                let m = 8.min(count - q);
                self.fill_taps(input, shape, pad, os, first + q, m, zero, &mut taps);
                for o in 0..n {
                    let w = &weight[o * per_out..(o + 1) * per_out];
                    // SAFETY: AVX2/FMA are present (checked by the caller); the table points
                    // at `c` values of `input` or of the zero row, and `w` holds `taps · c`.
                    let sums = unsafe { super::gemm_avx2::indirect_dot8(&taps, c, w, m) };
                    for (r, &sum) in sums.iter().enumerate().take(m) {
                        let mut y = (sum + self.bias[o]).max(lo1).min(hi1);
                        if let Some(res) = epi.residual {
                            y = (y + res[(first + q + r) * n + o]).max(lo2).min(hi2);
                        }
                        chunk[(q + r) * n + o] = y;
                    }
                }
                q += m;
            }
        });
    }

    /// Few output channels: each output value is a sum of dot products over the contiguous
    /// in-bounds run of each kernel row (`kw·C_in` values inside the image).
    #[cfg(target_arch = "x86_64")]
    #[allow(clippy::too_many_arguments)]
    fn run_dots(
        &self,
        input: &[f32],
        shape: Shape,
        pad: Padding,
        os: Shape,
        first: usize,
        epi: Epilogue,
        chunk: &mut [f32],
    ) {
        let weight = self
            .rows
            .as_deref()
            .expect("dot layers keep their weight rows");
        let (kh, kw) = self.kernel;
        let c = self.c_in;
        let n = self.gemm.n();
        let (lo1, hi1) = epi.pre.bounds();
        let (lo2, hi2) = epi.post.bounds();
        for (i, px) in chunk.chunks_exact_mut(n).enumerate() {
            let q = first + i;
            let (oy, ox) = (q / os.width, q % os.width);
            let x0 = (ox * self.stride.1) as isize - pad.left as isize;
            let kx_lo = (-x0).max(0) as usize;
            let kx_hi = ((shape.width as isize - x0).max(0) as usize).min(kw);
            for (o, v) in px.iter_mut().enumerate() {
                let mut sum = self.bias[o];
                for ky in 0..kh {
                    let Some(iy) = (oy * self.stride.0 + ky).checked_sub(pad.top) else {
                        continue;
                    };
                    if iy >= shape.height || kx_lo >= kx_hi {
                        continue;
                    }
                    let xs = &input[(iy * shape.width + (x0 + kx_lo as isize) as usize) * c..]
                        [..(kx_hi - kx_lo) * c];
                    let ws = &weight[((o * kh + ky) * kw + kx_lo) * c..][..(kx_hi - kx_lo) * c];
                    // SAFETY: AVX2/FMA are present (checked by the caller); both runs hold
                    // `xs.len()` values.
                    sum += unsafe { super::gemm_avx2::dot(xs.as_ptr(), ws.as_ptr(), xs.len()) };
                }
                let mut y = sum.max(lo1).min(hi1);
                if let Some(r) = epi.residual {
                    y = (y + r[q * n + o]).max(lo2).min(hi2);
                }
                *v = y;
            }
        }
    }

    /// The portable path: gather each block of output pixels' rows, then one product.
    #[allow(clippy::too_many_arguments)]
    fn run_gathered(
        &self,
        input: &[f32],
        shape: Shape,
        pad: Padding,
        os: Shape,
        rows: usize,
        epi: Epilogue,
        out: &mut [f32],
    ) {
        let k = self.gemm.k();
        let n = self.gemm.n();
        let block = (GATHER_FLOATS / k).clamp(12, 480) / 12 * 12;
        parallel::for_each_chunk(out, rows * n, |t, chunk| {
            GATHER.with(|buf| {
                let mut buf = buf.borrow_mut();
                if buf.len() < block * k {
                    buf.resize(block * k, 0.0);
                }
                let first = t * rows;
                let count = chunk.len() / n;
                let mut r = 0;
                while r < count {
                    let rm = block.min(count - r);
                    let rows_buf = &mut buf[..rm * k];
                    self.gather(input, shape, pad, os, first + r, rows_buf);
                    let e = Epilogue {
                        residual: epi
                            .residual
                            .map(|x| &x[(first + r) * n..(first + r + rm) * n]),
                        ..epi
                    };
                    self.gemm
                        .run_serial(rows_buf, k, rm, e, &mut chunk[r * n..(r + rm) * n]);
                    r += rm;
                }
            });
        });
    }

    /// The gathered rows of output pixels `first..first + rows.len() / k`.
    fn gather(
        &self,
        input: &[f32],
        shape: Shape,
        pad: Padding,
        os: Shape,
        first: usize,
        rows: &mut [f32],
    ) {
        let (kh, kw) = self.kernel;
        let c = self.c_in;
        let k = kh * kw * c;
        for (i, row) in rows.chunks_exact_mut(k).enumerate() {
            let q = first + i;
            let (oy, ox) = (q / os.width, q % os.width);
            for ky in 0..kh {
                let taps = &mut row[ky * kw * c..(ky + 1) * kw * c];
                let iy = (oy * self.stride.0 + ky).checked_sub(pad.top);
                let Some(iy) = iy.filter(|&y| y < shape.height) else {
                    taps.fill(0.0);
                    continue;
                };
                for kx in 0..kw {
                    let dst = &mut taps[kx * c..(kx + 1) * c];
                    match (ox * self.stride.1 + kx).checked_sub(pad.left) {
                        Some(ix) if ix < shape.width => {
                            let at = (iy * shape.width + ix) * c;
                            dst.copy_from_slice(&input[at..at + c]);
                        }
                        _ => dst.fill(0.0),
                    }
                }
            }
        }
    }
}

/// One task's share of an RGB first convolution ([`ConvNhwc::rgb_rows`] and the 3×3
/// stride-2 kernels below).
#[cfg(target_arch = "x86_64")]
struct RgbJob<'a> {
    conv: &'a ConvNhwc,
    input: &'a [f32],
    shape: Shape,
    pad: Padding,
    os: Shape,
    first_row: usize,
    epi: Epilogue<'a>,
}

/// [`rgb_k3s2`] with AVX2/FMA.
///
/// # Safety
/// The CPU must have AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn rgb_k3s2_avx2<const NV: usize, const P: usize>(job: &RgbJob, chunk: &mut [f32]) {
    rgb_k3s2::<NV, P>(job, chunk)
}

/// The RGB first convolution for a 3×3 kernel with stride 2 (every BlazePose network's
/// first layer): as [`ConvNhwc::rgb_rows`], but with the kernel and stride known, each
/// group's three input rows are read at fixed offsets from the start of its input columns —
/// every broadcast one load with an immediate offset, no per-tap pointer arithmetic — and a
/// group that reaches into the padding reads a zero-padded copy of its columns instead.
///
/// # Safety
/// The caller's function must enable AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn rgb_k3s2<const NV: usize, const P: usize>(job: &RgbJob, chunk: &mut [f32]) {
    use std::arch::x86_64::*;
    const K: usize = 3;
    const S: usize = 2;
    const C: usize = RGB_IN;
    let conv = job.conv;
    let packed = conv
        .rgb
        .as_deref()
        .expect("rgb layers keep their packed weight");
    let n = NV * 8;
    let (h, w, ow) = (job.shape.height, job.shape.width, job.os.width);
    let span = ((P - 1) * S + K) * C;
    let mut buf = [0.0f32; 96];
    assert!(span <= buf.len());
    assert!(conv.kernel == (K, K) && conv.stride == (S, S) && conv.c_in == C);
    assert!(conv.gemm.n() == n && packed.len() == K * K * C * n && conv.bias.len() == n);
    assert!(job.input.len() >= h * w * C);
    assert!(chunk.len() % (ow * n) == 0 && job.first_row + chunk.len() / (ow * n) <= job.os.height);
    if let Some(r) = job.epi.residual {
        assert!(r.len() >= job.os.len());
    }
    let (lo1, hi1) = job.epi.pre.bounds();
    let (lo2, hi2) = job.epi.post.bounds();
    let (lo1, hi1, lo2, hi2) = (
        _mm256_set1_ps(lo1),
        _mm256_set1_ps(hi1),
        _mm256_set1_ps(lo2),
        _mm256_set1_ps(hi2),
    );
    let bias: [__m256; NV] =
        std::array::from_fn(|v| _mm256_loadu_ps(conv.bias.as_ptr().add(v * 8)));
    let base = job.input.as_ptr();
    let left = job.pad.left as isize;
    for r in 0..chunk.len() / (ow * n) {
        let oy = job.first_row + r;
        let y0 = (oy * S) as isize - job.pad.top as isize;
        let mut ox = 0;
        while ox < ow {
            let count = P.min(ow - ox);
            let x0 = (ox * S) as isize - left;
            let inside = x0 >= 0 && x0 as usize + (P - 1) * S + K <= w;
            // the bias is added after the sums, as in the general path (same rounding)
            let mut acc = [[_mm256_setzero_ps(); NV]; P];
            for ky in 0..K {
                let iy = y0 + ky as isize;
                if iy < 0 || iy >= h as isize {
                    continue;
                }
                let line = base.add(iy as usize * w * C);
                let seg = if inside {
                    line.add(x0 as usize * C)
                } else {
                    for (j, v) in buf[..span].iter_mut().enumerate() {
                        let ix = x0 + (j / C) as isize;
                        *v = if ix >= 0 && (ix as usize) < w {
                            *line.add(ix as usize * C + j % C)
                        } else {
                            0.0
                        };
                    }
                    buf.as_ptr()
                };
                let wt = packed.as_ptr().add(ky * K * C * n);
                for kx in 0..K {
                    for ci in 0..C {
                        let wv: [__m256; NV] = std::array::from_fn(|v| {
                            _mm256_loadu_ps(wt.add((kx * C + ci) * n + v * 8))
                        });
                        for (p, acc) in acc.iter_mut().enumerate() {
                            let x = _mm256_broadcast_ss(&*seg.add((p * S + kx) * C + ci));
                            for (acc, &wv) in acc.iter_mut().zip(&wv) {
                                *acc = _mm256_fmadd_ps(x, wv, *acc);
                            }
                        }
                    }
                }
            }
            for (p, acc) in acc.iter().enumerate().take(count) {
                let at = (r * ow + ox + p) * n;
                let q = (oy * ow + ox + p) * n;
                for (v, &a) in acc.iter().enumerate() {
                    let a = _mm256_add_ps(a, bias[v]);
                    let mut y = _mm256_min_ps(_mm256_max_ps(a, lo1), hi1);
                    if let Some(res) = job.epi.residual {
                        y = _mm256_add_ps(y, _mm256_loadu_ps(res.as_ptr().add(q + v * 8)));
                        y = _mm256_min_ps(_mm256_max_ps(y, lo2), hi2);
                    }
                    _mm256_storeu_ps(chunk.as_mut_ptr().add(at + v * 8), y);
                }
            }
            ox += P;
        }
    }
}

/// [`rgb_k3s2`] compiled with AVX-512VL, whose 32 vector registers hold twice the pixels
/// per group (Rust 1.89 or newer only, `lhmpp_bf16_intrinsics`).
#[cfg(all(target_arch = "x86_64", lhmpp_bf16_intrinsics))]
#[allow(clippy::incompatible_msrv)]
mod rgb_avx512 {
    use super::{rgb_k3s2, RgbJob};

    /// Whether the CPU has AVX-512F and VL (and AVX2 and FMA).
    pub(super) fn available() -> bool {
        std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512vl")
            && crate::kernels::gemm_avx2::available()
    }

    /// [`rgb_k3s2`] with the wider register file.
    ///
    /// # Safety
    /// The CPU must have AVX-512F/VL, AVX2 and FMA.
    #[target_feature(enable = "avx2,fma,avx512f,avx512vl")]
    pub(super) unsafe fn rows<const NV: usize, const P: usize>(job: &RgbJob, chunk: &mut [f32]) {
        rgb_k3s2::<NV, P>(job, chunk)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::nhwc::Activation;

    fn values(n: usize, seed: u32) -> Vec<f32> {
        (0..n)
            .map(|i| (((i as u32).wrapping_mul(seed * 2 + 7919) % 1999) as f32 / 999.5) - 1.0)
            .collect()
    }

    /// Direct summation over the definition.
    #[allow(clippy::too_many_arguments)]
    fn reference(
        x: &[f32],
        s: Shape,
        w: &[f32],
        b: &[f32],
        c_out: usize,
        (kh, kw): (usize, usize),
        (sh, sw): (usize, usize),
        pad: Padding,
    ) -> (Vec<f32>, Shape) {
        let oh = Padding::out_side(s.height, pad.top, pad.bottom, kh, sh);
        let ow = Padding::out_side(s.width, pad.left, pad.right, kw, sw);
        let mut out = vec![0.0; oh * ow * c_out];
        for oy in 0..oh {
            for ox in 0..ow {
                for o in 0..c_out {
                    let mut acc = b[o] as f64;
                    for ky in 0..kh {
                        for kx in 0..kw {
                            let iy = (oy * sh + ky) as isize - pad.top as isize;
                            let ix = (ox * sw + kx) as isize - pad.left as isize;
                            if iy < 0 || ix < 0 || iy >= s.height as isize || ix >= s.width as isize
                            {
                                continue;
                            }
                            for c in 0..s.channels {
                                let xv =
                                    x[((iy as usize) * s.width + ix as usize) * s.channels + c];
                                let wv = w[((o * kh + ky) * kw + kx) * s.channels + c];
                                acc += xv as f64 * wv as f64;
                            }
                        }
                    }
                    out[(oy * ow + ox) * c_out + o] = acc as f32;
                }
            }
        }
        (out, Shape::new(oh, ow, c_out))
    }

    /// The AVX2 build of the 3×3 stride-2 RGB kernel (what CPUs without AVX-512 run; `run`
    /// takes the AVX-512 one where it can) against the direct summation.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn rgb_kernel_without_avx512_matches_direct_summation() {
        if !crate::kernels::gemm_avx2::available() {
            return;
        }
        for (h, w, co, pad) in [
            (9, 37, 24, Padding::uniform(1)),
            (
                8,
                20,
                16,
                Padding {
                    top: 0,
                    left: 0,
                    bottom: 1,
                    right: 1,
                },
            ),
        ] {
            let s = Shape::new(h, w, 3);
            let (x, wt, b) = (values(s.len(), 5), values(co * 27, 6), values(co, 7));
            let conv = ConvNhwc::new(&wt, &b, co, (3, 3), 3, (2, 2));
            let (want, os) = reference(&x, s, &wt, &b, co, (3, 3), (2, 2), pad);
            let mut got = vec![f32::NAN; os.len()];
            let job = RgbJob {
                conv: &conv,
                input: &x,
                shape: s,
                pad,
                os,
                first_row: 0,
                epi: Epilogue::default(),
            };
            // SAFETY: the CPU has AVX2 and FMA (checked above).
            unsafe {
                match co / 8 {
                    2 => rgb_k3s2_avx2::<2, 6>(&job, &mut got),
                    _ => rgb_k3s2_avx2::<3, 4>(&job, &mut got),
                }
            }
            let d = got
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f32::max);
            assert!(d < 1e-4, "{h}x{w}->{co}: {d}");
        }
    }

    #[test]
    fn convolutions_match_direct_summation() {
        let cases = [
            // (h, w, c_in, c_out, kernel, stride, pad)
            (9, 11, 3, 24, (3, 3), (2, 2), Padding::uniform(1)),
            (7, 6, 8, 1, (3, 3), (1, 1), Padding::uniform(1)),
            (2, 2, 20, 13, (2, 2), (1, 1), Padding::default()),
            (5, 5, 16, 40, (1, 1), (1, 1), Padding::default()),
            (
                6,
                7,
                5,
                9,
                (1, 1),
                (2, 2),
                Padding {
                    top: 0,
                    left: 1,
                    bottom: 1,
                    right: 0,
                },
            ),
            (40, 31, 4, 18, (5, 5), (2, 2), Padding::uniform(2)),
            (13, 17, 8, 1, (3, 3), (1, 1), Padding::uniform(1)),
            (
                11,
                9,
                24,
                3,
                (3, 3),
                (2, 2),
                Padding {
                    top: 0,
                    left: 1,
                    bottom: 1,
                    right: 0,
                },
            ),
            (6, 5, 3, 30, (3, 3), (1, 1), Padding::uniform(1)),
            (5, 27, 16, 2, (3, 3), (1, 1), Padding::uniform(1)),
            (
                17,
                20,
                3,
                24,
                (3, 3),
                (2, 2),
                Padding {
                    top: 0,
                    left: 0,
                    bottom: 1,
                    right: 1,
                },
            ),
            (8, 13, 3, 8, (5, 5), (1, 1), Padding::uniform(2)),
            (10, 9, 3, 32, (3, 3), (2, 2), Padding::uniform(1)),
            (6, 41, 3, 16, (3, 3), (2, 2), Padding::uniform(1)),
            (
                9,
                50,
                3,
                8,
                (3, 3),
                (2, 2),
                Padding {
                    top: 0,
                    left: 0,
                    bottom: 1,
                    right: 1,
                },
            ),
            (5, 38, 3, 24, (3, 3), (2, 2), Padding::uniform(1)),
            (7, 11, 3, 16, (2, 3), (1, 2), Padding::uniform(1)),
            (2, 2, 288, 195, (2, 2), (1, 1), Padding::default()),
            (3, 4, 40, 72, (2, 2), (1, 1), Padding::default()),
            (
                9,
                21,
                8,
                3,
                (3, 3),
                (2, 2),
                Padding {
                    top: 0,
                    left: 1,
                    bottom: 1,
                    right: 0,
                },
            ),
        ];
        for (h, w, ci, co, k, st, pad) in cases {
            let s = Shape::new(h, w, ci);
            let x = values(s.len(), 1);
            let wt = values(co * k.0 * k.1 * ci, 2);
            let b = values(co, 3);
            let conv = ConvNhwc::new(&wt, &b, co, k, ci, st);
            let (want, os) = reference(&x, s, &wt, &b, co, k, st, pad);
            assert_eq!(conv.out_shape(s, pad), os);
            let mut got = vec![f32::NAN; os.len()];
            conv.run(&x, s, pad, Epilogue::default(), &mut got);
            let d = got
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f32::max);
            assert!(d < 1e-4, "{h}x{w}x{ci}->{co} k{k:?} s{st:?}: {d}");
            let res = values(os.len(), 4);
            let epi = Epilogue {
                pre: Activation::Relu6,
                residual: Some(&res),
                post: Activation::Relu,
            };
            conv.run(&x, s, pad, epi, &mut got);
            for i in 0..os.len() {
                let v = (want[i].clamp(0.0, 6.0) + res[i]).max(0.0);
                assert!((got[i] - v).abs() < 1e-4, "epilogue at {i}");
            }
        }
    }
}
