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
use super::matmul::{matmul_into, MatRef};

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
        let mut gw = vec![0f64; a * 3];
        for ci in 0..c_in {
            for co in 0..c_out {
                let w =
                    |ky: usize, kx: usize| weight[((ky * 3 + kx) * c_in + ci) * c_out + co] as f64;
                // G g, then (G g) Gᵀ
                for i in 0..a {
                    for kx in 0..3 {
                        gw[i * 3 + kx] = (0..3).map(|ky| g(i, ky) * w(ky, kx)).sum();
                    }
                }
                for i in 0..a {
                    for j in 0..a {
                        let v: f64 = (0..3).map(|kx| gw[i * 3 + kx] * g(j, kx)).sum();
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

/// `N` disjoint `c`-long rows of `out`, `stride` apart.
fn rows_of<const N: usize>(out: &mut [f32], stride: usize, c: usize) -> [&mut [f32]; N] {
    let mut it = out.chunks_mut(stride).map(|g| &mut g[..c]);
    std::array::from_fn(|_| it.next().expect("winograd: transform rows"))
}

/// F(4×4, 3×3) `Bᵀ` on six channel rows in one pass.
fn bt_f4(o: [&mut [f32]; 6], d: [&[f32]; 6], c: usize) {
    let [o0, o1, o2, o3, o4, o5] = o;
    let (o0, o1, o2, o3, o4, o5) = (
        &mut o0[..c],
        &mut o1[..c],
        &mut o2[..c],
        &mut o3[..c],
        &mut o4[..c],
        &mut o5[..c],
    );
    let (d0, d1, d2, d3, d4, d5) = (
        &d[0][..c],
        &d[1][..c],
        &d[2][..c],
        &d[3][..c],
        &d[4][..c],
        &d[5][..c],
    );
    for i in 0..c {
        let (a0, a1, a2, a3, a4, a5) = (d0[i], d1[i], d2[i], d3[i], d4[i], d5[i]);
        o0[i] = 4.0 * a0 - 5.0 * a2 + a4;
        o1[i] = -4.0 * (a1 + a2) + a3 + a4;
        o2[i] = 4.0 * (a1 - a2) - a3 + a4;
        o3[i] = 2.0 * (a3 - a1) - a2 + a4;
        o4[i] = 2.0 * (a1 - a3) - a2 + a4;
        o5[i] = 4.0 * a1 - 5.0 * a3 + a5;
    }
}

/// F(4×4, 3×3) `Aᵀ` on six channel rows in one pass.
fn at_f4(o: [&mut [f32]; 4], m: [&[f32]; 6], c: usize) {
    let [o0, o1, o2, o3] = o;
    let (o0, o1, o2, o3) = (&mut o0[..c], &mut o1[..c], &mut o2[..c], &mut o3[..c]);
    let (m0, m1, m2, m3, m4, m5) = (
        &m[0][..c],
        &m[1][..c],
        &m[2][..c],
        &m[3][..c],
        &m[4][..c],
        &m[5][..c],
    );
    for i in 0..c {
        let (p, q) = (m1[i] + m2[i], m1[i] - m2[i]);
        let (r, s) = (m3[i] + m4[i], m3[i] - m4[i]);
        o0[i] = m0[i] + p + r;
        o1[i] = q + 2.0 * s;
        o2[i] = p + 4.0 * r;
        o3[i] = q + 8.0 * s + m5[i];
    }
}

impl Variant {
    /// `Bᵀ` over α input rows `d`, output row `k` at `out[k·stride..][..c]`.
    fn input_transform(&self, d: &[&[f32]; 6], out: &mut [f32], stride: usize, c: usize) {
        if *self == F4X4 {
            return bt_f4(rows_of(out, stride, c), *d, c);
        }
        let a = self.alpha;
        for k in 0..a {
            let o = &mut out[k * stride..k * stride + c];
            combine(o, &self.bt[k * a..(k + 1) * a], |q| d[q]);
        }
    }

    /// `Aᵀ` over α rows `m`, output row `k < m` at `out[k·stride..][..c]`.
    fn output_transform(&self, m: &[&[f32]; 6], out: &mut [f32], stride: usize, c: usize) {
        if *self == F4X4 {
            return at_f4(rows_of(out, stride, c), *m, c);
        }
        let a = self.alpha;
        for k in 0..self.m {
            let o = &mut out[k * stride..k * stride + c];
            combine(o, &self.at[k * a..(k + 1) * a], |q| m[q]);
        }
    }
}

/// Per-thread scratch of one band.
struct Scratch {
    /// Transformed input tiles `[chunk, α², C_in]`.
    v: Vec<f32>,
    /// Products `[chunk, α², C_out]`.
    m: Vec<f32>,
    /// Half-transformed tile `[α, α, C]` (C = max(C_in, C_out)).
    t: Vec<f32>,
    /// One output block row `[m, C_out]` (for blocks cut by the right edge).
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
    let aa = a * a;
    let (h, w, c_in, c_out) = (x.height, x.width, x.channels, out.channels);
    let (th, tw) = (h.div_ceil(mb), w.div_ceil(mb));
    let chunk = (CHUNK_BYTES / (4 * aa * (c_in + c_out))).clamp(16, 256);
    // tile rows per band: enough tiles for one full chunk when the rows are narrow
    let band = chunk.div_ceil(tw).max(1);
    let zeros = vec![0f32; c_in];
    let empty: &[f32] = &[];
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
                    v: vec![0f32; chunk * aa * c_in],
                    m: vec![0f32; chunk * aa * c_out],
                    t: vec![0f32; aa * c_in.max(c_out)],
                    y: vec![0f32; mb * c_out],
                },
                |s, (bi, rows)| {
                    let ty0 = bi * band;
                    let tiles = (th - ty0).min(band) * tw;
                    let row0 = mb * ty0;
                    for first in (0..tiles).step_by(chunk) {
                        let n = (tiles - first).min(chunk);
                        // 1. transformed inputs V[t][ξ] = (Bᵀ d B)_ξ
                        for t in 0..n {
                            let (ty, tx) = (ty0 + (first + t) / tw, (first + t) % tw);
                            let pixel = |r: usize, q: usize| -> &[f32] {
                                let iy = (mb * ty + r) as isize - 1;
                                let ix = (mb * tx + q) as isize - 1;
                                if q >= a {
                                    empty
                                } else if iy < 0 || ix < 0 || iy >= h as isize || ix >= w as isize {
                                    &zeros
                                } else {
                                    let at = (iy as usize * w + ix as usize) * c_in;
                                    &input[at..at + c_in]
                                }
                            };
                            // along each input row r: t[r][j] = Σ_q Bᵀ[j][q] d[r][q]
                            let tr = &mut s.t[..aa * c_in];
                            for r in 0..a {
                                let d: [&[f32]; 6] = std::array::from_fn(|q| pixel(r, q));
                                v.input_transform(&d, &mut tr[r * a * c_in..], c_in, c_in);
                            }
                            // along the columns: V[i][j] = Σ_r Bᵀ[i][r] t[r][j]
                            let tr = &s.t[..aa * c_in];
                            let tile = &mut s.v[t * aa * c_in..(t + 1) * aa * c_in];
                            for j in 0..a {
                                let d: [&[f32]; 6] = std::array::from_fn(|r| {
                                    if r < a {
                                        &tr[(r * a + j) * c_in..(r * a + j + 1) * c_in]
                                    } else {
                                        empty
                                    }
                                });
                                v.input_transform(&d, &mut tile[j * c_in..], a * c_in, c_in);
                            }
                        }
                        // 2. the α² products M[·][ξ] = V[·][ξ] · U_ξ (tile rows α²·C apart)
                        for xi in 0..aa {
                            let rhs = &u[xi * c_in * c_out..(xi + 1) * c_in * c_out];
                            let lhs = &s.v[xi * c_in..];
                            let prod = &mut s.m[xi * c_out..];
                            matmul_into(
                                prod,
                                aa * c_out,
                                MatRef::rows_apart(lhs, n, c_in, aa * c_in),
                                MatRef::row_major(rhs, c_in, c_out),
                                false,
                                1.0,
                                Parallelism::None,
                            );
                        }
                        // 3. output blocks Y = Aᵀ M A, then bias, residual, activation
                        for t in 0..n {
                            let (ty, tx) = (ty0 + (first + t) / tw, (first + t) % tw);
                            let tile = &s.m[t * aa * c_out..(t + 1) * aa * c_out];
                            // over i: t[dy][j] = Σ_i Aᵀ[dy][i] M[i][j]
                            let tr = &mut s.t[..aa * c_out];
                            for j in 0..a {
                                let m: [&[f32]; 6] = std::array::from_fn(|i| {
                                    if i < a {
                                        &tile[(i * a + j) * c_out..(i * a + j + 1) * c_out]
                                    } else {
                                        empty
                                    }
                                });
                                v.output_transform(&m, &mut tr[j * c_out..], a * c_out, c_out);
                            }
                            // over j: Y[dy][dx] = Σ_j Aᵀ[dx][j] t[dy][j], written straight
                            // into the output row when the block lies inside the map
                            let tr = &s.t[..aa * c_out];
                            let ox = mb * tx;
                            for dy in 0..mb {
                                let oy = mb * ty + dy;
                                if oy >= h {
                                    break;
                                }
                                let m: [&[f32]; 6] = std::array::from_fn(|j| {
                                    if j < a {
                                        &tr[(dy * a + j) * c_out..(dy * a + j + 1) * c_out]
                                    } else {
                                        empty
                                    }
                                });
                                let px = mb.min(w - ox);
                                let at = ((oy - row0) * w + ox) * c_out;
                                let o = &mut rows[at..at + px * c_out];
                                if px == mb {
                                    v.output_transform(&m, o, c_out, c_out);
                                } else {
                                    v.output_transform(&m, &mut s.y, c_out, c_out);
                                    o.copy_from_slice(&s.y[..px * c_out]);
                                }
                                let r = residual.map(|r| &r[(oy * w + ox) * c_out..][..px * c_out]);
                                finish(o, bias, r, epi.relu);
                            }
                        }
                    }
                },
            );
    }
}

/// `o = act(o + bias + residual)` over pixel rows of `bias.len()` channels, in one pass.
fn finish(o: &mut [f32], bias: &[f32], residual: Option<&[f32]>, relu: bool) {
    let act = |v: f32| if relu { v.max(0.0) } else { v };
    match residual {
        Some(r) => {
            for (px, rp) in o
                .chunks_exact_mut(bias.len())
                .zip(r.chunks_exact(bias.len()))
            {
                for ((o, &r), &b) in px.iter_mut().zip(rp).zip(bias) {
                    *o = act(*o + b + r);
                }
            }
        }
        None => {
            for px in o.chunks_exact_mut(bias.len()) {
                for (o, &b) in px.iter_mut().zip(bias) {
                    *o = act(*o + b);
                }
            }
        }
    }
}
