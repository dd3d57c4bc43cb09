//! Register-blocked matrix products for channels-last convolutions: `out [m, n] =
//! epilogue(a [m, k] · W [k, n])`, where the rows are pixels and the columns output channels.
//! A 1×1 convolution is one such product over the pixels of an NHWC map; a k×k convolution
//! gathers its taps into rows first ([`super::conv_nhwc`]).
//!
//! The weights are packed once into column panels of 16 or 8 channels (`[k][width]`, the
//! last panel zero-padded). A micro-kernel keeps a `rows × width` block of the output in
//! registers (6×16 or 12×8, twelve 256-bit accumulators with AVX2/FMA; one or two rows
//! without padding them to a block) and runs over `k`, broadcasting one input value per row
//! against the panel's row of weights. The epilogue adds the bias, applies the first
//! activation, adds an optional residual and applies the second, as the block is stored. Rows
//! are cut into blocks that stay in the L2 cache while every panel passes over them, and into
//! parallel tasks; products of at most 128 rows on several threads split the column panels
//! instead (even shares, and each weight read by one thread only).

use super::nhwc::Epilogue;
use super::parallel;

/// Floats of input rows per cache block (128 KiB).
const BLOCK_FLOATS: usize = 1 << 15;

/// Multiply-adds below which a product runs as one rayon task.
const MIN_TASK_MACS: usize = 1 << 18;

/// One column panel of packed weights.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Panel {
    /// First output column.
    col: usize,
    /// Columns the panel holds (32, 16 or 8; the last ones past `n` are zero).
    width: usize,
    /// Offset of its `[k][width]` values in [`PackedGemm::data`].
    offset: usize,
}

/// A `[k, n]` weight matrix and its `[n]` bias, packed into column panels.
#[derive(Debug, Clone)]
pub struct PackedGemm {
    k: usize,
    n: usize,
    panels: Vec<Panel>,
    data: Vec<f32>,
    bias: Vec<f32>,
    /// `bias` with zeros up to the last panel's width.
    padded_bias: Vec<f32>,
}

impl PackedGemm {
    /// Packs `weight(row, col)` for `row < k`, `col < n` (the value multiplying input column
    /// `row` into output column `col`) and `bias [n]`.
    pub fn new(k: usize, n: usize, weight: impl Fn(usize, usize) -> f32, bias: &[f32]) -> Self {
        assert_eq!(bias.len(), n, "packed gemm: bias length");
        let mut panels = Vec::new();
        let (mut col, mut offset) = (0, 0);
        while col < n {
            let width = if n - col > 8 { 16 } else { 8 };
            panels.push(Panel { col, width, offset });
            offset += k * width;
            col += width;
        }
        let mut data = vec![0.0; offset];
        for p in &panels {
            for row in 0..k {
                for j in 0..p.width.min(n - p.col) {
                    data[p.offset + row * p.width + j] = weight(row, p.col + j);
                }
            }
        }
        let mut padded_bias = bias.to_vec();
        padded_bias.resize(col, 0.0);
        Self {
            k,
            n,
            panels,
            data,
            bias: bias.to_vec(),
            padded_bias,
        }
    }

    /// Packs a TFLite convolution weight `[n][k]` (output channel major; `k` = taps × input
    /// channels in the order the rows are gathered).
    pub fn from_rows(weight: &[f32], k: usize, n: usize, bias: &[f32]) -> Self {
        assert_eq!(weight.len(), k * n, "packed gemm: weight length");
        Self::new(k, n, |row, col| weight[col * k + row], bias)
    }

    /// The inner dimension (input values per row).
    pub fn k(&self) -> usize {
        self.k
    }

    /// Output columns.
    pub fn n(&self) -> usize {
        self.n
    }

