//! The blocked bf16 product `out += A · Bᵀ` or `out = A · Bᵀ` (f32 output) over a
//! [`PackedRhs`].
//!
//! Work is cut into tasks of up to [`MC`] rows × a range of [`NR`]-column tiles (rayon runs
//! them when the product is large enough); inside a task, for each block of [`KC_PAIRS`] pairs
//! of `k`, the task's rows are rounded to bf16 into a small buffer, then every tile of the right
//! operand is multiplied by every [`MR`]-row slice of that buffer with the micro-kernel.

use std::mem::MaybeUninit;
use std::ops::Range;

use rayon::prelude::*;

use super::pack::{convert_portable, PackedRhs};
use super::{portable, Kernel, KC_PAIRS, MC, MR, NR};

/// Products smaller than this many multiply-adds run on one thread (as `linear`).
const PARALLEL_MIN_MACS: usize = 1 << 18;
/// Right operands up to this size (bytes of bf16) are read whole by every row task of the tile
/// kernel: about one core's L2 cache.
const ROW_TASK_RHS_BYTES: usize = 2 << 20;
/// Tasks per thread a parallel product aims for (load balance against re-converting rows).
const TASKS_PER_THREAD: usize = 8;

/// The left operand: `m` rows of `k` values, row `i` from `i·ld`.
#[derive(Debug, Clone, Copy)]
pub enum Lhs<'a> {
    /// f32 values, rounded to bf16 as the product runs.
    F32 {
        /// The values.
        data: &'a [f32],
        /// Distance between rows.
        ld: usize,
    },
    /// bf16 values.
    Bf16 {
        /// The values.
        data: &'a [half::bf16],
        /// Distance between rows.
        ld: usize,
    },
}

impl Lhs<'_> {
    fn len_ld(&self) -> (usize, usize) {
        match self {
            Lhs::F32 { data, ld } => (data.len(), *ld),
            Lhs::Bf16 { data, ld } => (data.len(), *ld),
        }
    }
}

/// Whether a product adds to the output or replaces it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Store {
    /// `out += A · Bᵀ`.
    Accumulate,
    /// `out = A · Bᵀ`: the old values are never read, so `out` may start uninitialised (no
    /// zeroing pass over memory before the product).
    Overwrite,
}

/// A part of a [`PackedRhs`]: `n` output columns from tile `tile0`, `k` values of the inner
/// dimension from pair `pair0`.
#[derive(Debug, Clone, Copy)]
pub struct RhsView<'a> {
    rhs: &'a PackedRhs,
    tile0: usize,
    n: usize,
    pair0: usize,
    k: usize,
}

impl PackedRhs {
    /// The whole operand.
    pub fn view(&self) -> RhsView<'_> {
        RhsView {
            rhs: self,
            tile0: 0,
            n: self.n(),
            pair0: 0,
            k: self.k(),
        }
    }
}

impl<'a> RhsView<'a> {
    /// Output columns `start..start + len` of this view (`start` a multiple of [`NR`]).
    pub fn columns(self, start: usize, len: usize) -> candle_core::Result<Self> {
        if start % NR != 0 || start + len > self.n {
            candle_core::bail!(
                "bf16 gemm: columns {start}..{} of {} (start must be a multiple of {NR})",
                start + len,
                self.n
            );
        }
        Ok(Self {
            tile0: self.tile0 + start / NR,
            n: len,
            ..self
        })
    }

    /// Inner values `start..start + len` of this view (`start` even). Padding inside the last
    /// pair is multiplied by the zeros the left operand is padded with.
    pub fn depth(self, start: usize, len: usize) -> candle_core::Result<Self> {
        if start % 2 != 0 || start + len > self.k {
            candle_core::bail!(
                "bf16 gemm: inner range {start}..{} of {} (start must be even)",
                start + len,
                self.k
            );
        }
        Ok(Self {
            pair0: self.pair0 + start / 2,
            k: len,
            ..self
        })
    }

    /// Output columns.
    pub fn n(&self) -> usize {
        self.n
    }

    /// Inner size.
    pub fn k(&self) -> usize {
        self.k
    }

    /// Packed tile `tile` of the view from its pair `pair` on.
    fn tile(&self, tile: usize, pair: usize) -> &'a [u16] {
        self.rhs.tile(self.tile0 + tile, self.pair0 + pair)
    }
}

