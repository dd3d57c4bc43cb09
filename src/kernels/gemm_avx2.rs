//! The x86-64 micro-kernels of [`super::pointwise`], written with AVX2 + FMA intrinsics: a
//! 6 × 16 block (twelve 256-bit accumulators) for 16-wide weight panels and a 12 × 8 block for
//! 8-wide ones, each running over `k` with one broadcast input value per row. (Left to the
//! auto-vectoriser, the same loops came out with some accumulators spilled or shuffled lane by
//! lane depending on the surrounding code; AVX-512 intrinsics would need a newer compiler than
//! the crate's minimum, and 256-bit multiply-adds have the same throughput on the CPUs we
//! target.) Every function here needs AVX2 and FMA: callers check with [`available`].

use std::arch::x86_64::*;

use super::nhwc::Epilogue;

/// Whether the CPU has AVX2 and FMA.
pub(crate) fn available() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

/// An output buffer written through a raw pointer, so that tasks storing disjoint column
/// panels of the same rows can share it (a `&mut [f32]` each would alias).
#[derive(Clone, Copy)]
pub(crate) struct OutPtr {
    /// The first value.
    pub ptr: *mut f32,
    /// Values writable from `ptr`.
    pub len: usize,
}

impl OutPtr {
    /// The whole of `out`.
    pub(crate) fn new(out: &mut [f32]) -> Self {
        Self {
            ptr: out.as_mut_ptr(),
            len: out.len(),
        }
    }

    /// Values `at..` of this buffer (`at ≤ len`).
    pub(crate) fn skip(self, at: usize) -> Self {
        assert!(at <= self.len, "output pointer: offset past the end");
        Self {
            ptr: self.ptr.wrapping_add(at),
            len: self.len - at,
        }
    }
}

/// Where a panel's results go: its columns `col..col + valid` of `n`-wide output rows.
#[derive(Clone, Copy)]
pub(crate) struct PanelOut<'a> {
    /// Output row width.
    pub n: usize,
    /// First column.
    pub col: usize,
    /// Columns that exist (`≤` the panel width).
    pub valid: usize,
    /// The panel's bias, padded to the panel width.
    pub bias: &'a [f32],
}

/// One 16-wide panel (`[k][16]`) over rows `0..m` of `a` (rows `lda` apart).
///
/// # Safety
/// The CPU must have AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn panel16(
    panel: &[f32],
    k: usize,
    a: &[f32],
    lda: usize,
    m: usize,
    po: PanelOut,
    epi: Epilogue,
    out: OutPtr,
) {
    #[cfg(lhmpp_bf16_intrinsics)]
    if m >= WIDE_ROWS && std::arch::is_x86_feature_detected!("avx512f") {
        // SAFETY: the CPU has AVX-512F (checked) besides AVX2 and FMA.
        return unsafe { panel16_avx512(panel, k, a, lda, m, po, epi, out) };
    }
    rows::<6, 2>(panel, k, a, lda, m, po, epi, out)
}

/// Rows per block of [`panel16_avx512`].
#[cfg(lhmpp_bf16_intrinsics)]
const WIDE_ROWS: usize = 8;