    /// `out [m, n] = epi(a [m, k] · W + bias)` with `a`'s rows `lda` apart, in parallel over
    /// row blocks on the current rayon pool.
    pub fn run(&self, a: &[f32], lda: usize, m: usize, epi: Epilogue, out: &mut [f32]) {
        let n = self.n;
        assert!(lda >= self.k, "packed gemm: lda < k");
        assert!(
            m == 0 || a.len() >= (m - 1) * lda + self.k,
            "packed gemm: input length"
        );
        assert_eq!(out.len(), m * n, "packed gemm: output length");
        if let Some(r) = epi.residual {
            assert_eq!(r.len(), m * n, "packed gemm: residual length");
        }
        if m == 0 {
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if let Some(tasks) = self.column_tasks(m) {
            let (ptr, len) = (parallel::SendPtr(out.as_mut_ptr()), out.len());
            parallel::for_each(tasks, |t| {
                let out = super::gemm_avx2::OutPtr {
                    ptr: ptr.get(),
                    len,
                };
                // SAFETY: the CPU has AVX2 and FMA (checked by `column_tasks`); task `t`
                // writes only the columns of its own panels, and `out` outlives the loop.
                unsafe { self.run_panels_avx2(a, lda, m, epi, out, self.panel_range(t, tasks)) };
            });
            return;
        }
        let rows = rows_per_task(m, m * n * self.k);
        parallel::for_each_chunk(out, rows * n, |t, chunk| {
            let r0 = t * rows;
            let rm = chunk.len() / n;
            let epi = Epilogue {
                residual: epi.residual.map(|r| &r[r0 * n..(r0 + rm) * n]),
                ..epi
            };
            self.run_serial(&a[r0 * lda..], lda, rm, epi, chunk);
        });
    }

    /// For products of few rows on several threads (with AVX2/FMA): the number of tasks that
    /// split the column panels between them, every task taking all rows. Splitting rows
    /// into multiples of 12 leaves such products uneven between the threads (64 rows: tasks
    /// of 12, 12, 12 against 12, 12, 4) and has every task read the whole weight matrix,
    /// which for the last layers of a network (a few pixels, 300 KB–1 MB of weights) is what
    /// takes the time.
    #[cfg(target_arch = "x86_64")]
    fn column_tasks(&self, m: usize) -> Option<usize> {
        let threads = parallel::threads();
        let split = threads > 1
            && m <= COLUMN_SPLIT_MAX_ROWS
            && self.panels.len() >= 2
            && m * self.n * self.k >= MIN_COLUMN_SPLIT_MACS
            && super::gemm_avx2::available();
        split.then(|| self.panels.len().min(2 * threads))
    }

    /// Panels of task `t` of `tasks` (consecutive, as even as the panel count allows).
    fn panel_range(&self, t: usize, tasks: usize) -> std::ops::Range<usize> {
        let p = self.panels.len();
        t * p / tasks..(t + 1) * p / tasks
    }

    /// Rows `0..m` of the product for the panels `panels` only, in row blocks that stay in
    /// the L2 cache, written through `out` (rows `n` apart).
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA; `out` must hold `m · n` writable values that no one
    /// else writes in these panels' columns meanwhile.
    #[cfg(target_arch = "x86_64")]
    #[allow(clippy::too_many_arguments)]
    unsafe fn run_panels_avx2(
        &self,
        a: &[f32],
        lda: usize,
        m: usize,
        epi: Epilogue,
        out: super::gemm_avx2::OutPtr,
        panels: std::ops::Range<usize>,
    ) {
        use super::gemm_avx2::{panel16, panel8, PanelOut};
        let n = self.n;
        assert!(out.len >= m * n && (m == 0 || a.len() >= (m - 1) * lda + self.k));
        // Whole blocks of every micro-kernel (6 and 12 rows with AVX2, 8 with AVX-512): a
        // block of 12 rows would have the 8-row kernel recompute 4 of them.
        let block = (BLOCK_FLOATS / self.k.max(1)).clamp(24, 240) / 24 * 24;
        let mut r0 = 0;
        while r0 < m {
            let rm = block.min(m - r0);
            let epi_block = Epilogue {
                residual: epi.residual.map(|r| &r[r0 * n..(r0 + rm) * n]),
                ..epi
            };
            let out_block = out.skip(r0 * n);
            for p in &self.panels[panels.clone()] {
                let po = PanelOut {
                    n,
                    col: p.col,
                    valid: p.width.min(n - p.col),
                    bias: &self.padded_bias[p.col..p.col + p.width],
                };
                let panel = &self.data[p.offset..p.offset + self.k * p.width];
                let a_block = &a[r0 * lda..];
                if p.width == 16 {
                    panel16(panel, self.k, a_block, lda, rm, po, epi_block, out_block);
                } else {
                    panel8(panel, self.k, a_block, lda, rm, po, epi_block, out_block);
                }
            }
            r0 += rm;
        }
    }

    /// [`Self::run`] on the calling thread.
    pub fn run_serial(&self, a: &[f32], lda: usize, m: usize, epi: Epilogue, out: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        if super::gemm_avx2::available() {
            assert!(out.len() >= m * self.n, "packed gemm: output length");
            let out = super::gemm_avx2::OutPtr::new(out);
            // SAFETY: the CPU has AVX2 and FMA (checked above); `out` is borrowed mutably.
            unsafe { self.run_panels_avx2(a, lda, m, epi, out, 0..self.panels.len()) };
            return;
        }
        let block = (BLOCK_FLOATS / self.k.max(1)).clamp(12, 240) / 12 * 12;
        let mut r0 = 0;
        while r0 < m {
            let rm = block.min(m - r0);
            let epi_block = Epilogue {
                residual: epi.residual.map(|r| &r[r0 * self.n..(r0 + rm) * self.n]),
                ..epi
            };
            let out_block = &mut out[r0 * self.n..(r0 + rm) * self.n];
            gemm_block_portable(self, &a[r0 * lda..], lda, rm, epi_block, out_block);
            r0 += rm;
        }
    }
}

impl PackedGemm {
    /// The number of column panels.
    pub(crate) fn panel_count(&self) -> usize {
        self.panels.len()
    }

