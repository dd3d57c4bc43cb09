//! 1×1 convolutions with mostly-zero weights (BlazePose's person detector stores two thirds of
//! its 1×1 weights as zeros): only the non-zero weights are multiplied.
//!
//! The weights are kept per output channel as (input channel, value) lists. Pixels go in
//! blocks: the block's input rows are transposed so that each input channel's values for the
//! block's pixels are contiguous vectors, each output channel accumulates `value × vector` over
//! its non-zero list, and the results are transposed back through the epilogue into the NHWC
//! output rows. With AVX2/FMA the blocks are 32 pixels (a shorter last one of 8, 16 or 24),
//! the transposed block is 64-byte aligned (one input channel = two cache lines), and the
//! input channels are cut into k-blocks of at most [`KB_MAX`] so that the part of the
//! transposed block that an output channel's entries read stays in the L1 cache while every
//! output channel passes over it (the per-output sums carry over between k-blocks). Elsewhere
//! a portable loop works on blocks of 16.

use std::cell::RefCell;

use super::nhwc::Epilogue;
use super::parallel;
use super::pointwise::rows_per_task;

/// Pixels per block of the portable path.
const BLOCK: usize = 16;

/// Pixels per block of the AVX2 path (the row stride of its transposed block).
const WIDE: usize = 32;

/// Input channels per k-block of the AVX2 path (`KB_MAX · WIDE` floats: 16 KiB).
const KB_MAX: usize = 128;

/// Pixels up to which the AVX2 path on several threads splits output channels, not pixels.
#[cfg(target_arch = "x86_64")]
const CHANNEL_SPLIT_MAX_PIXELS: usize = 256;

/// Whether the CPU has AVX-512F (for [`SparsePointwise::spmm32_avx512`]).
#[cfg(all(target_arch = "x86_64", lhmpp_bf16_intrinsics))]
fn avx512() -> bool {
    std::arch::is_x86_feature_detected!("avx512f")
}

/// This thread's scratch grown to a transposed block of `k` and of `n` rows, each starting
/// on a 64-byte boundary.
#[cfg(target_arch = "x86_64")]
fn aligned_scratch<'a>(
    xt: &'a mut Vec<f32>,
    yt: &'a mut Vec<f32>,
    k: usize,
    n: usize,
) -> (&'a mut [f32], &'a mut [f32]) {
    xt.resize(k * WIDE + 16, 0.0);
    yt.resize(n * WIDE + 16, 0.0);
    let xo = xt.as_ptr().align_offset(64).min(16);
    let yo = yt.as_ptr().align_offset(64).min(16);
    (&mut xt[xo..xo + k * WIDE], &mut yt[yo..yo + n * WIDE])
}

thread_local! {
    /// Each thread's transposed input block and transposed results, kept between calls.
    static SCRATCH: RefCell<(Vec<f32>, Vec<f32>)> = const { RefCell::new((Vec::new(), Vec::new())) };
}

/// A `[n][k]` weight matrix stored by its non-zero entries, with its bias.
#[derive(Debug, Clone)]
pub struct SparsePointwise {
    k: usize,
    n: usize,
    /// `starts[o]..starts[o + 1]` index output channel `o`'s entries.
    starts: Vec<usize>,
    /// Input channel of each entry.
    inputs: Vec<u32>,
    /// Value of each entry.
    values: Vec<f32>,
    bias: Vec<f32>,
    /// The entries again for the AVX2 path, ordered by (k-block, output channel):
    /// `kb_starts[b·n + o]..kb_starts[b·n + o + 1]` are output `o`'s entries in k-block `b`.
    kb_starts: Vec<u32>,
    /// Each entry's offset in the transposed block (input channel × [`WIDE`]).
    kb_offsets: Vec<u32>,
    /// Each entry's value.
    kb_values: Vec<f32>,
    /// Number of k-blocks.
    kb_count: usize,
}

