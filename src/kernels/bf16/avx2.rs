//! The AVX2 + FMA micro-kernel, for x86-64 CPUs without AVX512-BF16: the portable kernel's
//! sums (f32 products of the bf16 values, f32 accumulation) with eight-lane fused
//! multiply-adds, in register blocks of up to 4 rows × 16 columns. A packed pair of bf16
//! weights becomes two f32 vectors with one shift and one mask (a bf16 is the top half of an
//! f32); each row's pairs are widened to f32 once per tile.

use super::{bf16_bits_to_f32, KC_PAIRS, NR};
use std::arch::x86_64::*;

/// Whether this CPU runs the kernel (AVX2 and FMA).
pub fn available() -> bool {
    is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
}

/// Rows per register block.
const ROWS: usize = 4;
/// Columns per register block (two 8-lane vectors).
const COLS: usize = 16;

/// `C[rows × cols] += A · Bᵀ` (or `=` when `add` is false) for one tile, as
/// [`super::portable::tile`].
///
/// # Safety
/// As [`super::portable::tile`], with `kc ≤ KC_PAIRS`; the CPU must have AVX2 and FMA
/// ([`available`]).
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx2,fma")]
pub unsafe fn tile(
    rows: usize,
    kc: usize,
    a: &[u32],
    lda: usize,
    b: &[u16],
    c: *mut f32,
    ldc: usize,
    cols: usize,
    add: bool,
) {
    assert!(kc <= KC_PAIRS && cols <= NR);
    let b = &b[..kc * NR * 2];
    let mut r0 = 0;
    while r0 < rows {
        let n = (rows - r0).min(ROWS);
        // Each row's pairs as f32: [k even, k odd] per pair.
        let mut widened = [[0f32; 2 * KC_PAIRS]; ROWS];
        for (r, row) in widened.iter_mut().enumerate().take(n) {
            let src = &a[(r0 + r) * lda..(r0 + r) * lda + kc];
            for (dst, &pair) in row.chunks_exact_mut(2).zip(src) {
                dst[0] = bf16_bits_to_f32(pair as u16);
                dst[1] = bf16_bits_to_f32((pair >> 16) as u16);
            }
        }
        let c_rows = c.add(r0 * ldc);
        let mut col = 0;
        while col < cols {
            // SAFETY: `b` holds `kc` pairs of `NR` columns; `c_rows` rows `0..n` hold `cols`
            // values each (caller).
            unsafe {
                match n {
                    4 => block::<4>(&widened, kc, b, col, c_rows, ldc, cols, add),
                    3 => block::<3>(&widened, kc, b, col, c_rows, ldc, cols, add),
                    2 => block::<2>(&widened, kc, b, col, c_rows, ldc, cols, add),
                    _ => block::<1>(&widened, kc, b, col, c_rows, ldc, cols, add),
                }
            }
            col += COLS;
        }
        r0 += n;
    }
}

/// Rows `0..R` × columns `col..col + 16` (those below `cols` stored) of the tile.
///
/// # Safety
/// As [`tile`].
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx2,fma")]
unsafe fn block<const R: usize>(
    widened: &[[f32; 2 * KC_PAIRS]; ROWS],
    kc: usize,
    b: &[u16],
    col: usize,
    c: *mut f32,
    ldc: usize,
    cols: usize,
    add: bool,
) {
    let high = _mm256_set1_epi32(0xFFFF_0000u32 as i32);
    let mut acc = [[_mm256_setzero_ps(); 2]; R];
    for p in 0..kc {
        // Columns col..col+8 and col+8..col+16 of pair p: each u32 lane holds (k even, k odd).
        let at = b.as_ptr().add(p * NR * 2 + col * 2) as *const __m256i;
        let (x0, x1) = (_mm256_loadu_si256(at), _mm256_loadu_si256(at.add(1)));
        let (b0e, b0o) = (
            _mm256_castsi256_ps(_mm256_slli_epi32::<16>(x0)),
            _mm256_castsi256_ps(_mm256_and_si256(x0, high)),
        );
        let (b1e, b1o) = (
            _mm256_castsi256_ps(_mm256_slli_epi32::<16>(x1)),
            _mm256_castsi256_ps(_mm256_and_si256(x1, high)),
        );
        for (r, acc) in acc.iter_mut().enumerate() {
            let ae = _mm256_broadcast_ss(&widened[r][2 * p]);
            let ao = _mm256_broadcast_ss(&widened[r][2 * p + 1]);
            acc[0] = _mm256_fmadd_ps(ae, b0e, acc[0]);
            acc[0] = _mm256_fmadd_ps(ao, b0o, acc[0]);
            acc[1] = _mm256_fmadd_ps(ae, b1e, acc[1]);
            acc[1] = _mm256_fmadd_ps(ao, b1o, acc[1]);
        }
    }
    let width = COLS.min(cols - col);
    for (r, acc) in acc.iter().enumerate() {
        let out = c.add(r * ldc + col);
        if width == COLS {
            for (h, v) in acc.iter().enumerate() {
                let o = out.add(8 * h);
                let v = if add {
                    _mm256_add_ps(_mm256_loadu_ps(o), *v)
                } else {
                    *v
                };
                _mm256_storeu_ps(o, v);
            }
        } else {
            let mut sums = [0f32; COLS];
            _mm256_storeu_ps(sums.as_mut_ptr(), acc[0]);
            _mm256_storeu_ps(sums.as_mut_ptr().add(8), acc[1]);
            // SAFETY: `width` values of this row lie below `cols` (caller).
            let row = std::slice::from_raw_parts_mut(out, width);
            if add {
                for (o, s) in row.iter_mut().zip(sums) {
                    *o += s;
                }
            } else {
                row.copy_from_slice(&sums[..width]);
            }
        }
    }
}