/// [`panel16`] with AVX-512F, for `m ≥ 8` rows: blocks of 8 rows × one 512-bit vector, each
/// step one load of the panel, eight broadcasts and eight multiply-adds (the AVX2 block needs
/// eight loads for six rows), the same sums in the same order. A short last block overlaps
/// the one before it. Compiled with Rust 1.89 or newer only (`lhmpp_bf16_intrinsics`).
///
/// # Safety
/// The CPU must have AVX-512F, AVX2 and FMA.
#[cfg(lhmpp_bf16_intrinsics)]
#[target_feature(enable = "avx512f,avx2,fma")]
#[allow(clippy::too_many_arguments)]
// The AVX-512 intrinsics are stable since Rust 1.89; `lhmpp_bf16_intrinsics` is set only then.
#[allow(clippy::incompatible_msrv)]
unsafe fn panel16_avx512(
    panel: &[f32],
    k: usize,
    a: &[f32],
    lda: usize,
    m: usize,
    po: PanelOut,
    epi: Epilogue,
    out: OutPtr,
) {
    const M: usize = WIDE_ROWS;
    assert!(m >= M && panel.len() >= k * 16 && po.bias.len() >= 16 && po.valid <= 16);
    assert!(out.len >= m * po.n && po.col + po.valid <= po.n);
    assert!(a.len() >= (m - 1) * lda + k);
    if let Some(r) = epi.residual {
        assert!(r.len() >= m * po.n);
    }
    let mut r0 = 0;
    loop {
        let start = r0.min(m - M);
        let rows = a.as_ptr().add(start * lda);
        let mut acc = [_mm512_setzero_ps(); M];
        let mut b = panel.as_ptr();
        for p in 0..k {
            let bv = _mm512_loadu_ps(b);
            for (r, acc) in acc.iter_mut().enumerate() {
                let x = _mm512_set1_ps(*rows.add(r * lda + p));
                *acc = _mm512_fmadd_ps(x, bv, *acc);
            }
            b = b.add(16);
        }
        let halves = acc.map(|v| {
            let hi = _mm512_extractf64x4_pd::<1>(_mm512_castps_pd(v));
            [_mm512_castps512_ps256(v), _mm256_castpd_ps(hi)]
        });
        store::<M, 2>(&halves, start, M, po, epi, out);
        r0 += M;
        if r0 >= m {
            break;
        }
    }
}

/// One 8-wide panel (`[k][8]`) over rows `0..m`.
///
/// # Safety
/// The CPU must have AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn panel8(
    panel: &[f32],
    k: usize,
    a: &[f32],
    lda: usize,
    m: usize,
    po: PanelOut,
    epi: Epilogue,
    out: OutPtr,
) {
    rows::<12, 1>(panel, k, a, lda, m, po, epi, out)
}

/// One 16-wide panel over `m ≤ 6` output pixels of a k×k convolution whose input rows are
/// read through `taps[t][r]` (the `c` input values of tap `t` under output pixel `r`, or a
/// row of zeros): the product without gathering the rows first.
///
/// # Safety
/// The CPU must have AVX2 and FMA, and every pointer in `taps[..][..m]` must point at `c`
/// readable values.
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn indirect16(
    panel: &[f32],
    taps: &[[*const f32; 12]],
    c: usize,
    m: usize,
    first: usize,
    po: PanelOut,
    epi: Epilogue,
    out: OutPtr,
) {
    match m {
        1 => indirect::<1, 2>(panel, taps, c, m, first, po, epi, out),
        2 => indirect::<2, 2>(panel, taps, c, m, first, po, epi, out),
        3 => indirect::<3, 2>(panel, taps, c, m, first, po, epi, out),
        _ => indirect::<6, 2>(panel, taps, c, m, first, po, epi, out),
    }
}