/// `out[i·ldc + j] += Σ_t A[i, t] · B[j, t]` for `i < m`, `j < rhs.n()`, `t < rhs.k()` with the
/// kernel [`Kernel::detect`] picks; `parallel` lets large products use the rayon pool.
pub fn gemm(
    lhs: Lhs,
    m: usize,
    rhs: RhsView,
    out: &mut [f32],
    ldc: usize,
    parallel: bool,
) -> candle_core::Result<()> {
    gemm_with(Kernel::detect(), lhs, m, rhs, out, ldc, parallel)
}

/// `out[i·ldc + j] = Σ_t A[i, t] · B[j, t]`: as [`gemm`], but the old values of the `m × n`
/// output are never read.
pub fn gemm_overwrite(
    lhs: Lhs,
    m: usize,
    rhs: RhsView,
    out: &mut [f32],
    ldc: usize,
    parallel: bool,
) -> candle_core::Result<()> {
    let kernel = Kernel::detect();
    let out = (OutPtr(out.as_mut_ptr()), out.len());
    run(
        kernel,
        Store::Overwrite,
        lhs,
        m,
        rhs,
        out,
        ldc,
        parallel,
        None,
    )
}

/// The output pointer shared by the tasks, which write disjoint rectangles.
#[derive(Clone, Copy)]
struct OutPtr(*mut f32);
// SAFETY: tasks write disjoint (row range × column range) rectangles of the output (see
// `gemm_with`), so sharing the base pointer between threads never makes two writers meet.
unsafe impl Send for OutPtr {}
unsafe impl Sync for OutPtr {}

/// Work on finished output, `f(row, first_column, values)`: called once for every row segment
/// of a task's rectangle as soon as its products are complete (still in the cache), with the
/// values of that row from `first_column` on, which it may change in place.
pub type RowEpilogue<'a> = &'a (dyn Fn(usize, usize, &mut [f32]) + Sync);

/// [`gemm`] with an explicit micro-kernel (errors if the CPU lacks it).
pub fn gemm_with(
    kernel: Kernel,
    lhs: Lhs,
    m: usize,
    rhs: RhsView,
    out: &mut [f32],
    ldc: usize,
    parallel: bool,
) -> candle_core::Result<()> {
    let out = (OutPtr(out.as_mut_ptr()), out.len());
    run(
        kernel,
        Store::Accumulate,
        lhs,
        m,
        rhs,
        out,
        ldc,
        parallel,
        None,
    )
}

/// `out = A · Bᵀ` into memory not yet initialised, followed, task by task, by `epilogue` on
/// every output row segment (each `(row, column)` of the `m × rhs.n()` output is passed exactly
/// once): afterwards the values at `i·ldc + j` for `i < m`, `j < rhs.n()` are initialised (the
/// gaps between rows are not touched).
#[allow(clippy::too_many_arguments)]
pub fn gemm_uninit(
    kernel: Kernel,
    lhs: Lhs,
    m: usize,
    rhs: RhsView,
    out: &mut [MaybeUninit<f32>],
    ldc: usize,
    parallel: bool,
    epilogue: Option<RowEpilogue>,
) -> candle_core::Result<()> {
    let out = (OutPtr(out.as_mut_ptr().cast()), out.len());
    run(
        kernel,
        Store::Overwrite,
        lhs,
        m,
        rhs,
        out,
        ldc,
        parallel,
        epilogue,
    )
}

