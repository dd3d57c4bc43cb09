//! Depthwise 2-D convolution of one channels-last image (each channel with its own `kh×kw`
//! filter; depth multiplier 1), with a stride, explicit zero padding and the fused bias,
//! activations and residual of [`Epilogue`].
//!
//! Channels are processed in blocks of 16 (then 8, then single channels), so every tap is a
//! vector multiply-add of contiguous input and weight values. Square 3×3 and 5×5 filters with
//! stride 1 or 2 (all of BlazePose's) take a row kernel with AVX2/FMA (16-channel blocks with
//! AVX-512 where the compiler and CPU have it): eight output pixels of a row at a time, each
//! input column under them loaded once for every tap that reads it, padding columns read as
//! zeros (no separate border path). Other filters take an eight-pixel AVX2 kernel inside the
//! image and a checked path at the border; without AVX2, portable loops. Output rows run in
//! parallel; maps of few rows split their channels between the threads instead.

use super::nhwc::{Epilogue, Padding, Shape};
use super::parallel;
use crate::simd::simd_dispatch;

/// Multiply-adds below which a layer runs as one rayon task.
const MIN_TASK_MACS: usize = 1 << 17;

/// Output rows up to which a layer on several threads splits channels rather than rows.
#[cfg(target_arch = "x86_64")]
const CHANNEL_SPLIT_MAX_ROWS: usize = 8;

/// Multiply-adds below which a layer of few rows runs as one task.
#[cfg(target_arch = "x86_64")]
const MIN_CHANNEL_SPLIT_MACS: usize = 1 << 16;

/// A packed depthwise convolution.
#[derive(Debug, Clone)]
pub struct Depthwise {
    /// `[kh·kw][C]`, tap major.
    weight: Vec<f32>,
    bias: Vec<f32>,
    kernel: (usize, usize),
    stride: (usize, usize),
    channels: usize,
}

impl Depthwise {
    /// Packs TFLite's `weight [1][kh][kw][C]` and `bias [C]`; `stride` is (rows, columns).
    pub fn new(
        weight: &[f32],
        bias: &[f32],
        kernel: (usize, usize),
        channels: usize,
        stride: (usize, usize),
    ) -> Self {
        assert_eq!(
            weight.len(),
            kernel.0 * kernel.1 * channels,
            "depthwise: weight length"
        );
        assert_eq!(bias.len(), channels, "depthwise: bias length");
        assert!(stride.0 > 0 && stride.1 > 0, "depthwise: zero stride");
        Self {
            weight: weight.to_vec(),
            bias: bias.to_vec(),
            kernel,
            stride,
            channels,
        }
    }

    /// Channels.
    pub fn channels(&self) -> usize {
        self.channels
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
            self.channels,
        )
    }

    /// `out = epi(depthwise(input padded by pad) + bias)`.
    pub fn run(&self, input: &[f32], shape: Shape, pad: Padding, epi: Epilogue, out: &mut [f32]) {
        assert_eq!(shape.channels, self.channels, "depthwise: input channels");
        assert_eq!(input.len(), shape.len(), "depthwise: input length");
        let os = self.out_shape(shape, pad);
        assert_eq!(out.len(), os.len(), "depthwise: output length");
        if let Some(r) = epi.residual {
            assert_eq!(r.len(), os.len(), "depthwise: residual length");
        }
        if os.is_empty() {
            return;
        }
        let row = os.width * os.channels;
        let macs = os.len() * self.kernel.0 * self.kernel.1;
        #[cfg(target_arch = "x86_64")]
        if self.channels % 8 == 0
            && os.height <= CHANNEL_SPLIT_MAX_ROWS
            && parallel::threads() > 1
            && self.channels / 8 >= 2 * parallel::threads()
            && macs >= MIN_CHANNEL_SPLIT_MACS
            && avx2::square(self).is_some()
            && super::gemm_avx2::available()
        {
            // few rows (7×7 and smaller maps): tasks split the 8-channel blocks instead
            let tasks = 2 * parallel::threads();
            let blocks = self.channels / 8;
            let (ptr, len) = (parallel::SendPtr(out.as_mut_ptr()), out.len());
            let job = Rows {
                dw: self,
                input,
                shape,
                pad,
                out_shape: os,
                first: 0,
            };
            parallel::for_each(tasks, |t| {
                let channels = t * blocks / tasks * 8..(t + 1) * blocks / tasks * 8;
                let out = super::gemm_avx2::OutPtr {
                    ptr: ptr.get(),
                    len,
                };
                // SAFETY: the CPU has AVX2 and FMA (checked above); this task alone writes
                // `channels` of the output.
                unsafe { avx2::rows_square(&job, epi, out, channels) };
            });
            return;
        }
        let rows = parallel::items_per_task(os.height, macs, MIN_TASK_MACS, 1);
        parallel::for_each_chunk(out, rows * row, |t, chunk| {
            let first = t * rows;
            let job = Rows {
                dw: self,
                input,
                shape,
                pad,
                out_shape: os,
                first,
            };
            let epi = Epilogue {
                residual: epi
                    .residual
                    .map(|r| &r[first * row..first * row + chunk.len()]),
                ..epi
            };
            run_rows_fast(&job, epi, chunk);
        });
    }
}

