//! The AVX512-BF16 micro-kernel and row conversion. Every `unsafe fn` here needs a CPU with
//! `avx512f` and `avx512bf16`: callers check [`available`] first.
//!
//! The intrinsics are stable since Rust 1.89, newer than the crate's minimum: the module is
//! compiled only when the build script found such a compiler (`lhmpp_bf16_intrinsics`).
#![allow(clippy::incompatible_msrv)]

use std::arch::x86_64::*;

use super::NR;

/// Whether the CPU has AVX512F and AVX512-BF16 (`vdpbf16ps`, `vcvtneps2bf16`), with the BW and
/// VL extensions (masked 16-bit stores; every CPU with AVX512-BF16 has them).
pub fn available() -> bool {
    std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512bf16")
        && std::arch::is_x86_feature_detected!("avx512bw")
        && std::arch::is_x86_feature_detected!("avx512vl")
}

/// Rounds `src` to bf16 (nearest, ties to even) into `dst`, 16 values per instruction.
///
/// # Safety
/// The CPU must have AVX512F and AVX512-BF16.
#[target_feature(enable = "avx512f,avx512bf16,avx512bw,avx512vl")]
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

/// `C[rows × cols] += A · Bᵀ` (or `=` when `add` is false: `C` is then only written) for one
/// tile: `A` is `rows` rows of `kc` bf16 pairs (`lda`
/// pairs apart), `B` one packed tile (`kc × NR × 2` bf16 from `b`), `C` rows `ldc` apart.
///
/// # Safety
/// The CPU must have AVX512F and AVX512-BF16; `1 ≤ rows ≤ 6`, `cols ≤ NR`; `a` holds
/// `(rows − 1)·lda + kc` values, `b` holds `kc·NR·2`, and `c` is valid for reads and writes of
/// `cols` values at each of `rows` rows `ldc` apart, touched by no one else meanwhile.
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx512f,avx512bf16,avx512bw,avx512vl")]
pub unsafe fn tile(
    rows: usize,
    kc: usize,
    a: *const u32,
    lda: usize,
    b: *const u16,
    c: *mut f32,
    ldc: usize,
    cols: usize,
    add: bool,
) {
    match rows {
        1 => tile_rows::<1>(kc, a, lda, b, c, ldc, cols, add),
        2 => tile_rows::<2>(kc, a, lda, b, c, ldc, cols, add),
        3 => tile_rows::<3>(kc, a, lda, b, c, ldc, cols, add),
        4 => tile_rows::<4>(kc, a, lda, b, c, ldc, cols, add),
        5 => tile_rows::<5>(kc, a, lda, b, c, ldc, cols, add),
        _ => tile_rows::<6>(kc, a, lda, b, c, ldc, cols, add),
    }
}

/// [`tile`] for `R` rows: `R × 4` accumulators of 16 columns.
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx512f,avx512bf16,avx512bw,avx512vl")]
unsafe fn tile_rows<const R: usize>(
    kc: usize,
    a: *const u32,
    lda: usize,
    b: *const u16,
    c: *mut f32,
    ldc: usize,
    cols: usize,
    add: bool,
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
            let v = if add {
                _mm512_add_ps(_mm512_maskz_loadu_ps(mask, row.add(col)), v)
            } else {
                v
            };
            _mm512_mask_storeu_ps(row.add(col), mask, v);
        }
    }
}

/// Largest value of `xs` (`−∞` when empty), 16 lanes at a time.
///
/// # Safety
/// The CPU must have AVX512F.
#[target_feature(enable = "avx512f")]
pub unsafe fn max_of(xs: &[f32]) -> f32 {
    let neg_inf = _mm512_set1_ps(f32::NEG_INFINITY);
    let mut best = neg_inf;
    let mut i = 0;
    while i < xs.len() {
        let mask = lanes_from(xs.len() - i);
        let v = _mm512_mask_loadu_ps(neg_inf, mask, xs.as_ptr().add(i));
        best = _mm512_max_ps(best, v);
        i += 16;
    }
    _mm512_reduce_max_ps(best)
}

/// Writes `exp(scale·s − shift)` of every score `s` of `scores` as bf16 bits into `probs` and
/// returns the sum of the f32 values: `2^t` with `t = (scale·s − shift)·log₂e` (one
/// multiply-add), `2^t = 2^round(t) · 2^f` by `vscalefps`, and `2^f` on `f ∈ [−½, ½]` by a
/// degree-6 polynomial (relative error about 2e-7), values below `2^-127` flushed towards 0.
///
/// # Safety
/// The CPU must have AVX512F and AVX512-BF16.
#[target_feature(enable = "avx512f,avx512bf16,avx512bw,avx512vl")]
pub unsafe fn exp_to_bf16(scores: &[f32], scale: f32, shift: f32, probs: &mut [u16]) -> f32 {
    let n = scores.len().min(probs.len());
    let a = _mm512_set1_ps(scale * std::f32::consts::LOG2_E);
    let b = _mm512_set1_ps(-shift * std::f32::consts::LOG2_E);
    let lowest = _mm512_set1_ps(-127.0);
    let mut sum = _mm512_setzero_ps();
    let mut i = 0;
    while i < n {
        let mask = lanes_from(n - i);
        let s = _mm512_maskz_loadu_ps(mask, scores.as_ptr().add(i));
        let t = _mm512_max_ps(_mm512_fmadd_ps(s, a, b), lowest);
        let e = _mm512_maskz_mov_ps(mask, exp2(t));
        sum = _mm512_add_ps(sum, e);
        let h: __m256i = std::mem::transmute(_mm512_cvtneps_pbh(e));
        _mm256_mask_storeu_epi16(probs.as_mut_ptr().add(i) as *mut i16, mask, h);
        i += 16;
    }
    _mm512_reduce_add_ps(sum)
}

/// `2^t` for `t ≥ −127`: `2^round(t) · (1 + f·P(f))` with `f = t − round(t)` and the
/// Cephes `exp2f` minimax coefficients.
#[inline]
#[target_feature(enable = "avx512f")]
unsafe fn exp2(t: __m512) -> __m512 {
    let whole = _mm512_roundscale_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(t);
    let f = _mm512_sub_ps(t, whole);
    let mut p = _mm512_set1_ps(1.535_336_2e-4);
    for c in [
        1.339_887_4e-3,
        9.618_437e-3,
        5.550_332_5e-2,
        0.240_226_48,
        std::f32::consts::LN_2,
    ] {
        p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(c));
    }
    let p = _mm512_fmadd_ps(p, f, _mm512_set1_ps(1.0));
    _mm512_scalef_ps(p, whole)
}

/// The mask of the first `min(left, 16)` lanes.
#[inline]
fn lanes_from(left: usize) -> __mmask16 {
    if left >= 16 {
        0xffff
    } else {
        (1u16 << left) - 1
    }
}