/// The product behind the public entry points, on an output of `len` values at `ptr`: only
/// the `m × n` values are touched, each by one task, and (in [`Store::Overwrite`]) written
/// before anything reads them.
#[allow(clippy::too_many_arguments)]
fn run(
    kernel: Kernel,
    store: Store,
    lhs: Lhs,
    m: usize,
    rhs: RhsView,
    (ptr, out_len): (OutPtr, usize),
    ldc: usize,
    parallel: bool,
    epilogue: Option<RowEpilogue>,
) -> candle_core::Result<()> {
    let (n, k) = (rhs.n, rhs.k);
    if !kernel.runs_here() {
        candle_core::bail!(
            "bf16 gemm: this CPU cannot run the {} kernel",
            kernel.name()
        );
    }
    if m == 0 || n == 0 {
        return Ok(());
    }
    let (len, ld) = lhs.len_ld();
    if k > 0 && (m - 1) * ld + k > len {
        candle_core::bail!(
            "bf16 gemm: left operand of {len} values is too short for {m}×{k} with rows {ld} apart"
        );
    }
    if ldc < n || (m - 1) * ldc + n > out_len {
        candle_core::bail!(
            "bf16 gemm: output of {out_len} values is too short for {m}×{n} with rows {ldc} apart"
        );
    }
    let tiles = n.div_ceil(NR);
    let row_blocks = m.div_ceil(MC);
    let threads = rayon::current_num_threads();
    let parallel = parallel && threads > 1 && m * n * k.max(1) >= PARALLEL_MIN_MACS;
    // Tasks of equal size: row blocks of at most MC rows (multiples of MR), and tiles
    // split so that there are at least TASKS_PER_THREAD tasks per thread when the size allows.
    let converts = direct_pairs(lhs, k).is_none();
    let row_tasks_fit = converts || n * k * 2 <= ROW_TASK_RHS_BYTES;
    let (row_block, tiles_per_task) =
        if parallel && kernel == Kernel::Amx && row_tasks_fit && m >= 64 * threads {
            // The tile kernel converts f32 rows faster than it multiplies only when each row is
            // converted once: tasks take every column of a block of rows (multiples of 32). Rows
            // read in place (bf16) split the columns instead, so that each task's right-operand
            // tiles are reused by many rows (ViT-B/14 at 224 px, 2 threads: 93 against 102–112 ms).
            let want = m.div_ceil(TASKS_PER_THREAD * threads).next_multiple_of(32);
            (want.clamp(32, MC), tiles)
        } else if parallel {
            // Whole 32-row tile pairs for the tile kernel (its edge rows take the slower
            // vector kernel), whole micro-kernel rows otherwise.
            let rows_step = if kernel == Kernel::Amx { 32 } else { MR };
            let row_block = m.div_ceil(row_blocks).next_multiple_of(rows_step);
            let col_tasks = (TASKS_PER_THREAD * threads).div_ceil(row_blocks).min(tiles);
            (row_block, tiles.div_ceil(col_tasks))
        } else {
            (m, tiles)
        };
    let row_tasks = m.div_ceil(row_block);
    let col_tasks = tiles.div_ceil(tiles_per_task);
    let task = |i: usize| {
        let (rt, ct) = (i / col_tasks, i % col_tasks);
        let rows = rt * row_block..m.min((rt + 1) * row_block);
        let tiles = ct * tiles_per_task..tiles.min((ct + 1) * tiles_per_task);
        let columns = tiles.start * NR..n.min(tiles.end * NR);
        if k > 0 {
            // SAFETY: rows < m and the tiles' columns < n lie inside `out` (checked above), and
            // the (rows × tiles) rectangles of different `i` are disjoint.
            unsafe { run_task(kernel, store, lhs, rows.clone(), rhs, tiles, ptr, ldc) };
        } else if store == Store::Overwrite {
            for row in rows.clone() {
                // SAFETY: as above; this task alone touches these values.
                unsafe {
                    std::ptr::write_bytes(ptr.0.add(row * ldc + columns.start), 0, columns.len())
                };
            }
        }
        if let Some(epilogue) = epilogue {
            for row in rows {
                // SAFETY: as above; this task alone touches these values.
                let values = unsafe {
                    std::slice::from_raw_parts_mut(
                        ptr.0.add(row * ldc + columns.start),
                        columns.len(),
                    )
                };
                epilogue(row, columns.start, values);
            }
        }
    };
    if parallel && row_tasks * col_tasks > 1 {
        (0..row_tasks * col_tasks).into_par_iter().for_each(task);
    } else {
        (0..row_tasks * col_tasks).for_each(task);
    }
    Ok(())
}