/// Output rows `first..` of one layer call.
struct Rows<'a> {
    dw: &'a Depthwise,
    input: &'a [f32],
    shape: Shape,
    pad: Padding,
    out_shape: Shape,
    first: usize,
}

simd_dispatch! {
    avx2_fma;
    fn run_rows[](job: &Rows, epi: Epilogue, out: &mut [f32], skip_channels: usize) = run_rows_skipping;
}

#[inline(always)]
#[cfg(test)]
fn run_rows_portable(job: &Rows, epi: Epilogue, out: &mut [f32]) {
    run_rows_skipping(job, epi, out, 0);
}

/// The job's rows on the portable loops, channels `skip_channels..` only (the caller computes
/// the others).
#[inline(always)]
fn run_rows_skipping(job: &Rows, epi: Epilogue, out: &mut [f32], skip_channels: usize) {
    match job.dw.kernel {
        (3, 3) => blocks::<3, 9>(job, epi, out, skip_channels),
        (5, 5) => blocks::<5, 25>(job, epi, out, skip_channels),
        _ => blocks::<0, 0>(job, epi, out, skip_channels),
    }
}

/// The job's rows: whole 8-channel blocks with the AVX2/FMA kernel where the CPU has it, the
/// remaining channels (or all, elsewhere) on the portable loops.
fn run_rows_fast(job: &Rows, epi: Epilogue, out: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if super::gemm_avx2::available() {
        let skip = job.dw.channels / 8 * 8;
        // SAFETY: the CPU has AVX2 and FMA (checked above).
        unsafe {
            if avx2::square(job.dw).is_some() {
                let out = super::gemm_avx2::OutPtr::new(out);
                avx2::rows_square(job, epi, out, 0..skip);
            } else {
                avx2::rows(job, epi, out);
            }
        }
        run_rows(job, epi, out, skip);
        return;
    }
    run_rows(job, epi, out, 0);
}

/// All channel blocks of the job's rows. `K` is the square kernel side the register path is
/// compiled for (`T = K²`), 0 for the generic path.
#[inline(always)]
fn blocks<const K: usize, const T: usize>(job: &Rows, epi: Epilogue, out: &mut [f32], skip: usize) {
    const { assert!(T == K * K) };
    let c = job.dw.channels;
    let mut c0 = skip;
    while c0 + 16 <= c {
        block::<K, T, 16>(job, c0, epi, out);
        c0 += 16;
    }
    while c0 + 8 <= c {
        block::<K, T, 8>(job, c0, epi, out);
        c0 += 8;
    }
    while c0 < c {
        block::<K, T, 1>(job, c0, epi, out);
        c0 += 1;
    }
}