/// [`indirect16`] for an 8-wide panel and `m ≤ 12` pixels.
///
/// # Safety
/// As [`indirect16`].
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn indirect8(
    panel: &[f32],
    taps: &[[*const f32; 12]],
    c: usize,
    m: usize,
    first: usize,
    po: PanelOut,
    epi: Epilogue,
    out: OutPtr,
) {
    match m {
        1 => indirect::<1, 1>(panel, taps, c, m, first, po, epi, out),
        2 => indirect::<2, 1>(panel, taps, c, m, first, po, epi, out),
        3 | 4 => indirect::<4, 1>(panel, taps, c, m, first, po, epi, out),
        _ => indirect::<12, 1>(panel, taps, c, m, first, po, epi, out),
    }
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn indirect<const M: usize, const NV: usize>(
    panel: &[f32],
    taps: &[[*const f32; 12]],
    c: usize,
    m: usize,
    first: usize,
    po: PanelOut,
    epi: Epilogue,
    out: OutPtr,
) {
    assert!(m <= M && panel.len() >= taps.len() * c * NV * 8);
    assert!(taps.iter().all(|t| t.len() >= M));
    assert!(out.len >= (first + m) * po.n && po.col + po.valid <= po.n);
    if let Some(r) = epi.residual {
        assert!(r.len() >= (first + m) * po.n);
    }
    let mut acc = [[_mm256_setzero_ps(); NV]; M];
    let mut b = panel.as_ptr();
    for rows in taps {
        for ch in 0..c {
            let mut bv = [_mm256_setzero_ps(); NV];
            for (v, bv) in bv.iter_mut().enumerate() {
                *bv = _mm256_loadu_ps(b.add(v * 8));
            }
            for (acc, &row) in acc.iter_mut().zip(rows) {
                let x = _mm256_broadcast_ss(&*row.add(ch));
                for (acc, &bv) in acc.iter_mut().zip(&bv) {
                    *acc = _mm256_fmadd_ps(x, bv, *acc);
                }
            }
            b = b.add(NV * 8);
        }
    }
    store::<M, NV>(&acc, first, m, po, epi, out);
}

/// Output pixels `0..m` (`m ≤ 8`) of one output channel whose input rows are read through
/// `taps[t][r]` (`c` values each, `c` a multiple of 8) against `weight [taps][c]`: the eight
/// sums `Σ_t Σ_i taps[t][r][i] · weight[t][i]`.
///
/// # Safety
/// The CPU must have AVX2 and FMA; every pointer in `taps[..][..m]` must point at `c`
/// readable values and `weight` hold `taps.len() · c`.
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn indirect_dot8(
    taps: &[[*const f32; 12]],
    c: usize,
    weight: &[f32],
    m: usize,
) -> [f32; 8] {
    assert!(m <= 8 && c % 8 == 0 && weight.len() >= taps.len() * c);
    let mut acc = [_mm256_setzero_ps(); 8];
    for (t, rows) in taps.iter().enumerate() {
        for c0 in (0..c).step_by(8) {
            let wv = _mm256_loadu_ps(weight.as_ptr().add(t * c + c0));
            for (acc, &row) in acc.iter_mut().zip(rows).take(m) {
                *acc = _mm256_fmadd_ps(_mm256_loadu_ps(row.add(c0)), wv, *acc);
            }
        }
    }
    let mut sums = [0.0f32; 8];
    _mm256_storeu_ps(sums.as_mut_ptr(), hsum8(&acc));
    sums
}

/// Pixels of one output row that [`row_taps`] accumulates at a time.
pub(crate) const ROW_PIXELS: usize = 8;

/// One kernel row of a `K`-wide, stride-`S` convolution over [`ROW_PIXELS`] consecutive
/// output pixels of 8 channels: `acc[p] += x[(p·S + kx)] · wk[kx]` for every `p` and `kx`,
/// where `x[j]` is the 8 values at `line + (x0 + j)·c` (input column `x0 + j`). Each of the
/// `7·S + K` input columns is loaded once and multiplied by every tap that reads it, so a
/// 5×5 stride-1 row costs 12 loads for 40 multiply-adds. With `CHECKED`, columns outside
/// `0..w` read the 8 zeros at `zero` instead (padding); without, all must lie inside.
///
/// Used by the depthwise kernel (one output per channel) and by the few-output convolution
/// (whose lanes are input channels, summed afterwards).
///
/// # Safety
/// The caller's function must enable AVX2 and FMA; every column read must hold 8 readable
/// values (`zero` too).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn row_taps<const K: usize, const S: usize, const CHECKED: bool>(
    acc: &mut [__m256; ROW_PIXELS],
    wk: &[__m256; K],
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
        let x = _mm256_loadu_ps(ptr);
        for (kx, wv) in wk.iter().enumerate() {
            if j >= kx && (j - kx) % S == 0 && (j - kx) / S < ROW_PIXELS {
                let p = (j - kx) / S;
                acc[p] = _mm256_fmadd_ps(x, *wv, acc[p]);
            }
        }
    }
}