/// Rounds rows `rows` of `lhs`, pairs `pairs` (values past `k` zero), into `buf` (rows of
/// `pairs.len()` pairs).
fn pack_lhs(
    kernel: Kernel,
    lhs: Lhs,
    rows: Range<usize>,
    pairs: Range<usize>,
    k: usize,
    buf: &mut [u32],
) {
    let kc = pairs.len();
    let t0 = 2 * pairs.start;
    let t1 = k.min(2 * pairs.end);
    for (r, i) in rows.enumerate() {
        let dst: &mut [u16] = bytemuck::cast_slice_mut(&mut buf[r * kc..(r + 1) * kc]);
        let (dst, pad) = dst.split_at_mut(t1 - t0);
        pad.fill(0);
        match lhs {
            Lhs::Bf16 { data, ld } => {
                let src: &[u16] = bytemuck::cast_slice(&data[i * ld + t0..i * ld + t1]);
                dst.copy_from_slice(src);
            }
            Lhs::F32 { data, ld } => {
                let src = &data[i * ld + t0..i * ld + t1];
                match kernel {
                    // SAFETY: `gemm_with` checked that the CPU has AVX512-BF16.
                    #[cfg(all(target_arch = "x86_64", lhmpp_bf16_intrinsics))]
                    Kernel::Avx512Bf16 | Kernel::Amx => unsafe { super::avx512::convert(src, dst) },
                    _ => convert_portable(src, dst),
                }
            }
        }
    }
}

/// One task: `rows × tiles` of the output.
///
/// # Safety
/// `out` must be valid for reads and writes at `i·ldc + j` for the task's rows `i` and the
/// columns `j < rhs.n` of its tiles, touched by no other task; the kernel must run on this CPU.
#[allow(clippy::too_many_arguments)]
unsafe fn run_task(
    kernel: Kernel,
    store: Store,
    lhs: Lhs,
    rows: Range<usize>,
    rhs: RhsView,
    tiles: Range<usize>,
    out: OutPtr,
    ldc: usize,
) {
    let pairs = rhs.k.div_ceil(2);
    let direct = direct_pairs(lhs, rhs.k);
    let mut buf = match direct {
        Some(_) => Vec::new(),
        None => vec![0u32; MC.min(rows.len()) * kc_pairs(kernel).min(pairs)],
    };
    // SAFETY: `gemm_with` checked that the CPU runs the AMX kernel.
    #[cfg(all(target_arch = "x86_64", lhmpp_bf16_intrinsics))]
    let tiles_amx = (kernel == Kernel::Amx).then(|| unsafe { super::amx::Tiles::load() });
    let mut pc = 0;
    while pc < pairs {
        let kc = kc_pairs(kernel).min(pairs - pc);
        let add = store == Store::Accumulate || pc > 0;
        let mut ic = rows.start;
        while ic < rows.end {
            let mc = MC.min(rows.end - ic);
            // Row `ir` of the block: its pairs from `pc` on, rows `lda` pairs apart.
            let (block, lda): (&[u32], usize) = match direct {
                Some((pairs_in_place, lda)) => (&pairs_in_place[ic * lda + pc..], lda),
                None => {
                    pack_lhs(kernel, lhs, ic..ic + mc, pc..pc + kc, rhs.k, &mut buf);
                    (&buf, kc)
                }
            };
            for t in tiles.clone() {
                let b = rhs.tile(t, pc);
                let col = t * NR;
                let cols = NR.min(rhs.n - col);
                #[cfg(all(target_arch = "x86_64", lhmpp_bf16_intrinsics))]
                if let Some(amx) = &tiles_amx {
                    assert!(block.len() >= (mc - 1) * lda + kc && b.len() >= kc * NR * 2);
                    let c = out.0.add(ic * ldc + col);
                    amx.tile(mc, kc, block.as_ptr(), lda, b.as_ptr(), c, ldc, cols, add);
                    continue;
                }
                let mut ir = 0;
                while ir < mc {
                    let r = MR.min(mc - ir);
                    let a = &block[ir * lda..];
                    let c = out.0.add((ic + ir) * ldc + col);
                    match kernel {
                        #[cfg(all(target_arch = "x86_64", lhmpp_bf16_intrinsics))]
                        Kernel::Avx512Bf16 | Kernel::Amx => {
                            assert!(a.len() >= (r - 1) * lda + kc && b.len() >= kc * NR * 2);
                            super::avx512::tile(
                                r,
                                kc,
                                a.as_ptr(),
                                lda,
                                b.as_ptr(),
                                c,
                                ldc,
                                cols,
                                add,
                            )
                        }
                        // SAFETY: `gemm_with` checked that the CPU runs the AVX2 kernel;
                        // `kc ≤ KC_PAIRS` for every kernel but AMX.
                        #[cfg(target_arch = "x86_64")]
                        Kernel::Avx2 => super::avx2::tile(r, kc, a, lda, b, c, ldc, cols, add),
                        _ => portable::tile(r, kc, a, lda, b, c, ldc, cols, add),
                    }
                    ir += r;
                }
            }
            ic += mc;
        }
        pc += kc;
    }
}

