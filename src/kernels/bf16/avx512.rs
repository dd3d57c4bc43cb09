//! The AVX512-BF16 micro-kernel and row conversion. Every `unsafe fn` here needs a CPU with
//! `avx512f` and `avx512bf16`: callers check [`available`] first.
//!
//! The intrinsics are stable since Rust 1.89, newer than the crate's minimum: the module is
//! compiled only when the build script found such a compiler (`lhmpp_bf16_intrinsics`).
#![allow(clippy::incompatible_msrv)]

use std::arch::x86_64::*;

use super::NR;

/// Whether the CPU has AVX512F and AVX512-BF16 (`vdpbf16ps`, `vcvtneps2bf16`).
pub fn available() -> bool {
    std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512bf16")
}

/// Rounds `src` to bf16 (nearest, ties to even) into `dst`, 16 values per instruction.
///
/// # Safety
/// The CPU must have AVX512F and AVX512-BF16.
#[target_feature(enable = "avx512f,avx512bf16")]
pub unsafe fn convert(src: &[f32], dst: &mut [u16]) {
    let n = src.len().min(dst.len());
    let mut i = 0;
    while i + 16 <= n {
        let v = _mm512_loadu_ps(src.as_ptr().add(i));
        let h: __m256i = std::mem::transmute(_mm512_cvtneps_pbh(v));
        _mm256_storeu_si256(dst.as_mut_ptr().add(i) as *mut __m256i, h);
        i += 16;
    }
    if i < n {
        let mask: __mmask16 = (1u16 << (n - i)) - 1;
        let v = _mm512_maskz_loadu_ps(mask, src.as_ptr().add(i));
        let h: __m256i = std::mem::transmute(_mm512_cvtneps_pbh(v));
        _mm256_mask_storeu_epi16(dst.as_mut_ptr().add(i) as *mut i16, mask, h);
    }
}

/// `C[rows × cols] += A · Bᵀ` for one tile: `A` is `rows` rows of `kc` bf16 pairs (`lda`
/// pairs apart), `B` one packed tile (`kc × NR × 2` bf16 from `b`), `C` rows `ldc` apart.
///
/// # Safety
/// The CPU must have AVX512F and AVX512-BF16; `1 ≤ rows ≤ 6`, `cols ≤ NR`; `a` holds
/// `(rows − 1)·lda + kc` values, `b` holds `kc·NR·2`, and `c` is valid for reads and writes of
/// `cols` values at each of `rows` rows `ldc` apart, touched by no one else meanwhile.
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx512f,avx512bf16")]
pub unsafe fn tile(
    rows: usize,
    kc: usize,
    a: *const u32,
    lda: usize,
    b: *const u16,
    c: *mut f32,
    ldc: usize,
    cols: usize,
) {
    match rows {
        1 => tile_rows::<1>(kc, a, lda, b, c, ldc, cols),
        2 => tile_rows::<2>(kc, a, lda, b, c, ldc, cols),
        3 => tile_rows::<3>(kc, a, lda, b, c, ldc, cols),
        4 => tile_rows::<4>(kc, a, lda, b, c, ldc, cols),
        5 => tile_rows::<5>(kc, a, lda, b, c, ldc, cols),
        _ => tile_rows::<6>(kc, a, lda, b, c, ldc, cols),
    }
}

/// [`tile`] for `R` rows: `R × 4` accumulators of 16 columns.
#[target_feature(enable = "avx512f,avx512bf16")]
unsafe fn tile_rows<const R: usize>(
    kc: usize,
    a: *const u32,
    lda: usize,
    b: *const u16,
    c: *mut f32,
    ldc: usize,
    cols: usize,
) {
    let mut acc = [[_mm512_setzero_ps(); 4]; R];
    for p in 0..kc {
        let bp = b.add(p * NR * 2);
        let b0: __m512bh = std::mem::transmute(_mm512_loadu_si512(bp as *const _));
        let b1: __m512bh = std::mem::transmute(_mm512_loadu_si512(bp.add(32) as *const _));
        let b2: __m512bh = std::mem::transmute(_mm512_loadu_si512(bp.add(64) as *const _));
        let b3: __m512bh = std::mem::transmute(_mm512_loadu_si512(bp.add(96) as *const _));
        for (r, acc_r) in acc.iter_mut().enumerate() {
            let av: __m512bh = std::mem::transmute(_mm512_set1_epi32(*a.add(r * lda + p) as i32));
            acc_r[0] = _mm512_dpbf16_ps(acc_r[0], av, b0);
            acc_r[1] = _mm512_dpbf16_ps(acc_r[1], av, b1);
            acc_r[2] = _mm512_dpbf16_ps(acc_r[2], av, b2);
            acc_r[3] = _mm512_dpbf16_ps(acc_r[3], av, b3);
        }
    }
    for (r, acc_r) in acc.iter().enumerate() {
        let row = c.add(r * ldc);
        for (j, &v) in acc_r.iter().enumerate() {
            let col = j * 16;
            if col >= cols {
                break;
            }
            let left = cols - col;
            let mask: __mmask16 = if left >= 16 {
                0xffff
            } else {
                (1u16 << left) - 1
            };
            let old = _mm512_maskz_loadu_ps(mask, row.add(col));
            _mm512_mask_storeu_ps(row.add(col), mask, _mm512_add_ps(old, v));
        }
    }
}