/// The eight horizontal sums of `acc[0..8]`, as the lanes of one vector.
///
/// # Safety
/// The caller's function must enable AVX2.
#[inline(always)]
pub(crate) unsafe fn hsum8(acc: &[__m256; 8]) -> __m256 {
    let s01 = _mm256_hadd_ps(acc[0], acc[1]);
    let s23 = _mm256_hadd_ps(acc[2], acc[3]);
    let s45 = _mm256_hadd_ps(acc[4], acc[5]);
    let s67 = _mm256_hadd_ps(acc[6], acc[7]);
    let s0123 = _mm256_hadd_ps(s01, s23);
    let s4567 = _mm256_hadd_ps(s45, s67);
    let lo = _mm256_permute2f128_ps::<0x20>(s0123, s4567);
    let hi = _mm256_permute2f128_ps::<0x31>(s0123, s4567);
    _mm256_add_ps(lo, hi)
}

/// The transpose of the 8 × 8 matrix whose rows are `r`.
///
/// # Safety
/// The CPU must have AVX2.
#[inline]
#[target_feature(enable = "avx2")]
pub(crate) unsafe fn transpose8(r: [__m256; 8]) -> [__m256; 8] {
    let t0 = _mm256_unpacklo_ps(r[0], r[1]);
    let t1 = _mm256_unpackhi_ps(r[0], r[1]);
    let t2 = _mm256_unpacklo_ps(r[2], r[3]);
    let t3 = _mm256_unpackhi_ps(r[2], r[3]);
    let t4 = _mm256_unpacklo_ps(r[4], r[5]);
    let t5 = _mm256_unpackhi_ps(r[4], r[5]);
    let t6 = _mm256_unpacklo_ps(r[6], r[7]);
    let t7 = _mm256_unpackhi_ps(r[6], r[7]);
    let u0 = _mm256_shuffle_ps::<0x44>(t0, t2);
    let u1 = _mm256_shuffle_ps::<0xEE>(t0, t2);
    let u2 = _mm256_shuffle_ps::<0x44>(t1, t3);
    let u3 = _mm256_shuffle_ps::<0xEE>(t1, t3);
    let u4 = _mm256_shuffle_ps::<0x44>(t4, t6);
    let u5 = _mm256_shuffle_ps::<0xEE>(t4, t6);
    let u6 = _mm256_shuffle_ps::<0x44>(t5, t7);
    let u7 = _mm256_shuffle_ps::<0xEE>(t5, t7);
    [
        _mm256_permute2f128_ps::<0x20>(u0, u4),
        _mm256_permute2f128_ps::<0x20>(u1, u5),
        _mm256_permute2f128_ps::<0x20>(u2, u6),
        _mm256_permute2f128_ps::<0x20>(u3, u7),
        _mm256_permute2f128_ps::<0x31>(u0, u4),
        _mm256_permute2f128_ps::<0x31>(u1, u5),
        _mm256_permute2f128_ps::<0x31>(u2, u6),
        _mm256_permute2f128_ps::<0x31>(u3, u7),
    ]
}

/// `Σ a[i]·b[i]` over `len` values.
///
/// # Safety
/// The CPU must have AVX2 and FMA; `a` and `b` hold `len` readable values.
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn dot(a: *const f32, b: *const f32, len: usize) -> f32 {
    let mut acc0 = _mm256_setzero_ps();
    let mut acc1 = _mm256_setzero_ps();
    let mut i = 0;
    while i + 16 <= len {
        acc0 = _mm256_fmadd_ps(_mm256_loadu_ps(a.add(i)), _mm256_loadu_ps(b.add(i)), acc0);
        acc1 = _mm256_fmadd_ps(
            _mm256_loadu_ps(a.add(i + 8)),
            _mm256_loadu_ps(b.add(i + 8)),
            acc1,
        );
        i += 16;
    }
    if i + 8 <= len {
        acc0 = _mm256_fmadd_ps(_mm256_loadu_ps(a.add(i)), _mm256_loadu_ps(b.add(i)), acc0);
        i += 8;
    }
    let v = _mm256_add_ps(acc0, acc1);
    let h = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps::<1>(v));
    let h = _mm_add_ps(h, _mm_movehl_ps(h, h));
    let h = _mm_add_ss(h, _mm_shuffle_ps::<1>(h, h));
    let mut sum = _mm_cvtss_f32(h);
    while i < len {
        sum += *a.add(i) * *b.add(i);
        i += 1;
    }
    sum
}