    /// Output rows `first..first + m` (`m ≤ 12`) of a product whose input rows are read
    /// through `taps[t][r]`: `k` is `taps.len() · c`, tap `t` of row `r` is the `c` values at
    /// `taps[t][r]`; panels `panels` only (task `t` of `tasks`: [`Self::panel_range`]).
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA, and every pointer in `taps[..][..m]` must
    /// point at `c` readable values; `out` must hold `(first + m) · n` writable values that no
    /// one else writes in these panels' columns meanwhile.
    #[cfg(target_arch = "x86_64")]
    #[allow(clippy::too_many_arguments)]
    pub(crate) unsafe fn run_indirect(
        &self,
        taps: &[[*const f32; 12]],
        c: usize,
        m: usize,
        first: usize,
        epi: Epilogue,
        out: super::gemm_avx2::OutPtr,
        task: Option<(usize, usize)>,
    ) {
        use super::gemm_avx2::{indirect16, indirect8, PanelOut};
        assert!(
            m <= 12 && taps.len() * c == self.k,
            "indirect product: shape"
        );
        let panels = match task {
            Some((t, tasks)) => self.panel_range(t, tasks),
            None => 0..self.panels.len(),
        };
        let mut upper: Vec<[*const f32; 12]> = Vec::new();
        for p in &self.panels[panels] {
            let po = PanelOut {
                n: self.n,
                col: p.col,
                valid: p.width.min(self.n - p.col),
                bias: &self.padded_bias[p.col..p.col + p.width],
            };
            let panel = &self.data[p.offset..p.offset + self.k * p.width];
            if p.width == 8 {
                indirect8(panel, taps, c, m, first, po, epi, out);
                continue;
            }
            indirect16(panel, taps, c, m.min(6), first, po, epi, out);
            if m > 6 {
                if upper.is_empty() {
                    upper = taps
                        .iter()
                        .map(|row| {
                            let mut r = *row;
                            r.rotate_left(6);
                            r
                        })
                        .collect();
                }
                indirect16(panel, &upper, c, m - 6, first + 6, po, epi, out);
            }
        }
    }
}

/// Rows up to which a product on several threads splits its column panels instead of its
/// rows ([`PackedGemm::column_tasks`]).
const COLUMN_SPLIT_MAX_ROWS: usize = 128;

/// Multiply-adds below which a product of few rows runs as one task.
const MIN_COLUMN_SPLIT_MACS: usize = 1 << 16;

/// Rows per task ([`parallel::items_per_task`], rayon tasks of at least [`MIN_TASK_MACS`]), in
/// multiples of 12 rows.
pub(crate) fn rows_per_task(m: usize, macs: usize) -> usize {
    parallel::items_per_task(m, macs, MIN_TASK_MACS, 12)
}

/// All panels over rows `0..m` (one cache block) on the portable loops.
fn gemm_block_portable(
    w: &PackedGemm,
    a: &[f32],
    lda: usize,
    m: usize,
    epi: Epilogue,
    out: &mut [f32],
) {
    for p in &w.panels {
        if p.width == 16 {
            panel_rows::<12, 16, 1>(w, p, a, lda, m, epi, out);
        } else {
            panel_rows::<12, 8, 1>(w, p, a, lda, m, epi, out);
        }
    }
}

/// One panel over rows `0..m` in blocks of `M` (the panel is `NV` vectors of `V` lanes wide);
/// a short last block is moved back to overlap the one before it (recomputing equal values),
/// and a total shorter than `M` is copied into a zero-padded block.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn panel_rows<const M: usize, const V: usize, const NV: usize>(
    w: &PackedGemm,
    p: &Panel,
    a: &[f32],
    lda: usize,
    m: usize,
    epi: Epilogue,
    out: &mut [f32],
) {
    let k = w.k;
    let panel = &w.data[p.offset..p.offset + k * NV * V];
    if m < M {
        let mut padded = vec![0.0f32; M * k];
        for r in 0..m {
            padded[r * k..(r + 1) * k].copy_from_slice(&a[r * lda..r * lda + k]);
        }
        let acc = tile::<M, V, NV>(&padded, k, panel, k);
        store::<M, V, NV>(&acc, w, p, 0, m, epi, out);
        return;
    }
    let mut r0 = 0;
    loop {
        let start = r0.min(m - M);
        let acc = tile::<M, V, NV>(&a[start * lda..], lda, panel, k);
        store::<M, V, NV>(&acc, w, p, start, M, epi, out);
        r0 += M;
        if r0 >= m {
            break;
        }
    }
}