/// Pairs of `k` per block for `kernel`: the tile kernel loads and stores its output tiles once
/// per block, so it takes deeper blocks (measured on 1024³ and ViT-L MLP shapes at 2 threads:
/// 256 pairs 7–15 % faster than 128, 512 no better).
fn kc_pairs(kernel: Kernel) -> usize {
    if kernel == Kernel::Amx {
        2 * KC_PAIRS
    } else {
        KC_PAIRS
    }
}

/// A bf16 left operand as pairs the micro-kernel reads in place, with the distance between
/// rows in pairs: when `k` and the row distance are even and the values are 4-byte aligned
/// (otherwise its rows are copied into a buffer, the last pair of an odd `k` padded with zero).
fn direct_pairs(lhs: Lhs<'_>, k: usize) -> Option<(&[u32], usize)> {
    let Lhs::Bf16 { data, ld } = lhs else {
        return None;
    };
    if ld % 2 != 0 || k % 2 != 0 {
        return None;
    }
    let even = data.len() & !1;
    bytemuck::try_cast_slice::<half::bf16, u32>(&data[..even])
        .ok()
        .map(|pairs| (pairs, ld / 2))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::bf16::bf16_bits_to_f32;
    use crate::kernels::bf16::f32_to_bf16_bits;

    fn values(n: usize, seed: u64) -> Vec<f32> {
        let mut s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
        (0..n)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                ((s >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) as f32
            })
            .collect()
    }

    fn round(v: f32) -> f64 {
        bf16_bits_to_f32(f32_to_bf16_bits(v)) as f64
    }

    /// `init + A Bᵀ` in f64 on the bf16-rounded values, and the bound `Σ|a·b|` per output.
    fn reference(
        a: &[f32],
        w: &[f32],
        init: &[f32],
        m: usize,
        n: usize,
        k: usize,
    ) -> (Vec<f64>, Vec<f64>) {
        let mut out = vec![0f64; m * n];
        let mut mag = vec![0f64; m * n];
        for i in 0..m {
            for j in 0..n {
                let mut s = init[i * n + j] as f64;
                let mut g = 0.0;
                for t in 0..k {
                    let p = round(a[i * k + t]) * round(w[j * k + t]);
                    s += p;
                    g += p.abs();
                }
                out[i * n + j] = s;
                mag[i * n + j] = g + (init[i * n + j] as f64).abs();
            }
        }
        (out, mag)
    }

    fn kernels() -> Vec<Kernel> {
        Kernel::available()
    }

    #[test]
    fn products_match_an_f64_reference_over_odd_shapes() {
        for &(m, n, k) in &[
            (1, 1, 1),
            (1, 70, 33),
            (5, 16, 2),
            (7, 63, 31),
            (13, 129, 257),
            (97, 65, 300),
            (200, 130, 64),
            (3, 200, 1),
        ] {
            let a = values(m * k, 1 + m as u64);
            let w = values(n * k, 2 + n as u64);
            let init = values(m * n, 3);
            let (want, mag) = reference(&a, &w, &init, m, n, k);
            let packed = PackedRhs::from_rows(&w, n, k).unwrap();
            let a16: Vec<half::bf16> = a.iter().map(|&v| half::bf16::from_f32(v)).collect();
            for kernel in kernels() {
                for lhs in [
                    Lhs::F32 { data: &a, ld: k },
                    Lhs::Bf16 { data: &a16, ld: k },
                ] {
                    for parallel in [false, true] {
                        let mut out = init.clone();
                        gemm_with(kernel, lhs, m, packed.view(), &mut out, n, parallel).unwrap();
                        for (idx, (&o, (&w, &g))) in
                            out.iter().zip(want.iter().zip(&mag)).enumerate()
                        {
                            // f32 accumulation: a few ulp of the sum of magnitudes per step.
                            let tol = 1e-6 * (k as f64 + 2.0) * g + 1e-30;
                            assert!(
                                (o as f64 - w).abs() <= tol,
                                "{kernel:?} {m}×{n}×{k} at {idx}: {o} vs {w} (tol {tol})"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn the_portable_kernel_agrees_with_the_fast_ones() {
        // 37 rows: one 32-row block of AMX tiles and five edge rows; k = 515: 257 whole pairs
        // past the last 16-pair step of the tiles, and a half-padded last pair; 150 columns: a
        // part-filled last column group.
        let (m, n, k) = (37, 150, 515);
        let a = values(m * k, 11);
        let w = values(n * k, 12);
        let packed = PackedRhs::from_rows(&w, n, k).unwrap();
        let lhs = Lhs::F32 { data: &a, ld: k };
        let mut slow = vec![0f32; m * n];
        gemm_with(Kernel::Portable, lhs, m, packed.view(), &mut slow, n, false).unwrap();
        let scale = slow.iter().map(|v| v.abs()).fold(0.0, f32::max);
        let fast_kernels: Vec<Kernel> = kernels()
            .into_iter()
            .filter(|&k| k != Kernel::Portable)
            .collect();
        if fast_kernels.is_empty() {
            eprintln!("no AVX512-BF16 on this CPU: the portable kernel is tested against f64 only");
        }
        for kernel in fast_kernels {
            let mut fast = vec![0f32; m * n];
            gemm_with(kernel, lhs, m, packed.view(), &mut fast, n, true).unwrap();
            let worst = fast
                .iter()
                .zip(&slow)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f32::max);
            assert!(worst <= 1e-5 * scale, "{kernel:?}: {worst} of {scale}");
        }
        // Both differ from the f32 product of the unrounded values by bf16 rounding only.
        let exact: f32 = (0..k).map(|t| a[t] * w[t]).sum();
        assert!(
            (slow[0] - exact).abs() < 0.05 * scale,
            "{} vs {exact}",
            slow[0]
        );
    }

    #[test]
    fn views_select_columns_and_depth() {
        let (m, n, k) = (9, 200, 40);
        let a = values(m * k, 5);
        let w = values(n * k, 6);
        let packed = PackedRhs::from_rows(&w, n, k).unwrap();
        // Columns 64..164, inner values 6..29 (odd length: the last pair is half padding).
        let view = packed
            .view()
            .columns(64, 100)
            .unwrap()
            .depth(6, 23)
            .unwrap();
        let mut out = vec![0f32; m * 100];
        gemm(
            Lhs::F32 {
                data: &a[6..],
                ld: k,
            },
            m,
            view,
            &mut out,
            100,
            false,
        )
        .unwrap();
        for i in 0..m {
            for j in 0..100 {
                let want: f64 = (6..29)
                    .map(|t| round(a[i * k + t]) * round(w[(64 + j) * k + t]))
                    .sum();
                assert!((out[i * 100 + j] as f64 - want).abs() < 1e-4, "{i},{j}");
            }
        }
        assert!(packed.view().columns(10, 5).is_err());
        assert!(packed.view().depth(3, 2).is_err());
        assert!(packed.view().depth(0, 41).is_err());
    }

    #[test]
    fn bad_sizes_are_errors_naming_the_op() {
        let w = values(8 * 4, 1);
        let packed = PackedRhs::from_rows(&w, 8, 4).unwrap();
        let a = vec![0f32; 7];
        let mut out = vec![0f32; 16];
        let e = gemm(
            Lhs::F32 { data: &a, ld: 4 },
            2,
            packed.view(),
            &mut out,
            8,
            false,
        )
        .unwrap_err();
        assert!(e.to_string().contains("bf16 gemm"), "{e}");
        let a = vec![0f32; 8];
        let e = gemm(
            Lhs::F32 { data: &a, ld: 4 },
            2,
            packed.view(),
            &mut out[..15],
            8,
            false,
        )
        .unwrap_err();
        assert!(e.to_string().contains("bf16 gemm"), "{e}");
    }

    #[test]
    fn bf16_rows_read_in_place_equal_rows_copied() {
        let (m, n, k) = (23, 70, 64);
        let a: Vec<half::bf16> = values(m * k, 8)
            .into_iter()
            .map(half::bf16::from_f32)
            .collect();
        let w = values(n * k, 9);
        let packed = PackedRhs::from_rows(&w, n, k).unwrap();
        // The same values one element further: misaligned for pairs, so they are copied.
        let mut shifted = vec![half::bf16::ZERO; m * k + 1];
        shifted[1..].copy_from_slice(&a);
        assert!(direct_pairs(Lhs::Bf16 { data: &a, ld: k }, k).is_some());
        assert!(direct_pairs(
            Lhs::Bf16 {
                data: &shifted[1..],
                ld: k
            },
            k
        )
        .is_none());
        for kernel in kernels() {
            let mut in_place = vec![0f32; m * n];
            let mut copied = vec![0f32; m * n];
            gemm_with(
                kernel,
                Lhs::Bf16 { data: &a, ld: k },
                m,
                packed.view(),
                &mut in_place,
                n,
                false,
            )
            .unwrap();
            let lhs = Lhs::Bf16 {
                data: &shifted[1..],
                ld: k,
            };
            gemm_with(kernel, lhs, m, packed.view(), &mut copied, n, false).unwrap();
            assert_eq!(in_place, copied, "{kernel:?}");
        }
    }

    #[test]
    fn the_epilogue_sees_every_output_once_after_its_product() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        for &(m, n, k) in &[(700, 300, 130), (5, 70, 0), (1, 1, 3)] {
            let a = values(m * k, 3);
            let w = values(n * k, 4);
            let packed = PackedRhs::from_rows(&w, n, k).unwrap();
            let mut plain = vec![0f32; m * n];
            let lhs = Lhs::F32 { data: &a, ld: k };
            gemm(lhs, m, packed.view(), &mut plain, n, true).unwrap();
            let seen: Vec<AtomicUsize> = (0..m * n).map(|_| AtomicUsize::new(0)).collect();
            let epilogue = |row: usize, col: usize, v: &mut [f32]| {
                for (j, x) in v.iter_mut().enumerate() {
                    assert_eq!(
                        *x,
                        plain[row * n + col + j],
                        "epilogue before the product ended"
                    );
                    seen[row * n + col + j].fetch_add(1, Ordering::Relaxed);
                    *x = -1.0;
                }
            };
            let mut out = vec![MaybeUninit::new(0f32); m * n];
            let kernel = Kernel::detect();
            let view = packed.view();
            gemm_uninit(kernel, lhs, m, view, &mut out, n, true, Some(&epilogue)).unwrap();
            assert!(
                seen.iter().all(|c| c.load(Ordering::Relaxed) == 1),
                "{m}×{n}×{k}"
            );
            // SAFETY: the values were initialised (zeros) before the product.
            assert!(out.iter().all(|x| unsafe { x.assume_init() } == -1.0));
        }
    }

    #[test]
    fn overwriting_ignores_the_old_output_and_equals_adding_to_zeros() {
        // The old output is NaN: any read of it would show in the result.
        // Shapes with AMX tiles, edge rows and columns, k tails past whole tiles, several
        // k blocks (k = 1100 > 2·256 pairs), and k = 0 (the output becomes zeros).
        for &(m, n, k) in &[(37, 70, 515), (64, 33, 1100), (5, 16, 2), (3, 40, 0)] {
            let a = values(m * k, 7);
            let w = values(n * k, 8);
            let packed = PackedRhs::from_rows(&w, n, k).unwrap();
            let lhs = Lhs::F32 { data: &a, ld: k };
            for kernel in kernels() {
                for parallel in [false, true] {
                    let mut added = vec![0f32; m * n];
                    gemm_with(kernel, lhs, m, packed.view(), &mut added, n, parallel).unwrap();
                    // NaN everywhere, and a stride wider than a row: the gap keeps its NaN.
                    let ldc = n + 3;
                    let mut written = vec![MaybeUninit::new(f32::NAN); (m - 1) * ldc + n];
                    let view = packed.view();
                    gemm_uninit(kernel, lhs, m, view, &mut written, ldc, parallel, None).unwrap();
                    // SAFETY: every value was initialised (NaN) before the product.
                    let written: Vec<f32> =
                        written.iter().map(|x| unsafe { x.assume_init() }).collect();
                    for i in 0..m {
                        assert_eq!(
                            &written[i * ldc..i * ldc + n],
                            &added[i * n..(i + 1) * n],
                            "{kernel:?} {m}×{n}×{k} row {i}"
                        );
                        if i + 1 < m {
                            assert!(written[i * ldc + n..(i + 1) * ldc]
                                .iter()
                                .all(|v| v.is_nan()));
                        }
                    }
                }
            }
        }
    }
}