/// Blocks of `M` rows × `NV` vectors; a short last block overlaps the one before it, and
/// fewer than `M` rows in all are copied into a zero-padded block.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn rows<const M: usize, const NV: usize>(
    panel: &[f32],
    k: usize,
    a: &[f32],
    lda: usize,
    m: usize,
    po: PanelOut,
    epi: Epilogue,
    out: OutPtr,
) {
    assert!(panel.len() >= k * NV * 8 && po.bias.len() >= NV * 8 && po.valid <= NV * 8);
    assert!(out.len >= m * po.n && po.col + po.valid <= po.n);
    if let Some(r) = epi.residual {
        assert!(r.len() >= m * po.n);
    }
    if m == 0 {
        return;
    }
    if m < M && m <= 2 {
        // a row or two (the last layers of a network, at 1×1 or 2×1 pixels): no padded copy
        assert!(a.len() >= (m - 1) * lda + k);
        if m == 1 {
            let acc = block::<1, NV>(a.as_ptr(), lda, panel.as_ptr(), k);
            store::<1, NV>(&acc, 0, 1, po, epi, out);
        } else {
            let acc = block::<2, NV>(a.as_ptr(), lda, panel.as_ptr(), k);
            store::<2, NV>(&acc, 0, 2, po, epi, out);
        }
        return;
    }
    if m < M {
        let mut padded = vec![0.0f32; M * k];
        for r in 0..m {
            padded[r * k..(r + 1) * k].copy_from_slice(&a[r * lda..r * lda + k]);
        }
        let acc = block::<M, NV>(padded.as_ptr(), k, panel.as_ptr(), k);
        store::<M, NV>(&acc, 0, m, po, epi, out);
        return;
    }
    assert!(a.len() >= (m - 1) * lda + k);
    let mut r0 = 0;
    loop {
        let start = r0.min(m - M);
        let acc = block::<M, NV>(a.as_ptr().add(start * lda), lda, panel.as_ptr(), k);
        store::<M, NV>(&acc, start, M, po, epi, out);
        r0 += M;
        if r0 >= m {
            break;
        }
    }
}

/// `M` rows × `NV` 8-lane vectors of `a · panel`.
///
/// Safety: rows `a + r·lda`, `r < M`, hold `k` readable values; `panel` holds `k·NV·8`.
#[inline(always)]
unsafe fn block<const M: usize, const NV: usize>(
    a: *const f32,
    lda: usize,
    panel: *const f32,
    k: usize,
) -> [[__m256; NV]; M] {
    let mut acc = [[_mm256_setzero_ps(); NV]; M];
    let mut b = panel;
    for p in 0..k {
        let mut bv = [_mm256_setzero_ps(); NV];
        for (v, bv) in bv.iter_mut().enumerate() {
            *bv = _mm256_loadu_ps(b.add(v * 8));
        }
        for (r, acc) in acc.iter_mut().enumerate() {
            let x = _mm256_broadcast_ss(&*a.add(r * lda + p));
            for (acc, &bv) in acc.iter_mut().zip(&bv) {
                *acc = _mm256_fmadd_ps(x, bv, *acc);
            }
        }
        b = b.add(NV * 8);
    }
    acc
}

