//! 1×1 convolutions with mostly-zero weights (BlazePose's person detector stores two thirds of
//! its 1×1 weights as zeros): only the non-zero weights are multiplied.
//!
//! The weights are kept per output channel as (input channel, value) lists. Pixels go in
//! blocks of 16: the block's input rows are transposed so that each input channel's 16 values
//! are two vectors, each output channel accumulates `value × vector` over its non-zero list
//! (four partial sums, so that the multiply-adds do not wait on each other), and the 16 × n
//! results are transposed back through the epilogue into the NHWC output rows.

use std::cell::RefCell;

use super::nhwc::Epilogue;
use super::parallel;
use super::pointwise::rows_per_task;

/// Pixels per block.
const BLOCK: usize = 16;

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
        Self {
            k,
            n,
            starts,
            inputs,
            values,
            bias: bias.to_vec(),
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
                    #[cfg(target_arch = "x86_64")]
                    if k % 8 == 0 && n % 8 == 0 && super::gemm_avx2::available() {
                        let dst = &mut chunk[b * n..(b + p) * n];
                        // SAFETY: the CPU has AVX2 and FMA (checked above).
                        unsafe { self.block_avx2_nhwc(a, r0, p, epi, xt, yt, dst) };
                        continue;
                    }
                    // transpose the block's input rows: xt[i][j] = a[r0 + j][i]
                    for j in 0..BLOCK {
                        let row = r0 + j.min(p - 1);
                        for (i, &v) in a[row * k..(row + 1) * k].iter().enumerate() {
                            xt[i * BLOCK + j] = v;
                        }
                    }
                    self.block(xt, yt);
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

    /// `yt[o][j] = Σ value · xt[input][j]` over output channel `o`'s entries.
    fn block(&self, xt: &[f32], yt: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        if super::gemm_avx2::available() {
            // SAFETY: the CPU has AVX2 and FMA (checked above).
            unsafe { self.block_avx2(xt, yt) };
            return;
        }
        self.block_portable(xt, yt);
    }

    /// [`Self::block`] on plain loops.
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

    /// One block of `p ≤ 16` pixels from row `r0` with AVX2/FMA, the transposes as 8 × 8
    /// register transposes (`k` and `n` multiples of 8); `dst` is the block's output rows.
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA.
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
        dst: &mut [f32],
    ) {
        use super::gemm_avx2::transpose8;
        use std::arch::x86_64::*;
        let (k, n) = (self.k, self.n);
        assert!((1..=BLOCK).contains(&p) && (r0 + p) * k <= a.len() && dst.len() == p * n);
        assert!(xt.len() >= k * BLOCK && yt.len() >= n * BLOCK);
        assert!(epi.residual.is_none_or(|r| r.len() >= (r0 + p) * n));
        // rows past `p` repeat the last one (their results are not stored)
        let row = |j: usize| a.as_ptr().add((r0 + j.min(p - 1)) * k);
        for half in 0..2 {
            let rows: [*const f32; 8] = std::array::from_fn(|q| row(half * 8 + q));
            for i in (0..k).step_by(8) {
                let v: [__m256; 8] = std::array::from_fn(|q| _mm256_loadu_ps(rows[q].add(i)));
                for (q, t) in transpose8(v).iter().enumerate() {
                    _mm256_storeu_ps(xt.as_mut_ptr().add((i + q) * BLOCK + half * 8), *t);
                }
            }
        }
        self.block_avx2(xt, yt);
        let (lo1, hi1) = epi.pre.bounds();
        let (lo2, hi2) = epi.post.bounds();
        let (lo1, hi1, lo2, hi2) = (
            _mm256_set1_ps(lo1),
            _mm256_set1_ps(hi1),
            _mm256_set1_ps(lo2),
            _mm256_set1_ps(hi2),
        );
        for o in (0..n).step_by(8) {
            let bias = _mm256_loadu_ps(self.bias.as_ptr().add(o));
            for half in 0..2 {
                let v: [__m256; 8] = std::array::from_fn(|q| {
                    _mm256_loadu_ps(yt.as_ptr().add((o + q) * BLOCK + half * 8))
                });
                for (q, &t) in transpose8(v).iter().enumerate() {
                    let j = half * 8 + q;
                    if j >= p {
                        break;
                    }
                    let mut y = _mm256_min_ps(_mm256_max_ps(_mm256_add_ps(t, bias), lo1), hi1);
                    if let Some(res) = epi.residual {
                        y = _mm256_add_ps(y, _mm256_loadu_ps(res.as_ptr().add((r0 + j) * n + o)));
                        y = _mm256_min_ps(_mm256_max_ps(y, lo2), hi2);
                    }
                    _mm256_storeu_ps(dst.as_mut_ptr().add(j * n + o), y);
                }
            }
        }
    }

    /// [`Self::block`] with AVX2/FMA: per entry one broadcast and two 8-lane multiply-adds,
    /// into four partial sums.
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn block_avx2(&self, xt: &[f32], yt: &mut [f32]) {
        use std::arch::x86_64::*;
        assert!(xt.len() >= self.k * BLOCK && yt.len() >= self.n * BLOCK);
        let x = xt.as_ptr();
        for o in 0..self.n {
            let (s, e) = (self.starts[o], self.starts[o + 1]);
            let mut acc = [_mm256_setzero_ps(); 8];
            let mut j = s;
            while j + 4 <= e {
                for u in 0..4 {
                    let w = _mm256_set1_ps(*self.values.get_unchecked(j + u));
                    let xi = x.add(*self.inputs.get_unchecked(j + u) as usize * BLOCK);
                    acc[2 * u] = _mm256_fmadd_ps(_mm256_loadu_ps(xi), w, acc[2 * u]);
                    acc[2 * u + 1] = _mm256_fmadd_ps(_mm256_loadu_ps(xi.add(8)), w, acc[2 * u + 1]);
                }
                j += 4;
            }
            while j < e {
                let w = _mm256_set1_ps(*self.values.get_unchecked(j));
                let xi = x.add(*self.inputs.get_unchecked(j) as usize * BLOCK);
                acc[0] = _mm256_fmadd_ps(_mm256_loadu_ps(xi), w, acc[0]);
                acc[1] = _mm256_fmadd_ps(_mm256_loadu_ps(xi.add(8)), w, acc[1]);
                j += 1;
            }
            let lo = _mm256_add_ps(_mm256_add_ps(acc[0], acc[2]), _mm256_add_ps(acc[4], acc[6]));
            let hi = _mm256_add_ps(_mm256_add_ps(acc[1], acc[3]), _mm256_add_ps(acc[5], acc[7]));
            _mm256_storeu_ps(yt.as_mut_ptr().add(o * BLOCK), lo);
            _mm256_storeu_ps(yt.as_mut_ptr().add(o * BLOCK + 8), hi);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::nhwc::Activation;

    #[test]
    fn sparse_products_match_dense_summation() {
        for (m, k, n) in [
            (1, 8, 3),
            (37, 64, 24),
            (100, 192, 40),
            (16, 5, 1),
            (41, 48, 16),
            (7, 8, 8),
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
            let xt: Vec<f32> = (0..k * BLOCK).map(|i| (i % 13) as f32 - 6.0).collect();
            let (mut y1, mut y2) = (vec![0.0; n * BLOCK], vec![0.0; n * BLOCK]);
            sp.block(&xt, &mut y1);
            sp.block_portable(&xt, &mut y2);
            for (u, v) in y1.iter().zip(&y2) {
                assert!((u - v).abs() < 1e-3, "{u} vs {v}");
            }
            let mut got = vec![f32::NAN; m * n];
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(2)
                .build()
                .unwrap();
            pool.install(|| sp.run(&a, m, epi, &mut got));
            for r in 0..m {
                for o in 0..n {
                    let s: f64 = (0..k)
                        .map(|i| a[r * k + i] as f64 * w[o * k + i] as f64)
                        .sum();
                    let want = (s as f32 + bias[o]).clamp(0.0, 6.0) + res[r * n + o];
                    let g = got[r * n + o];
                    assert!(
                        (g - want).abs() < 1e-4,
                        "m{m} k{k} n{n} ({r}, {o}): {g} vs {want}"
                    );
                }
            }
        }
    }
}