impl SparsePointwise {
    /// Keeps the non-zero entries of `weight [n][k]` (TFLite's 1×1 `[C_out][1][1][C_in]`).
    pub fn new(weight: &[f32], k: usize, n: usize, bias: &[f32]) -> Self {
        assert_eq!(weight.len(), k * n, "sparse pointwise: weight length");
        assert_eq!(bias.len(), n, "sparse pointwise: bias length");
        let mut starts = vec![0];
        let (mut inputs, mut values) = (Vec::new(), Vec::new());
        for row in weight.chunks_exact(k.max(1)).take(n) {
            for (i, &v) in row.iter().enumerate() {
                if v != 0.0 {
                    inputs.push(i as u32);
                    values.push(v);
                }
            }
            starts.push(values.len());
        }
        // the kernels index the transposed input block by these without bounds checks
        assert!(inputs.iter().all(|&i| (i as usize) < k));
        let kb_count = k.div_ceil(KB_MAX).max(1);
        let kb_len = k.div_ceil(kb_count).div_ceil(8) * 8;
        let mut kb_starts = vec![0u32];
        let (mut kb_offsets, mut kb_values) = (Vec::new(), Vec::new());
        for b in 0..kb_count {
            let range = b * kb_len..((b + 1) * kb_len).min(k);
            for o in 0..n {
                for e in starts[o]..starts[o + 1] {
                    if range.contains(&(inputs[e] as usize)) {
                        kb_offsets.push(inputs[e] * WIDE as u32);
                        kb_values.push(values[e]);
                    }
                }
                kb_starts.push(kb_values.len() as u32);
            }
        }
        assert_eq!(kb_values.len(), values.len());
        Self {
            k,
            n,
            starts,
            inputs,
            values,
            bias: bias.to_vec(),
            kb_starts,
            kb_offsets,
            kb_values,
            kb_count,
        }
    }

    /// The share of weights that are non-zero.
    pub fn density(&self) -> f64 {
        self.values.len() as f64 / (self.k * self.n).max(1) as f64
    }

    /// Input channels.
    pub fn k(&self) -> usize {
        self.k
    }

    /// Output channels.
    pub fn n(&self) -> usize {
        self.n
    }