/// Channels `c0..c0 + L` of the job's rows: the interior of each row (windows inside the
/// image, `K > 0`) four output pixels at a time with the taps in registers, the rest through
/// the checked path.
#[inline(always)]
fn block<const K: usize, const T: usize, const L: usize>(
    job: &Rows,
    c0: usize,
    epi: Epilogue,
    out: &mut [f32],
) {
    let dw = job.dw;
    let (c, (kh, kw), sw) = (dw.channels, dw.kernel, dw.stride.1);
    let (h, w) = (job.shape.height, job.shape.width);
    let ow = job.out_shape.width;
    let bias: [f32; L] = dw.bias[c0..c0 + L].try_into().unwrap();
    // The register copy of this block's taps (used when K > 0, i.e. kh = kw = K).
    let mut taps = [[0.0f32; L]; T];
    for (t, tap) in taps.iter_mut().enumerate() {
        *tap = dw.weight[t * c + c0..t * c + c0 + L].try_into().unwrap();
    }
    // Output columns whose window lies inside the image.
    let ox_lo = job.pad.left.div_ceil(sw).min(ow);
    let ox_hi = if w + job.pad.left >= kw {
        ((w + job.pad.left - kw) / sw + 1).min(ow).max(ox_lo)
    } else {
        ox_lo
    };
    let rows = out.len() / (ow * c);
    for r in 0..rows {
        let oy = job.first + r;
        let y0 = (oy * dw.stride.0) as isize - job.pad.top as isize;
        let inside = K > 0 && y0 >= 0 && y0 as usize + kh <= h;
        let (lo, hi) = if inside { (ox_lo, ox_hi) } else { (ow, ow) };
        let out_row = &mut out[r * ow * c..(r + 1) * ow * c];
        let res_row = epi.residual.map(|x| &x[r * ow * c..(r + 1) * ow * c]);
        for ox in (0..lo).chain(hi..ow) {
            let acc = border_pixel::<L>(job, c0, bias, y0, ox);
            store::<L>(&acc, epi, res_row, ox * c + c0, out_row);
        }
        if lo < hi {
            let line0 = (y0 as usize * w) * c + c0;
            let mut ox = lo;
            while ox + 4 <= hi {
                let acc = interior::<K, T, L, 4>(job, &taps, bias, line0, ox);
                for (p, acc) in acc.iter().enumerate() {
                    store::<L>(acc, epi, res_row, (ox + p) * c + c0, out_row);
                }
                ox += 4;
            }
            while ox < hi {
                let [acc] = interior::<K, T, L, 1>(job, &taps, bias, line0, ox);
                store::<L>(&acc, epi, res_row, ox * c + c0, out_row);
                ox += 1;
            }
        }
    }
}

/// Output pixels `ox..ox + P` of a row whose windows lie inside the image; `line0` is the
/// offset of the window's top row plus `c0`.
#[inline(always)]
fn interior<const K: usize, const T: usize, const L: usize, const P: usize>(
    job: &Rows,
    taps: &[[f32; L]; T],
    bias: [f32; L],
    line0: usize,
    ox: usize,
) -> [[f32; L]; P] {
    let (c, w, sw, left) = (
        job.dw.channels,
        job.shape.width,
        job.dw.stride.1,
        job.pad.left,
    );
    let mut acc = [bias; P];
    for ky in 0..K {
        let line = line0 + ky * w * c;
        for kx in 0..K {
            for (p, acc) in acc.iter_mut().enumerate() {
                let at = line + ((ox + p) * sw + kx - left) * c;
                let x: &[f32; L] = job.input[at..at + L].try_into().unwrap();
                madd(acc, x, &taps[ky * K + kx]);
            }
        }
    }
    acc
}

/// One output pixel through the bounds-checked path (any kernel).
#[inline(always)]
fn border_pixel<const L: usize>(
    job: &Rows,
    c0: usize,
    bias: [f32; L],
    y0: isize,
    ox: usize,
) -> [f32; L] {
    let dw = job.dw;
    let (c, (kh, kw)) = (dw.channels, dw.kernel);
    let (h, w) = (job.shape.height as isize, job.shape.width as isize);
    let x0 = (ox * dw.stride.1) as isize - job.pad.left as isize;
    let mut acc = bias;
    for ky in 0..kh {
        let iy = y0 + ky as isize;
        if iy < 0 || iy >= h {
            continue;
        }
        for kx in 0..kw {
            let ix = x0 + kx as isize;
            if ix < 0 || ix >= w {
                continue;
            }
            let at = (iy as usize * w as usize + ix as usize) * c + c0;
            let x: &[f32; L] = job.input[at..at + L].try_into().unwrap();
            let t = (ky * kw + kx) * c + c0;
            let wv: &[f32; L] = dw.weight[t..t + L].try_into().unwrap();
            madd(&mut acc, x, wv);
        }
    }
    acc
}

