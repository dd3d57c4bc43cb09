//! 3×3, stride-1, padding-1 convolution on channels-last f32 maps by Winograd's minimal
//! filtering F(m×m, 3×3): each m×m output block is `Aᵀ [(G g Gᵀ) ⊙ (Bᵀ d B)] A` for the
//! α×α input tile `d` (α = m + 2), so the 9·m² multiply-adds per block and channel pair of
//! direct convolution become α² (F(2×2): 16 for 36, 2.25× fewer; F(4×4): 36 for 144, 4×).
//! Over channels the elementwise product is α² matrix products
//! `V_ξ [tiles, C_in] · U_ξ [C_in, C_out]`, one per tile position ξ.
//!
//! The transforms are small linear combinations of whole channel rows (vectorised over the
//! channels). Work is split into bands of tile rows (each owns its output rows, in parallel on
//! rayon) and, inside a band, chunks of tiles whose transformed inputs and products stay in
//! cache; the bias, a residual and a ReLU are applied as each output block is written.

use gemm::Parallelism;
use rayon::prelude::*;

use super::conv2d::Epilogue;
use super::feature_map::FeatureMap;

/// Bytes of transformed inputs plus products per chunk (sized to the L2 cache).
const CHUNK_BYTES: usize = 1 << 21;

/// One Winograd F(m×m, 3×3) algorithm: its matrices, row-major.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Variant {
    /// Output block side m.
    pub m: usize,
    /// Input tile side α = m + 2.
    pub alpha: usize,
    /// `Bᵀ`, α×α.
    bt: &'static [f32],
    /// `G`, α×3.
    g: &'static [f64],
    /// `Aᵀ`, m×α.
    at: &'static [f32],
}

/// F(2×2, 3×3): transforms of ±1 and 0 only (the ½s live in the filter), exact up to rounding.
pub const F2X2: Variant = Variant {
    m: 2,
    alpha: 4,
    #[rustfmt::skip]
    bt: &[
        1.0, 0.0, -1.0, 0.0,
        0.0, 1.0, 1.0, 0.0,
        0.0, -1.0, 1.0, 0.0,
        0.0, 1.0, 0.0, -1.0,
    ],
    #[rustfmt::skip]
    g: &[
        1.0, 0.0, 0.0,
        0.5, 0.5, 0.5,
        0.5, -0.5, 0.5,
        0.0, 0.0, 1.0,
    ],
    #[rustfmt::skip]
    at: &[
        1.0, 1.0, 1.0, 0.0,
        0.0, 1.0, -1.0, -1.0,
    ],
};

/// F(4×4, 3×3) on the points 0, ±1, ±2, ∞ (Lavin & Gray): 4× fewer products, a few ulps
/// more rounding than F(2×2).
pub const F4X4: Variant = Variant {
    m: 4,
    alpha: 6,
    #[rustfmt::skip]
    bt: &[
        4.0, 0.0, -5.0, 0.0, 1.0, 0.0,
        0.0, -4.0, -4.0, 1.0, 1.0, 0.0,
        0.0, 4.0, -4.0, -1.0, 1.0, 0.0,
        0.0, -2.0, -1.0, 2.0, 1.0, 0.0,
        0.0, 2.0, -1.0, -2.0, 1.0, 0.0,
        0.0, 4.0, 0.0, -5.0, 0.0, 1.0,
    ],
    #[rustfmt::skip]
    g: &[
        1.0 / 4.0, 0.0, 0.0,
        -1.0 / 6.0, -1.0 / 6.0, -1.0 / 6.0,
        -1.0 / 6.0, 1.0 / 6.0, -1.0 / 6.0,
        1.0 / 24.0, 1.0 / 12.0, 1.0 / 6.0,
        1.0 / 24.0, -1.0 / 12.0, 1.0 / 6.0,
        0.0, 0.0, 1.0,
    ],
    #[rustfmt::skip]
    at: &[
        1.0, 1.0, 1.0, 1.0, 1.0, 0.0,
        0.0, 1.0, -1.0, 2.0, -2.0, 0.0,
        0.0, 1.0, 1.0, 4.0, 4.0, 0.0,
        0.0, 1.0, -1.0, 8.0, -8.0, 1.0,
    ],
};