/// Rows `0..rows` of `acc` to output rows `first..`, through the epilogue.
#[inline(always)]
unsafe fn store<const M: usize, const NV: usize>(
    acc: &[[__m256; NV]; M],
    first: usize,
    rows: usize,
    po: PanelOut,
    epi: Epilogue,
    out: OutPtr,
) {
    let (lo1, hi1) = epi.pre.bounds();
    let (lo2, hi2) = epi.post.bounds();
    let (lo1, hi1, lo2, hi2) = (
        _mm256_set1_ps(lo1),
        _mm256_set1_ps(hi1),
        _mm256_set1_ps(lo2),
        _mm256_set1_ps(hi2),
    );
    let full = po.valid == NV * 8;
    for (r, acc) in acc.iter().enumerate().take(rows) {
        let at = (first + r) * po.n + po.col;
        let mut vals = [_mm256_setzero_ps(); NV];
        for (v, (val, &acc)) in vals.iter_mut().zip(acc).enumerate() {
            let b = _mm256_loadu_ps(po.bias.as_ptr().add(v * 8));
            *val = _mm256_min_ps(_mm256_max_ps(_mm256_add_ps(acc, b), lo1), hi1);
        }
        assert!(at + po.valid <= out.len);
        if full {
            let dst = out.ptr.add(at);
            match epi.residual {
                Some(res) => {
                    let src = res[at..at + NV * 8].as_ptr();
                    for (v, &val) in vals.iter().enumerate() {
                        let x = _mm256_add_ps(val, _mm256_loadu_ps(src.add(v * 8)));
                        _mm256_storeu_ps(dst.add(v * 8), _mm256_min_ps(_mm256_max_ps(x, lo2), hi2));
                    }
                }
                None => {
                    for (v, &val) in vals.iter().enumerate() {
                        _mm256_storeu_ps(dst.add(v * 8), val);
                    }
                }
            }
        } else {
            let mut lanes = [0.0f32; 16];
            for (v, &val) in vals.iter().enumerate() {
                _mm256_storeu_ps(lanes.as_mut_ptr().add(v * 8), val);
            }
            let dst = std::slice::from_raw_parts_mut(out.ptr.add(at), po.valid);
            match epi.residual {
                Some(res) => {
                    let (lo2, hi2) = epi.post.bounds();
                    for ((d, &l), &x) in dst.iter_mut().zip(&lanes).zip(&res[at..at + po.valid]) {
                        *d = (l + x).max(lo2).min(hi2);
                    }
                }
                None => dst.copy_from_slice(&lanes[..po.valid]),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::nhwc::Activation;

    fn values(len: usize, seed: u32) -> Vec<f32> {
        (0..len)
            .map(|i| {
                ((i as u32).wrapping_mul(2_654_435_761).wrapping_add(seed) % 2001) as f32 / 1000.0
                    - 1.0
            })
            .collect()
    }

    /// The AVX-512 blocks give the AVX2 blocks' sums bit for bit (same products, same order),
    /// through the whole epilogue, for row counts that do and do not fill their blocks.
    #[cfg(lhmpp_bf16_intrinsics)]
    #[test]
    fn avx512_panels_match_avx2_panels() {
        if !(available() && std::arch::is_x86_feature_detected!("avx512f")) {
            return;
        }
        for (m, k, valid) in [(8, 5, 16), (13, 96, 16), (64, 1632, 16), (30, 40, 11)] {
            let (n, lda) = (20, k + 3);
            let a = values((m - 1) * lda + k, 1);
            let panel = values(k * 16, 2);
            let bias = values(16, 3);
            let residual = values(m * n, 4);
            let po = PanelOut {
                n,
                col: 2,
                valid,
                bias: &bias,
            };
            let epi = Epilogue {
                pre: Activation::Relu6,
                residual: Some(&residual),
                post: Activation::Relu,
            };
            let (mut wide, mut narrow) = (vec![0.0f32; m * n], vec![0.0f32; m * n]);
            // SAFETY: the CPU has AVX-512F, AVX2 and FMA (checked above).
            unsafe {
                panel16_avx512(&panel, k, &a, lda, m, po, epi, OutPtr::new(&mut wide));
                rows::<6, 2>(&panel, k, &a, lda, m, po, epi, OutPtr::new(&mut narrow));
            }
            assert_eq!(wide, narrow, "m {m}, k {k}, valid {valid}");
            assert!(wide.iter().any(|v| *v != 0.0));
        }
    }
}