/// `acc += x · b`, lane by lane.
#[inline(always)]
fn fma_lanes<const V: usize>(acc: &mut [f32; V], x: f32, b: &[f32; V]) {
    for (a, &b) in acc.iter_mut().zip(b) {
        *a = x.mul_add(b, *a);
    }
}

/// The `M × (NV·V)` product block of rows `a[r·lda .. r·lda + k]` and a `[k][NV·V]` panel.
/// (This shape — one lane loop per accumulator vector, the panel row read as whole vectors —
/// is what the compiler turns into one broadcast and `NV` vector multiply-adds per row.)
#[inline(always)]
fn tile<const M: usize, const V: usize, const NV: usize>(
    a: &[f32],
    lda: usize,
    panel: &[f32],
    k: usize,
) -> [[[f32; V]; NV]; M] {
    assert!(a.len() >= (M - 1) * lda + k && panel.len() >= k * NV * V);
    let mut acc = [[[0.0f32; V]; NV]; M];
    for p in 0..k {
        // SAFETY: `p·NV·V + NV·V ≤ k·NV·V ≤ panel.len()` (asserted), and `[[f32; V]; NV]` has
        // the layout of `NV·V` consecutive f32 with f32's alignment.
        let b: &[[f32; V]; NV] =
            unsafe { &*(panel.as_ptr().add(p * NV * V) as *const [[f32; V]; NV]) };
        for (r, row) in acc.iter_mut().enumerate() {
            // SAFETY: r·lda + p ≤ (M − 1)·lda + k − 1 < a.len() (asserted above).
            let x = unsafe { *a.get_unchecked(r * lda + p) };
            for (acc, b) in row.iter_mut().zip(b) {
                fma_lanes(acc, x, b);
            }
        }
    }
    acc
}