impl Variant {
    /// `G g Gᵀ` of every 3×3 filter, as α² matrices `[C_in, C_out]`.
    ///
    /// `weight` is `[9·C_in, C_out]` with rows ordered `(ky, kx, c_in)` (the im2col packing).
    pub(crate) fn transform_filters(&self, weight: &[f32], c_in: usize, c_out: usize) -> Vec<f32> {
        let a = self.alpha;
        let g = |i: usize, k: usize| self.g[i * 3 + k];
        let mut u = vec![0f32; a * a * c_in * c_out];
        for ci in 0..c_in {
            for co in 0..c_out {
                let w =
                    |ky: usize, kx: usize| weight[((ky * 3 + kx) * c_in + ci) * c_out + co] as f64;
                for i in 0..a {
                    for j in 0..a {
                        let mut v = 0.0;
                        for ky in 0..3 {
                            for kx in 0..3 {
                                v += g(i, ky) * w(ky, kx) * g(j, kx);
                            }
                        }
                        u[((i * a + j) * c_in + ci) * c_out + co] = v as f32;
                    }
                }
            }
        }
        u
    }
}

/// `out = Σ_q coefs[q] · row(q)` over channels (zero coefficients skipped).
fn combine<'a>(out: &mut [f32], coefs: &[f32], row: impl Fn(usize) -> &'a [f32]) {
    out.fill(0.0);
    for (q, &k) in coefs.iter().enumerate() {
        if k != 0.0 {
            out.iter_mut().zip(row(q)).for_each(|(o, &v)| *o += k * v);
        }
    }
}

/// Per-thread scratch of one band.
struct Scratch {
    /// Transformed input tiles `[α², chunk, C_in]`.
    v: Vec<f32>,
    /// Products `[α², chunk, C_out]`.
    m: Vec<f32>,
    /// Half-transformed tile `[α, α, C]` (C = max(C_in, C_out)).
    t: Vec<f32>,
    /// One output block `[m, m, C_out]`.
    y: Vec<f32>,
}