/// Writes one pixel's block through the epilogue at `at` of the output row.
#[inline(always)]
fn store<const L: usize>(
    acc: &[f32; L],
    epi: Epilogue,
    res_row: Option<&[f32]>,
    at: usize,
    out_row: &mut [f32],
) {
    let (lo1, hi1) = epi.pre.bounds();
    let dst: &mut [f32; L] = (&mut out_row[at..at + L]).try_into().unwrap();
    match res_row {
        Some(res) => {
            let (lo2, hi2) = epi.post.bounds();
            let res: &[f32; L] = res[at..at + L].try_into().unwrap();
            for ((d, &a), &r) in dst.iter_mut().zip(acc).zip(res) {
                *d = (a.max(lo1).min(hi1) + r).max(lo2).min(hi2);
            }
        }
        None => {
            for (d, &a) in dst.iter_mut().zip(acc) {
                *d = a.max(lo1).min(hi1);
            }
        }
    }
}

/// `acc += x · w`, lane by lane.
#[inline(always)]
fn madd<const L: usize>(acc: &mut [f32; L], x: &[f32; L], w: &[f32; L]) {
    for ((a, &x), &w) in acc.iter_mut().zip(x).zip(w) {
        *a = x.mul_add(w, *a);
    }
}

/// Whole 8-channel blocks with AVX2/FMA intrinsics: eight output pixels at a time where their
/// windows lie inside the image, each tap's weights loaded once for the eight.
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use super::{Epilogue, Rows};
    use crate::kernels::gemm_avx2::{row_taps, OutPtr, ROW_PIXELS};

    /// The (kernel side, stride) of the filters [`rows_square`] takes: 3×3 and 5×5, stride 1
    /// or 2 in both directions.
    pub(super) fn square(dw: &super::Depthwise) -> Option<(usize, usize)> {
        match (dw.kernel, dw.stride) {
            ((k @ (3 | 5), kw), (s @ (1 | 2), sw)) if kw == k && sw == s => Some((k, s)),
            _ => None,
        }
    }

    /// [`rows_k`] for the job's filter ([`square`] must accept it).
    ///
    /// # Safety
    /// As [`rows_k`].
    pub(super) unsafe fn rows_square(
        job: &Rows,
        epi: Epilogue,
        out: OutPtr,
        mut channels: std::ops::Range<usize>,
    ) {
        #[cfg(lhmpp_bf16_intrinsics)]
        if super::avx512::available() {
            // whole 16-channel blocks with AVX-512, a last 8 with AVX2
            let wide = channels.start..channels.start + channels.len() / 16 * 16;
            if !wide.is_empty() {
                let ch = wide.clone();
                match square(job.dw) {
                    Some((3, 1)) => super::avx512::rows_k::<3, 1>(job, epi, out, ch),
                    Some((3, 2)) => super::avx512::rows_k::<3, 2>(job, epi, out, ch),
                    Some((5, 1)) => super::avx512::rows_k::<5, 1>(job, epi, out, ch),
                    Some((5, 2)) => super::avx512::rows_k::<5, 2>(job, epi, out, ch),
                    _ => panic!("depthwise: no square kernel for this filter"),
                }
            }
            channels = wide.end..channels.end;
            if channels.is_empty() {
                return;
            }
        }
        match square(job.dw) {
            Some((3, 1)) => rows_k::<3, 1>(job, epi, out, channels),
            Some((3, 2)) => rows_k::<3, 2>(job, epi, out, channels),
            Some((5, 1)) => rows_k::<5, 1>(job, epi, out, channels),
            Some((5, 2)) => rows_k::<5, 2>(job, epi, out, channels),
            _ => panic!("depthwise: no square kernel for this filter"),
        }
    }

    /// Square `K×K` filters with stride `S` in both directions, channels `channels` (a range
    /// of multiples of 8 below `C / 8 · 8`), written through `out` (the job's rows): along
    /// each output row [`ROW_PIXELS`] output pixels at a time, for each 8-channel block (so
    /// that the cache lines under a group are used whole before moving on), each
    /// kernel row through [`row_taps`] (every input column loaded once for all the taps that
    /// read it). Groups whose columns lie inside the image skip the bounds checks; the others
    /// read zeros for the padding columns, and rows off the image are skipped.
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA; no one else may write `out`'s `channels` meanwhile.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn rows_k<const K: usize, const S: usize>(
        job: &Rows,
        epi: Epilogue,
        out: OutPtr,
        channels: std::ops::Range<usize>,
    ) {
        const P: usize = ROW_PIXELS;
        let dw = job.dw;
        let c = dw.channels;
        let (h, w) = (job.shape.height, job.shape.width);
        let ow = job.out_shape.width;
        let left = job.pad.left as isize;
        assert!(dw.kernel == (K, K) && dw.stride == (S, S));
        assert!(job.input.len() >= h * w * c && dw.weight.len() >= K * K * c);
        assert!(dw.bias.len() >= c && out.len % (ow * c) == 0);
        assert!(channels.start % 8 == 0 && channels.end % 8 == 0 && channels.end <= c);
        assert!(epi.residual.is_none_or(|r| r.len() >= out.len));
        let rows = out.len / (ow * c);
        let (lo1, hi1) = epi.pre.bounds();
        let (lo2, hi2) = epi.post.bounds();
        let (lo1, hi1, lo2, hi2) = (
            _mm256_set1_ps(lo1),
            _mm256_set1_ps(hi1),
            _mm256_set1_ps(lo2),
            _mm256_set1_ps(hi2),
        );
        let zero = [0.0f32; 8];
        let input = job.input.as_ptr();
        for r in 0..rows {
            let oy = job.first + r;
            let y0 = (oy * S) as isize - job.pad.top as isize;
            let ky_lo = (-y0).max(0) as usize;
            let ky_hi = ((h as isize - y0).max(0) as usize).min(K);
            let out_row = out.ptr.add(r * ow * c);
            let res_row = epi.residual.map(|x| x.as_ptr().add(r * ow * c));
            let mut ox = 0;
            while ox < ow {
                let x0 = (ox * S) as isize - left;
                let inside = x0 >= 0 && x0 as usize + (P - 1) * S + K <= w;
                for c0 in channels.clone().step_by(8) {
                    let bias = _mm256_loadu_ps(dw.bias.as_ptr().add(c0));
                    let wts = dw.weight.as_ptr().add(c0);
                    let mut acc = [bias; P];
                    for ky in ky_lo..ky_hi {
                        let line = input.add((y0 + ky as isize) as usize * w * c + c0);
                        let wk: [__m256; K] =
                            std::array::from_fn(|kx| _mm256_loadu_ps(wts.add((ky * K + kx) * c)));
                        if inside {
                            row_taps::<K, S, false>(&mut acc, &wk, line, x0, w, c, zero.as_ptr());
                        } else {
                            row_taps::<K, S, true>(&mut acc, &wk, line, x0, w, c, zero.as_ptr());
                        }
                    }
                    for (p, &a) in acc.iter().enumerate().take(ow - ox) {
                        let at = (ox + p) * c + c0;
                        let mut v = _mm256_min_ps(_mm256_max_ps(a, lo1), hi1);
                        if let Some(res) = res_row {
                            v = _mm256_add_ps(v, _mm256_loadu_ps(res.add(at)));
                            v = _mm256_min_ps(_mm256_max_ps(v, lo2), hi2);
                        }
                        _mm256_storeu_ps(out_row.add(at), v);
                    }
                }
                ox += P;
            }
        }
    }

    /// Every pixel of the job's rows, channels `0..C / 8 · 8`: windows inside the image eight
    /// pixels at a time, the others one at a time over their in-bounds taps.
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn rows(job: &Rows, epi: Epilogue, out: &mut [f32]) {
        let dw = job.dw;
        let (c, (kh, kw), (sh, sw)) = (dw.channels, dw.kernel, dw.stride);
        let (h, w) = (job.shape.height, job.shape.width);
        let ow = job.out_shape.width;
        let left = job.pad.left;
        let ox_lo = left.div_ceil(sw).min(ow);
        let ox_hi = if w + left >= kw {
            ((w + left - kw) / sw + 1).min(ow).max(ox_lo)
        } else {
            ox_lo
        };
        let rows = out.len() / (ow * c);
        assert!(job.input.len() >= h * w * c && dw.weight.len() >= kh * kw * c);
        assert!(epi.residual.is_none_or(|r| r.len() >= out.len()));
        let (lo1, hi1) = epi.pre.bounds();
        let (lo2, hi2) = epi.post.bounds();
        let (lo1, hi1, lo2, hi2) = (
            _mm256_set1_ps(lo1),
            _mm256_set1_ps(hi1),
            _mm256_set1_ps(lo2),
            _mm256_set1_ps(hi2),
        );
        let input = job.input.as_ptr();
        for r in 0..rows {
            let oy = job.first + r;
            let y0 = (oy * sh) as isize - job.pad.top as isize;
            let ky_lo = (-y0).max(0) as usize;
            let ky_hi = ((h as isize - y0).max(0) as usize).min(kh);
            let inside = ky_lo == 0 && ky_hi == kh;
            let out_row = out[r * ow * c..(r + 1) * ow * c].as_mut_ptr();
            let res_row = epi.residual.map(|x| x[r * ow * c..].as_ptr());
            let store = |at: usize, acc: __m256| {
                let mut v = _mm256_min_ps(_mm256_max_ps(acc, lo1), hi1);
                if let Some(res) = res_row {
                    v = _mm256_add_ps(v, _mm256_loadu_ps(res.add(at)));
                    v = _mm256_min_ps(_mm256_max_ps(v, lo2), hi2);
                }
                _mm256_storeu_ps(out_row.add(at), v);
            };
            for c0 in (0..c / 8 * 8).step_by(8) {
                let bias = _mm256_loadu_ps(dw.bias.as_ptr().add(c0));
                let wts = dw.weight.as_ptr().add(c0);
                let mut ox = 0;
                while ox < ow {
                    if inside && ox >= ox_lo && ox + 8 <= ox_hi {
                        // eight pixels, every tap inside the image
                        let mut acc = [bias; 8];
                        for ky in 0..kh {
                            let line = input.add((y0 as usize + ky) * w * c + c0);
                            for kx in 0..kw {
                                let wv = _mm256_loadu_ps(wts.add((ky * kw + kx) * c));
                                let x0 = line.add((ox * sw + kx - left) * c);
                                for (i, acc) in acc.iter_mut().enumerate() {
                                    let x = _mm256_loadu_ps(x0.add(i * sw * c));
                                    *acc = _mm256_fmadd_ps(x, wv, *acc);
                                }
                            }
                        }
                        for (i, &acc) in acc.iter().enumerate() {
                            store((ox + i) * c + c0, acc);
                        }
                        ox += 8;
                        continue;
                    }
                    // one pixel over its in-bounds taps
                    let x0 = (ox * sw) as isize - left as isize;
                    let kx_lo = (-x0).max(0) as usize;
                    let kx_hi = ((w as isize - x0).max(0) as usize).min(kw);
                    let mut acc = bias;
                    for ky in ky_lo..ky_hi {
                        let line = input.add((y0 + ky as isize) as usize * w * c + c0);
                        for kx in kx_lo..kx_hi {
                            let wv = _mm256_loadu_ps(wts.add((ky * kw + kx) * c));
                            let x = _mm256_loadu_ps(line.add((x0 + kx as isize) as usize * c));
                            acc = _mm256_fmadd_ps(x, wv, acc);
                        }
                    }
                    store(ox * c + c0, acc);
                    ox += 1;
                }
            }
        }
    }
}