/// Stores rows `0..rows` of `acc` as output rows `first..first + rows`, panel columns that
/// exist only, through the epilogue.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn store<const M: usize, const V: usize, const NV: usize>(
    acc: &[[[f32; V]; NV]; M],
    w: &PackedGemm,
    p: &Panel,
    first: usize,
    rows: usize,
    epi: Epilogue,
    out: &mut [f32],
) {
    let n = w.n;
    let valid = (NV * V).min(n - p.col);
    let bias = &w.bias[p.col..p.col + valid];
    let (lo1, hi1) = epi.pre.bounds();
    let (lo2, hi2) = epi.post.bounds();
    for (r, acc_row) in acc.iter().enumerate().take(rows) {
        let at = (first + r) * n + p.col;
        if valid == NV * V {
            // whole vectors: fixed-length lane loops
            for (v, acc) in acc_row.iter().enumerate() {
                let o = at + v * V;
                let dst: &mut [f32; V] = (&mut out[o..o + V]).try_into().unwrap();
                let b: &[f32; V] = w.bias[p.col + v * V..p.col + (v + 1) * V]
                    .try_into()
                    .unwrap();
                match epi.residual {
                    Some(res) => {
                        let x: &[f32; V] = res[o..o + V].try_into().unwrap();
                        for l in 0..V {
                            dst[l] = ((acc[l] + b[l]).max(lo1).min(hi1) + x[l]).max(lo2).min(hi2);
                        }
                    }
                    None => {
                        for l in 0..V {
                            dst[l] = (acc[l] + b[l]).max(lo1).min(hi1);
                        }
                    }
                }
            }
            continue;
        }
        let dst = &mut out[at..at + valid];
        let values = acc_row.iter().flatten();
        match epi.residual {
            Some(res) => {
                let res = &res[at..at + valid];
                for (((o, &v), &b), &x) in dst.iter_mut().zip(values).zip(bias).zip(res) {
                    *o = ((v + b).max(lo1).min(hi1) + x).max(lo2).min(hi2);
                }
            }
            None => {
                for ((o, &v), &b) in dst.iter_mut().zip(values).zip(bias) {
                    *o = (v + b).max(lo1).min(hi1);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::nhwc::Activation;

    fn values(n: usize, seed: u32) -> Vec<f32> {
        let mut s = seed.wrapping_mul(2_654_435_761).wrapping_add(1);
        (0..n)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 17;
                s ^= s << 5;
                (s % 2001) as f32 / 1000.0 - 1.0
            })
            .collect()
    }

    /// The product through the straightforward triple loop.
    #[allow(clippy::too_many_arguments)]
    fn reference(
        a: &[f32],
        lda: usize,
        m: usize,
        w: &[f32],
        k: usize,
        n: usize,
        bias: &[f32],
        epi: Epilogue,
    ) -> Vec<f32> {
        let mut out = vec![0.0; m * n];
        for r in 0..m {
            for c in 0..n {
                let mut s = 0.0f64;
                for p in 0..k {
                    s += a[r * lda + p] as f64 * w[c * k + p] as f64;
                }
                let mut v = epi.pre.apply(s as f32 + bias[c]);
                if let Some(res) = epi.residual {
                    v = epi.post.apply(v + res[r * n + c]);
                }
                out[r * n + c] = v;
            }
        }
        out
    }

    fn check(m: usize, k: usize, n: usize, lda: usize) {
        let a = values((m.max(1) - 1) * lda + k, 1);
        let w = values(n * k, 2);
        let bias = values(n, 3);
        let res = values(m * n, 4);
        let packed = PackedGemm::from_rows(&w, k, n, &bias);
        for epi in [
            Epilogue::default(),
            Epilogue {
                pre: Activation::Relu6,
                residual: None,
                post: Activation::None,
            },
            Epilogue {
                pre: Activation::None,
                residual: Some(&res),
                post: Activation::Relu6,
            },
            Epilogue {
                pre: Activation::Relu,
                residual: Some(&res),
                post: Activation::None,
            },
        ] {
            let want = reference(&a, lda, m, &w, k, n, &bias, epi);
            let mut got = vec![f32::NAN; m * n];
            packed.run(&a, lda, m, epi, &mut got);
            let tol = 1e-5 * (k as f32).sqrt().max(1.0);
            for i in 0..m * n {
                assert!(
                    (got[i] - want[i]).abs() <= tol,
                    "m{m} k{k} n{n} lda{lda} at {i}: {} vs {}",
                    got[i],
                    want[i]
                );
            }
            let mut serial = vec![f32::NAN; m * n];
            gemm_block_portable(&packed, &a, lda, m, epi, &mut serial);
            let d = serial
                .iter()
                .zip(&want)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f32::max);
            assert!(d <= tol, "portable m{m} k{k} n{n}: {d}");
        }
    }

    #[test]
    fn products_match_the_triple_loop_over_odd_shapes() {
        for (m, k, n) in [
            (1, 1, 1),
            (5, 3, 2),
            (11, 7, 8),
            (12, 16, 16),
            (13, 24, 24),
            (37, 17, 40),
            (100, 64, 88),
            (6, 288, 195),
            (250, 144, 33),
            (700, 8, 8),
            (1, 1152, 117),
            (2, 300, 40),
            (64, 864, 288),
            (4, 288, 288),
        ] {
            check(m, k, n, k);
        }
        check(29, 10, 20, 13);
    }

    #[test]
    fn parallel_tasks_give_the_serial_result() {
        let (m, k, n) = (3001, 96, 48);
        let a = values(m * k, 5);
        let w = values(n * k, 6);
        let packed = PackedGemm::from_rows(&w, k, n, &values(n, 7));
        let mut serial = vec![0.0; m * n];
        packed.run_serial(&a, k, m, Epilogue::default(), &mut serial);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        let mut par = vec![0.0; m * n];
        pool.install(|| packed.run(&a, k, m, Epilogue::default(), &mut par));
        assert_eq!(serial, par);
    }
}