/// `act(conv3x3(x) + bias + residual)` with stride 1 and padding 1 into `out` (already shaped
/// `[B, H, W, C_out]`); `u` from [`Variant::transform_filters`].
pub(crate) fn conv3x3_winograd(
    v: Variant,
    x: &FeatureMap,
    u: &[f32],
    bias: &[f32],
    epi: Epilogue,
    out: &mut FeatureMap,
) {
    let (a, mb) = (v.alpha, v.m);
    let (h, w, c_in, c_out) = (x.height, x.width, x.channels, out.channels);
    let (th, tw) = (h.div_ceil(mb), w.div_ceil(mb));
    let chunk = (CHUNK_BYTES / (4 * a * a * (c_in + c_out))).clamp(16, 256);
    // tile rows per band: enough tiles for one full chunk when the rows are narrow
    let band = chunk.div_ceil(tw).max(1);
    let zeros = vec![0f32; c_in];
    let image_out = h * w * c_out;
    for b in 0..x.batch {
        let input = &x.data[b * h * w * c_in..(b + 1) * h * w * c_in];
        let residual = epi
            .residual
            .map(|r| &r.data[b * image_out..(b + 1) * image_out]);
        let dst = &mut out.data[b * image_out..(b + 1) * image_out];
        dst.par_chunks_mut(mb * band * w * c_out)
            .enumerate()
            .for_each_init(
                || Scratch {
                    v: vec![0f32; a * a * chunk * c_in],
                    m: vec![0f32; a * a * chunk * c_out],
                    t: vec![0f32; a * a * c_in.max(c_out)],
                    y: vec![0f32; mb * mb * c_out],
                },
                |s, (bi, rows)| {
                    let ty0 = bi * band;
                    let tiles = (th - ty0).min(band) * tw;
                    let row0 = mb * ty0;
                    for first in (0..tiles).step_by(chunk) {
                        let n = (tiles - first).min(chunk);
                        // 1. transformed inputs V_ξ[t, :] = (Bᵀ d B)_ξ
                        for t in 0..n {
                            let (ty, tx) = (ty0 + (first + t) / tw, (first + t) % tw);
                            let pixel = |r: usize, q: usize| -> &[f32] {
                                let iy = (mb * ty + r) as isize - 1;
                                let ix = (mb * tx + q) as isize - 1;
                                if iy < 0 || ix < 0 || iy >= h as isize || ix >= w as isize {
                                    &zeros
                                } else {
                                    let at = (iy as usize * w + ix as usize) * c_in;
                                    &input[at..at + c_in]
                                }
                            };
                            // along each input row r: t[r][j] = Σ_q Bᵀ[j][q] d[r][q]
                            let tr = &mut s.t[..a * a * c_in];
                            for (rj, dst) in tr.chunks_exact_mut(c_in).enumerate() {
                                let (r, j) = (rj / a, rj % a);
                                combine(dst, &v.bt[j * a..(j + 1) * a], |q| pixel(r, q));
                            }
                            // along the columns: V[i][j] = Σ_r Bᵀ[i][r] t[r][j]
                            let tr = &s.t[..a * a * c_in];
                            for i in 0..a {
                                for j in 0..a {
                                    let at = ((i * a + j) * chunk + t) * c_in;
                                    combine(
                                        &mut s.v[at..at + c_in],
                                        &v.bt[i * a..(i + 1) * a],
                                        |r| &tr[(r * a + j) * c_in..(r * a + j + 1) * c_in],
                                    );
                                }
                            }
                        }
                        // 2. the α² products M_ξ = V_ξ · U_ξ
                        for xi in 0..a * a {
                            let lhs = &s.v[xi * chunk * c_in..][..n * c_in];
                            let prod = &mut s.m[xi * chunk * c_out..][..n * c_out];
                            let rhs = &u[xi * c_in * c_out..(xi + 1) * c_in * c_out];
                            product(prod, lhs, rhs, n, c_out, c_in);
                        }
                        // 3. output blocks Y = Aᵀ M A, then bias, residual, activation
                        for t in 0..n {
                            let (ty, tx) = (ty0 + (first + t) / tw, (first + t) % tw);
                            let mrow = |i: usize, j: usize| -> &[f32] {
                                &s.m[((i * a + j) * chunk + t) * c_out..][..c_out]
                            };
                            // over i: t[dy][j] = Σ_i Aᵀ[dy][i] M[i][j]
                            let tr = &mut s.t[..mb * a * c_out];
                            for (dj, dst) in tr.chunks_exact_mut(c_out).enumerate() {
                                let (dy, j) = (dj / a, dj % a);
                                combine(dst, &v.at[dy * a..(dy + 1) * a], |i| mrow(i, j));
                            }
                            // over j: Y[dy][dx] = Σ_j Aᵀ[dx][j] t[dy][j]
                            let tr = &s.t[..mb * a * c_out];
                            for (yx, o) in s.y.chunks_exact_mut(c_out).enumerate() {
                                let (dy, dx) = (yx / mb, yx % mb);
                                combine(o, &v.at[dx * a..(dx + 1) * a], |j| {
                                    &tr[(dy * a + j) * c_out..(dy * a + j + 1) * c_out]
                                });
                            }
                            for (yx, y) in s.y.chunks_exact(c_out).enumerate() {
                                let (oy, ox) = (mb * ty + yx / mb, mb * tx + yx % mb);
                                if oy >= h || ox >= w {
                                    continue;
                                }
                                let at = ((oy - row0) * w + ox) * c_out;
                                let o = &mut rows[at..at + c_out];
                                for ((o, &y), &b) in o.iter_mut().zip(y).zip(bias) {
                                    *o = y + b;
                                }
                                if let Some(r) = residual {
                                    let at = (oy * w + ox) * c_out;
                                    o.iter_mut()
                                        .zip(&r[at..at + c_out])
                                        .for_each(|(o, r)| *o += r);
                                }
                                if epi.relu {
                                    o.iter_mut().for_each(|v| *v = v.max(0.0));
                                }
                            }
                        }
                    }
                },
            );
    }
}

/// `out [m, n] = lhs [m, k] · rhs [k, n]`, all row-major, on the calling thread.
fn product(out: &mut [f32], lhs: &[f32], rhs: &[f32], m: usize, n: usize, k: usize) {
    assert!(out.len() == m * n && lhs.len() == m * k && rhs.len() == k * n);
    if m == 0 || n == 0 || k == 0 {
        out.fill(0.0);
        return;
    }
    // SAFETY: dst `m × n` row-major in `out`; lhs `m × k` row-major in `lhs`; rhs `k × n`
    // row-major in `rhs`; the lengths are asserted above. `read_dst = false`: dst is written.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            out.as_mut_ptr(),
            1,
            n as isize,
            false,
            lhs.as_ptr(),
            1,
            k as isize,
            rhs.as_ptr(),
            1,
            n as isize,
            0.0,
            1.0,
            false,
            false,
            false,
            Parallelism::None,
        );
    }
}