/// [`avx2::rows_k`] on 16-channel blocks with AVX-512 (half the instructions per
/// multiply-add; compiled with Rust 1.89 or newer only, `lhmpp_bf16_intrinsics`).
#[cfg(all(target_arch = "x86_64", lhmpp_bf16_intrinsics))]
#[allow(clippy::incompatible_msrv)]
mod avx512 {
    use std::arch::x86_64::*;

    use super::{Epilogue, Rows};
    use crate::kernels::gemm_avx2::{OutPtr, ROW_PIXELS};

    /// Whether the CPU has AVX-512F.
    pub(super) fn available() -> bool {
        std::arch::is_x86_feature_detected!("avx512f")
    }

    /// [`crate::kernels::gemm_avx2::row_taps`] on 16 channels.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    unsafe fn row_taps<const K: usize, const S: usize, const CHECKED: bool>(
        acc: &mut [__m512; ROW_PIXELS],
        wk: &[__m512; K],
        line: *const f32,
        x0: isize,
        w: usize,
        c: usize,
        zero: *const f32,
    ) {
        for j in 0..(ROW_PIXELS - 1) * S + K {
            let ix = x0 + j as isize;
            let at = line.wrapping_offset(ix * c as isize);
            let ptr = if !CHECKED || (ix as usize) < w {
                at
            } else {
                zero
            };
            let x = _mm512_loadu_ps(ptr);
            for (kx, wv) in wk.iter().enumerate() {
                if j >= kx && (j - kx) % S == 0 && (j - kx) / S < ROW_PIXELS {
                    let p = (j - kx) / S;
                    acc[p] = _mm512_fmadd_ps(x, *wv, acc[p]);
                }
            }
        }
    }

    /// [`super::avx2::rows_k`] for `channels` a range of multiples of 16.
    ///
    /// # Safety
    /// The CPU must have AVX-512F; no one else may write `out`'s `channels` meanwhile.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn rows_k<const K: usize, const S: usize>(
        job: &Rows,
        epi: Epilogue,
        out: OutPtr,
        channels: std::ops::Range<usize>,
    ) {
        const P: usize = ROW_PIXELS;
        let dw = job.dw;
        let c = dw.channels;
        let (h, w) = (job.shape.height, job.shape.width);
        let ow = job.out_shape.width;
        let left = job.pad.left as isize;
        assert!(dw.kernel == (K, K) && dw.stride == (S, S));
        assert!(job.input.len() >= h * w * c && dw.weight.len() >= K * K * c);
        assert!(dw.bias.len() >= c && out.len % (ow * c) == 0);
        assert!(channels.start % 8 == 0 && channels.len() % 16 == 0 && channels.end <= c);
        assert!(epi.residual.is_none_or(|r| r.len() >= out.len));
        let rows = out.len / (ow * c);
        let (lo1, hi1) = epi.pre.bounds();
        let (lo2, hi2) = epi.post.bounds();
        let (lo1, hi1, lo2, hi2) = (
            _mm512_set1_ps(lo1),
            _mm512_set1_ps(hi1),
            _mm512_set1_ps(lo2),
            _mm512_set1_ps(hi2),
        );
        let zero = [0.0f32; 16];
        let input = job.input.as_ptr();
        for r in 0..rows {
            let oy = job.first + r;
            let y0 = (oy * S) as isize - job.pad.top as isize;
            let ky_lo = (-y0).max(0) as usize;
            let ky_hi = ((h as isize - y0).max(0) as usize).min(K);
            let out_row = out.ptr.add(r * ow * c);
            let res_row = epi.residual.map(|x| x.as_ptr().add(r * ow * c));
            let mut ox = 0;
            while ox < ow {
                let x0 = (ox * S) as isize - left;
                let inside = x0 >= 0 && x0 as usize + (P - 1) * S + K <= w;
                for c0 in channels.clone().step_by(16) {
                    let bias = _mm512_loadu_ps(dw.bias.as_ptr().add(c0));
                    let wts = dw.weight.as_ptr().add(c0);
                    let mut acc = [bias; P];
                    for ky in ky_lo..ky_hi {
                        let line = input.add((y0 + ky as isize) as usize * w * c + c0);
                        let wk: [__m512; K] =
                            std::array::from_fn(|kx| _mm512_loadu_ps(wts.add((ky * K + kx) * c)));
                        if inside {
                            row_taps::<K, S, false>(&mut acc, &wk, line, x0, w, c, zero.as_ptr());
                        } else {
                            row_taps::<K, S, true>(&mut acc, &wk, line, x0, w, c, zero.as_ptr());
                        }
                    }
                    for (p, &a) in acc.iter().enumerate().take(ow - ox) {
                        let at = (ox + p) * c + c0;
                        let mut v = _mm512_min_ps(_mm512_max_ps(a, lo1), hi1);
                        if let Some(res) = res_row {
                            v = _mm512_add_ps(v, _mm512_loadu_ps(res.add(at)));
                            v = _mm512_min_ps(_mm512_max_ps(v, lo2), hi2);
                        }
                        _mm512_storeu_ps(out_row.add(at), v);
                    }
                }
                ox += P;
            }
        }
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

    fn reference(dw: &Depthwise, x: &[f32], s: Shape, pad: Padding) -> Vec<f32> {
        let os = dw.out_shape(s, pad);
        let (kh, kw) = dw.kernel;
        let c = s.channels;
        let mut out = vec![0.0; os.len()];
        for oy in 0..os.height {
            for ox in 0..os.width {
                for ch in 0..c {
                    let mut acc = dw.bias[ch] as f64;
                    for ky in 0..kh {
                        for kx in 0..kw {
                            let iy = (oy * dw.stride.0 + ky) as isize - pad.top as isize;
                            let ix = (ox * dw.stride.1 + kx) as isize - pad.left as isize;
                            if iy >= 0
                                && ix >= 0
                                && (iy as usize) < s.height
                                && (ix as usize) < s.width
                            {
                                let xv = x[(iy as usize * s.width + ix as usize) * c + ch];
                                acc += xv as f64 * dw.weight[(ky * kw + kx) * c + ch] as f64;
                            }
                        }
                    }
                    out[(oy * os.width + ox) * c + ch] = acc as f32;
                }
            }
        }
        out
    }

    #[test]
    fn depthwise_matches_direct_summation() {
        let cases = [
            // (h, w, c, kernel, stride, pad)
            (9, 10, 24, (3, 3), (1, 1), Padding::uniform(1)),
            (12, 12, 40, (3, 3), (2, 2), Padding::uniform(1)),
            (
                8,
                8,
                288,
                (3, 3),
                (2, 2),
                Padding {
                    top: 0,
                    left: 0,
                    bottom: 1,
                    right: 1,
                },
            ),
            (14, 13, 19, (5, 5), (1, 1), Padding::uniform(2)),
            (16, 16, 48, (5, 5), (2, 2), Padding::uniform(2)),
            (
                7,
                5,
                9,
                (2, 3),
                (1, 2),
                Padding {
                    top: 1,
                    left: 0,
                    bottom: 0,
                    right: 2,
                },
            ),
            (2, 2, 16, (3, 3), (1, 1), Padding::uniform(1)),
            (64, 3, 8, (3, 3), (1, 1), Padding::uniform(1)),
            (5, 37, 16, (5, 5), (2, 2), Padding::uniform(2)),
            (
                6,
                29,
                24,
                (3, 3),
                (1, 1),
                Padding {
                    top: 0,
                    left: 1,
                    bottom: 2,
                    right: 1,
                },
            ),
            (
                9,
                23,
                16,
                (3, 3),
                (2, 2),
                Padding {
                    top: 0,
                    left: 0,
                    bottom: 1,
                    right: 1,
                },
            ),
            (11, 30, 8, (5, 5), (1, 1), Padding::uniform(2)),
            (3, 7, 8, (5, 5), (1, 1), Padding::uniform(2)),
            (7, 7, 1152, (5, 5), (1, 1), Padding::uniform(2)),
            (
                14,
                14,
                672,
                (5, 5),
                (2, 2),
                Padding {
                    top: 1,
                    left: 1,
                    bottom: 2,
                    right: 2,
                },
            ),
        ];
        for (h, w, c, k, st, pad) in cases {
            let s = Shape::new(h, w, c);
            let dw = Depthwise::new(&values(k.0 * k.1 * c, 2), &values(c, 3), k, c, st);
            let x = values(s.len(), 1);
            let want = reference(&dw, &x, s, pad);
            let os = dw.out_shape(s, pad);
            let res = values(os.len(), 5);
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(2)
                .build()
                .unwrap();
            for threads in [1, 2] {
                let mut got = vec![f32::NAN; os.len()];
                let epi = Epilogue {
                    pre: Activation::Relu6,
                    residual: Some(&res),
                    post: Activation::None,
                };
                let run = |got: &mut Vec<f32>| dw.run(&x, s, pad, epi, got);
                if threads == 1 {
                    run(&mut got);
                } else {
                    pool.install(|| run(&mut got));
                }
                for i in 0..os.len() {
                    let v = want[i].clamp(0.0, 6.0) + res[i];
                    assert!(
                        (got[i] - v).abs() < 1e-5,
                        "{h}x{w}x{c} k{k:?} s{st:?} at {i}: {} vs {v}",
                        got[i]
                    );
                }
            }
            let mut portable = vec![f32::NAN; os.len()];
            let job = Rows {
                dw: &dw,
                input: &x,
                shape: s,
                pad,
                out_shape: os,
                first: 0,
            };
            run_rows_portable(&job, Epilogue::default(), &mut portable);
            let d = portable
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f32::max);
            assert!(d < 1e-5, "portable {h}x{w}x{c}: {d}");
        }
    }
}