    /// `out [m, n] = epi(a [m, k] · Wᵀ + bias)`, in parallel over pixel blocks.
    pub fn run(&self, a: &[f32], m: usize, epi: Epilogue, out: &mut [f32]) {
        let (k, n) = (self.k, self.n);
        assert_eq!(a.len(), m * k, "sparse pointwise: input length");
        assert_eq!(out.len(), m * n, "sparse pointwise: output length");
        if let Some(r) = epi.residual {
            assert_eq!(r.len(), m * n, "sparse pointwise: residual length");
        }
        if m == 0 {
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if k % 8 == 0 && n % 8 == 0 && super::gemm_avx2::available() {
            self.run_avx2(a, m, epi, out);
            return;
        }
        self.run_portable(a, m, epi, out);
    }

    /// [`Self::run`] on plain loops, blocks of [`BLOCK`] pixels.
    fn run_portable(&self, a: &[f32], m: usize, epi: Epilogue, out: &mut [f32]) {
        let (k, n) = (self.k, self.n);
        let rows = rows_per_task(m, m * self.values.len()).div_ceil(BLOCK) * BLOCK;
        parallel::for_each_chunk(out, rows * n, |t, chunk| {
            SCRATCH.with(|s| {
                let (xt, yt) = &mut *s.borrow_mut();
                xt.resize(k * BLOCK, 0.0);
                yt.resize(n * BLOCK, 0.0);
                let first = t * rows;
                let count = chunk.len() / n;
                for b in (0..count).step_by(BLOCK) {
                    let p = BLOCK.min(count - b);
                    let r0 = first + b;
                    // transpose the block's input rows: xt[i][j] = a[r0 + j][i]
                    for j in 0..BLOCK {
                        let row = r0 + j.min(p - 1);
                        for (i, &v) in a[row * k..(row + 1) * k].iter().enumerate() {
                            xt[i * BLOCK + j] = v;
                        }
                    }
                    self.block_portable(xt, yt);
                    let (lo1, hi1) = epi.pre.bounds();
                    let (lo2, hi2) = epi.post.bounds();
                    for j in 0..p {
                        let dst = &mut chunk[(b + j) * n..(b + j + 1) * n];
                        for (o, d) in dst.iter_mut().enumerate() {
                            let mut v = (yt[o * BLOCK + j] + self.bias[o]).max(lo1).min(hi1);
                            if let Some(res) = epi.residual {
                                v = (v + res[(r0 + j) * n + o]).max(lo2).min(hi2);
                            }
                            *d = v;
                        }
                    }
                }
            });
        });
    }

    /// `yt[o][j] = Σ value · xt[input][j]` over output channel `o`'s entries (rows of
    /// [`BLOCK`]).
    fn block_portable(&self, xt: &[f32], yt: &mut [f32]) {
        for o in 0..self.n {
            let mut acc = [0.0f32; BLOCK];
            for e in self.starts[o]..self.starts[o + 1] {
                let x = &xt[self.inputs[e] as usize * BLOCK..][..BLOCK];
                let v = self.values[e];
                for (a, &x) in acc.iter_mut().zip(x) {
                    *a += v * x;
                }
            }
            yt[o * BLOCK..(o + 1) * BLOCK].copy_from_slice(&acc);
        }
    }

    /// The AVX2 path of [`Self::run`] (`k`, `n` multiples of 8): pixels cut into one task per
    /// thread (up to four per thread for large layers, each at least 64 pixels, in multiples
    /// of 8 so that the tasks come out even), each task in blocks of [`WIDE`].
    #[cfg(target_arch = "x86_64")]
    fn run_avx2(&self, a: &[f32], m: usize, epi: Epilogue, out: &mut [f32]) {
        use super::gemm_avx2::OutPtr;
        let (k, n) = (self.k, self.n);
        let threads = parallel::threads();
        let cost = m * self.values.len();
        if threads > 1 && cost >= 1 << 16 && m <= CHANNEL_SPLIT_MAX_PIXELS && n >= 16 * threads {
            // few pixels: one task per thread over all of them, the output channels split
            // into ranges of about equal non-zero counts (tasks write disjoint columns)
            let bounds = self.channel_bounds(threads);
            let (ptr, len) = (parallel::SendPtr(out.as_mut_ptr()), out.len());
            parallel::for_each(threads, |t| {
                let channels = bounds[t]..bounds[t + 1];
                SCRATCH.with(|s| {
                    let (xt, yt) = &mut *s.borrow_mut();
                    let (xt, yt) = aligned_scratch(xt, yt, k, n);
                    for b in (0..m).step_by(WIDE) {
                        let p = WIDE.min(m - b);
                        let dst = OutPtr {
                            ptr: ptr.get(),
                            len,
                        }
                        .skip(b * n);
                        // SAFETY: the CPU has AVX2 and FMA (checked by the caller); this
                        // task alone writes `channels` of the output rows.
                        unsafe {
                            self.block_avx2_nhwc(a, b, p, epi, xt, yt, dst, channels.clone())
                        };
                    }
                });
            });
            return;
        }
        let tasks = if threads == 1 || cost < (1 << 16) {
            1
        } else {
            threads * (m / (threads * 64)).clamp(1, 4)
        };
        let per = m.div_ceil(tasks).div_ceil(8) * 8;
        parallel::for_each_chunk(out, per * n, |t, chunk| {
            SCRATCH.with(|s| {
                let (xt, yt) = &mut *s.borrow_mut();
                let (xt, yt) = aligned_scratch(xt, yt, k, n);
                let first = t * per;
                let count = chunk.len() / n;
                for b in (0..count).step_by(WIDE) {
                    let p = WIDE.min(count - b);
                    let dst = OutPtr::new(&mut chunk[b * n..(b + p) * n]);
                    // SAFETY: the CPU has AVX2 and FMA (checked by the caller).
                    unsafe { self.block_avx2_nhwc(a, first + b, p, epi, xt, yt, dst, 0..n) };
                }
            });
        });
    }

    /// Output channel bounds (multiples of 8) that cut the channels into `tasks` ranges of
    /// about equal non-zero counts.
    #[cfg(target_arch = "x86_64")]
    fn channel_bounds(&self, tasks: usize) -> Vec<usize> {
        let groups = self.n / 8;
        let total = self.values.len().max(1);
        let mut bounds = vec![0];
        let mut g = 0;
        for t in 1..tasks {
            let target = total * t / tasks;
            while g < groups && self.starts[(g + 1) * 8] <= target {
                g += 1;
            }
            bounds.push((g * 8).max(*bounds.last().unwrap()));
        }
        bounds.push(self.n);
        bounds
    }

    /// One block of `p ≤ 32` pixels from row `r0` with AVX2/FMA, the transposes as 8 × 8
    /// register transposes (`k` and `n` multiples of 8), output channels `channels` only
    /// (a range of multiples of 8); `dst` is the block's output rows (`n` apart). Only
    /// `⌈p / 8⌉` vectors of each transposed row are computed.
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA, and no one else may write `dst`'s `channels` meanwhile.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    #[allow(clippy::too_many_arguments)]
    unsafe fn block_avx2_nhwc(
        &self,
        a: &[f32],
        r0: usize,
        p: usize,
        epi: Epilogue,
        xt: &mut [f32],
        yt: &mut [f32],
        dst: super::gemm_avx2::OutPtr,
        channels: std::ops::Range<usize>,
    ) {
        use super::gemm_avx2::transpose8;
        use std::arch::x86_64::*;
        let (k, n) = (self.k, self.n);
        assert!((1..=WIDE).contains(&p) && (r0 + p) * k <= a.len() && dst.len >= p * n);
        assert!(channels.start % 8 == 0 && channels.end % 8 == 0 && channels.end <= n);
        assert!(xt.len() >= k * WIDE && yt.len() >= n * WIDE);
        assert!(epi.residual.is_none_or(|r| r.len() >= (r0 + p) * n));
        let nv = p.div_ceil(8);
        // rows past `p` repeat the last one (their results are not stored)
        let row = |j: usize| a.as_ptr().add((r0 + j.min(p - 1)) * k);
        for g in 0..nv {
            let rows: [*const f32; 8] = std::array::from_fn(|q| row(g * 8 + q));
            for i in (0..k).step_by(8) {
                let v: [__m256; 8] = std::array::from_fn(|q| _mm256_loadu_ps(rows[q].add(i)));
                for (q, t) in transpose8(v).iter().enumerate() {
                    _mm256_storeu_ps(xt.as_mut_ptr().add((i + q) * WIDE + g * 8), *t);
                }
            }
        }
        let ch = channels.clone();
        match nv {
            #[cfg(lhmpp_bf16_intrinsics)]
            4 if avx512() => self.spmm32_avx512(xt, yt, ch),
            4 => self.spmm_avx2::<4>(xt, yt, ch),
            3 => self.spmm_avx2::<3>(xt, yt, ch),
            2 => self.spmm_avx2::<2>(xt, yt, ch),
            _ => self.spmm_avx2::<1>(xt, yt, ch),
        }
        let (lo1, hi1) = epi.pre.bounds();
        let (lo2, hi2) = epi.post.bounds();
        let (lo1, hi1, lo2, hi2) = (
            _mm256_set1_ps(lo1),
            _mm256_set1_ps(hi1),
            _mm256_set1_ps(lo2),
            _mm256_set1_ps(hi2),
        );
        for o in channels.step_by(8) {
            let bias = _mm256_loadu_ps(self.bias.as_ptr().add(o));
            for g in 0..nv {
                let v: [__m256; 8] = std::array::from_fn(|q| {
                    _mm256_loadu_ps(yt.as_ptr().add((o + q) * WIDE + g * 8))
                });
                for (q, &t) in transpose8(v).iter().enumerate() {
                    let j = g * 8 + q;
                    if j >= p {
                        break;
                    }
                    let mut y = _mm256_min_ps(_mm256_max_ps(_mm256_add_ps(t, bias), lo1), hi1);
                    if let Some(res) = epi.residual {
                        y = _mm256_add_ps(y, _mm256_loadu_ps(res.as_ptr().add((r0 + j) * n + o)));
                        y = _mm256_min_ps(_mm256_max_ps(y, lo2), hi2);
                    }
                    _mm256_storeu_ps(dst.ptr.add(j * n + o), y);
                }
            }
        }
    }

    /// [`Self::spmm_avx2`] for whole 32-pixel blocks with AVX-512: per entry one broadcast
    /// and two 16-lane multiply-adds, the same sums in the same order lane by lane. (The
    /// CPUs we target multiply-add at the same rate at either width, but this loop is bound
    /// by its loads and instructions, which halve.)
    ///
    /// # Safety
    /// The CPU must have AVX-512F.
    #[cfg(all(target_arch = "x86_64", lhmpp_bf16_intrinsics))]
    #[target_feature(enable = "avx512f")]
    #[allow(clippy::incompatible_msrv)]
    unsafe fn spmm32_avx512(&self, xt: &[f32], yt: &mut [f32], channels: std::ops::Range<usize>) {
        use std::arch::x86_64::*;
        let n = self.n;
        assert!(xt.len() >= self.k * WIDE && yt.len() >= n * WIDE && WIDE == 32);
        assert!(channels.end <= n);
        assert!(self.kb_starts.len() == self.kb_count * n + 1);
        assert!(*self.kb_starts.last().unwrap() as usize <= self.kb_values.len());
        assert!(self.kb_offsets.len() == self.kb_values.len());
        // every offset is (input channel < k) · WIDE (see `new`)
        let (x, y) = (xt.as_ptr(), yt.as_mut_ptr());
        let (offs, vals) = (self.kb_offsets.as_ptr(), self.kb_values.as_ptr());
        let starts = self.kb_starts.as_ptr();
        for b in 0..self.kb_count {
            for o in channels.clone() {
                let s = *starts.add(b * n + o) as usize;
                let e = *starts.add(b * n + o + 1) as usize;
                let yo = y.add(o * WIDE);
                let (mut a0, mut a1) = if b == 0 {
                    (_mm512_setzero_ps(), _mm512_setzero_ps())
                } else {
                    (_mm512_loadu_ps(yo), _mm512_loadu_ps(yo.add(16)))
                };
                let (mut c0, mut c1) = (_mm512_setzero_ps(), _mm512_setzero_ps());
                let mut j = s;
                while j + 2 <= e {
                    let w0 = _mm512_set1_ps(*vals.add(j));
                    let w1 = _mm512_set1_ps(*vals.add(j + 1));
                    let x0 = x.add(*offs.add(j) as usize);
                    let x1 = x.add(*offs.add(j + 1) as usize);
                    a0 = _mm512_fmadd_ps(_mm512_loadu_ps(x0), w0, a0);
                    a1 = _mm512_fmadd_ps(_mm512_loadu_ps(x0.add(16)), w0, a1);
                    c0 = _mm512_fmadd_ps(_mm512_loadu_ps(x1), w1, c0);
                    c1 = _mm512_fmadd_ps(_mm512_loadu_ps(x1.add(16)), w1, c1);
                    j += 2;
                }
                if j < e {
                    let w0 = _mm512_set1_ps(*vals.add(j));
                    let x0 = x.add(*offs.add(j) as usize);
                    a0 = _mm512_fmadd_ps(_mm512_loadu_ps(x0), w0, a0);
                    a1 = _mm512_fmadd_ps(_mm512_loadu_ps(x0.add(16)), w0, a1);
                }
                _mm512_storeu_ps(yo, _mm512_add_ps(a0, c0));
                _mm512_storeu_ps(yo.add(16), _mm512_add_ps(a1, c1));
            }
        }
    }

    /// `yt[o][0..8·NV] = Σ value · xt[input][0..8·NV]` over output channel `o`'s entries
    /// (rows of both [`WIDE`] apart), k-block by k-block: per entry one broadcast and `NV`
    /// 8-lane multiply-adds, alternate entries into two sets of sums.
    ///
    /// # Safety
    /// The caller's function must enable AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    #[allow(clippy::needless_range_loop)]
    unsafe fn spmm_avx2<const NV: usize>(
        &self,
        xt: &[f32],
        yt: &mut [f32],
        channels: std::ops::Range<usize>,
    ) {
        use std::arch::x86_64::*;
        let n = self.n;
        assert!(xt.len() >= self.k * WIDE && yt.len() >= n * WIDE && NV * 8 <= WIDE);
        assert!(channels.end <= n);
        assert!(self.kb_starts.len() == self.kb_count * n + 1);
        assert!(*self.kb_starts.last().unwrap() as usize <= self.kb_values.len());
        assert!(self.kb_offsets.len() == self.kb_values.len());
        // every offset is (input channel < k) · WIDE (see `new`)
        let (x, y) = (xt.as_ptr(), yt.as_mut_ptr());
        let (offs, vals) = (self.kb_offsets.as_ptr(), self.kb_values.as_ptr());
        let starts = self.kb_starts.as_ptr();
        for b in 0..self.kb_count {
            for o in channels.clone() {
                let s = *starts.add(b * n + o) as usize;
                let e = *starts.add(b * n + o + 1) as usize;
                let yo = y.add(o * WIDE);
                let mut a0: [__m256; NV] = if b == 0 {
                    [_mm256_setzero_ps(); NV]
                } else {
                    std::array::from_fn(|v| _mm256_loadu_ps(yo.add(v * 8)))
                };
                let mut a1 = [_mm256_setzero_ps(); NV];
                let mut j = s;
                while j + 2 <= e {
                    let w0 = _mm256_broadcast_ss(&*vals.add(j));
                    let w1 = _mm256_broadcast_ss(&*vals.add(j + 1));
                    let x0 = x.add(*offs.add(j) as usize);
                    let x1 = x.add(*offs.add(j + 1) as usize);
                    for v in 0..NV {
                        a0[v] = _mm256_fmadd_ps(_mm256_loadu_ps(x0.add(v * 8)), w0, a0[v]);
                        a1[v] = _mm256_fmadd_ps(_mm256_loadu_ps(x1.add(v * 8)), w1, a1[v]);
                    }
                    j += 2;
                }
                if j < e {
                    let w0 = _mm256_broadcast_ss(&*vals.add(j));
                    let x0 = x.add(*offs.add(j) as usize);
                    for v in 0..NV {
                        a0[v] = _mm256_fmadd_ps(_mm256_loadu_ps(x0.add(v * 8)), w0, a0[v]);
                    }
                }
                for v in 0..NV {
                    _mm256_storeu_ps(yo.add(v * 8), _mm256_add_ps(a0[v], a1[v]));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::nhwc::Activation;

    /// The AVX-512 and AVX2 32-pixel kernels give the same sums (the AVX2 one is what CPUs
    /// without AVX-512 run; on those, only it is checked, through `run`).
    #[cfg(all(target_arch = "x86_64", lhmpp_bf16_intrinsics))]
    #[test]
    fn avx512_blocks_match_avx2_blocks() {
        if !(avx512() && crate::kernels::gemm_avx2::available()) {
            return;
        }
        for (k, n) in [(8, 8), (264, 40), (1152, 24)] {
            let w: Vec<f32> = (0..n * k)
                .map(|i| {
                    if i % 4 == 1 {
                        (i % 23) as f32 * 0.1 - 1.0
                    } else {
                        0.0
                    }
                })
                .collect();
            let sp = SparsePointwise::new(&w, k, n, &vec![0.0; n]);
            let xt: Vec<f32> = (0..k * WIDE)
                .map(|i| (i % 17) as f32 * 0.25 - 2.0)
                .collect();
            let (mut y1, mut y2) = (vec![0.0; n * WIDE], vec![0.0; n * WIDE]);
            // SAFETY: both instruction sets are present (checked above).
            unsafe {
                sp.spmm32_avx512(&xt, &mut y1, 0..n);
                avx2_spmm4(&sp, &xt, &mut y2);
            }
            assert_eq!(y1, y2, "k{k} n{n}");
        }
    }

    /// [`SparsePointwise::spmm_avx2`] for 32 pixels, with the features enabled.
    #[cfg(all(target_arch = "x86_64", lhmpp_bf16_intrinsics))]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn avx2_spmm4(sp: &SparsePointwise, xt: &[f32], yt: &mut [f32]) {
        sp.spmm_avx2::<4>(xt, yt, 0..sp.n);
    }

    #[test]
    fn sparse_products_match_dense_summation() {
        for (m, k, n) in [
            (1, 8, 3),
            (37, 64, 24),
            (100, 192, 40),
            (16, 5, 1),
            (41, 48, 16),
            (7, 8, 8),
            (49, 1152, 24),
            (200, 272, 48),
            (75, 136, 16),
            (196, 96, 72),
            (49, 192, 1152),
        ] {
            let a: Vec<f32> = (0..m * k)
                .map(|i| ((i * 7919 % 1013) as f32 / 506.5) - 1.0)
                .collect();
            // two thirds zeros
            let w: Vec<f32> = (0..n * k)
                .map(|i| {
                    if i % 3 == 0 {
                        ((i * 31 % 97) as f32 / 48.5) - 1.0
                    } else {
                        0.0
                    }
                })
                .collect();
            let bias: Vec<f32> = (0..n).map(|o| o as f32 * 0.1 - 0.5).collect();
            let res: Vec<f32> = (0..m * n).map(|i| (i % 11) as f32 * 0.2 - 1.0).collect();
            let sp = SparsePointwise::new(&w, k, n, &bias);
            assert!(sp.density() <= 0.4);
            let epi = Epilogue {
                pre: Activation::Relu6,
                residual: Some(&res),
                post: Activation::None,
            };
            let mut got = vec![f32::NAN; m * n];
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(2)
                .build()
                .unwrap();
            pool.install(|| sp.run(&a, m, epi, &mut got));
            let mut portable = vec![f32::NAN; m * n];
            sp.run_portable(&a, m, epi, &mut portable);
            for r in 0..m {
                for o in 0..n {
                    let s: f64 = (0..k)
                        .map(|i| a[r * k + i] as f64 * w[o * k + i] as f64)
                        .sum();
                    let want = (s as f32 + bias[o]).clamp(0.0, 6.0) + res[r * n + o];
                    for g in [got[r * n + o], portable[r * n + o]] {
                        assert!(
                            (g - want).abs() < 1e-4,
                            "m{m} k{k} n{n} ({r}, {o}): {g} vs {want}"
                        );
                    }
                }
            }
        }
    }
}
