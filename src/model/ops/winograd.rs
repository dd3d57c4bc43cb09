//! 3×3, stride-1, padding-1 convolution on channels-last f32 maps by Winograd's minimal
//! filtering F(2×2, 3×3): each 2×2 output block is `Aᵀ [(G g Gᵀ) ⊙ (Bᵀ d B)] A` for the 4×4
//! input tile `d`, so the 36 multiply-adds per output pixel and channel pair of direct
//! convolution become 16 per 2×2 block (2.25× fewer). Over channels the elementwise product
//! is 16 matrix products `V_ξ [tiles, C_in] · U_ξ [C_in, C_out]`, one per tile position ξ.
//!
//! The input and output transforms only add and subtract (the ½s live in the packed filter),
//! so the result differs from direct convolution by float rounding alone. Work is split into
//! bands of tile rows (each owns its output rows, in parallel on rayon) and, inside a band,
//! chunks of at most [`CHUNK_TILES`] tiles whose transformed inputs and products stay in cache.

use gemm::Parallelism;
use rayon::prelude::*;

use super::conv2d::Epilogue;
use super::feature_map::FeatureMap;

/// Tiles per matrix product (the `m` of the 16 products).
const CHUNK_TILES: usize = 192;

/// `G g Gᵀ` of every 3×3 filter, as 16 matrices `[C_in, C_out]`.
///
/// `weight` is `[k·k·C_in, C_out]` with rows ordered `(ky, kx, c_in)` (the im2col packing).
pub(crate) fn transform_filters(weight: &[f32], c_in: usize, c_out: usize) -> Vec<f32> {
    const G: [[f64; 3]; 4] = [
        [1.0, 0.0, 0.0],
        [0.5, 0.5, 0.5],
        [0.5, -0.5, 0.5],
        [0.0, 0.0, 1.0],
    ];
    let mut u = vec![0f32; 16 * c_in * c_out];
    for ci in 0..c_in {
        for co in 0..c_out {
            let g = |ky: usize, kx: usize| weight[((ky * 3 + kx) * c_in + ci) * c_out + co] as f64;
            for i in 0..4 {
                for j in 0..4 {
                    let mut v = 0.0;
                    for (ky, gi) in G[i].iter().enumerate() {
                        for (kx, gj) in G[j].iter().enumerate() {
                            v += gi * g(ky, kx) * gj;
                        }
                    }
                    u[((i * 4 + j) * c_in + ci) * c_out + co] = v as f32;
                }
            }
        }
    }
    u
}

/// `out = a - b` over channels.
fn sub(out: &mut [f32], a: &[f32], b: &[f32]) {
    out.iter_mut()
        .zip(a.iter().zip(b))
        .for_each(|(o, (a, b))| *o = a - b);
}

/// `out = a + b` over channels.
fn add(out: &mut [f32], a: &[f32], b: &[f32]) {
    out.iter_mut()
        .zip(a.iter().zip(b))
        .for_each(|(o, (a, b))| *o = a + b);
}

/// `Bᵀ` applied to four channel rows: `(d0 − d2, d1 + d2, d2 − d1, d1 − d3)`.
fn input_transform(out: [&mut [f32]; 4], d: [&[f32]; 4]) {
    let [o0, o1, o2, o3] = out;
    sub(o0, d[0], d[2]);
    add(o1, d[1], d[2]);
    sub(o2, d[2], d[1]);
    sub(o3, d[1], d[3]);
}

/// `Aᵀ` applied to four channel rows: `(m0 + m1 + m2, m1 − m2 − m3)`.
fn output_transform(o0: &mut [f32], o1: &mut [f32], m: [&[f32]; 4]) {
    for i in 0..o0.len() {
        o0[i] = m[0][i] + m[1][i] + m[2][i];
        o1[i] = m[1][i] - m[2][i] - m[3][i];
    }
}

/// Per-thread scratch of one band.
struct Scratch {
    /// Transformed input tiles `[16, CHUNK_TILES, C_in]`.
    v: Vec<f32>,
    /// Products `[16, CHUNK_TILES, C_out]`.
    m: Vec<f32>,
    /// Row-transformed tile `[4, 4, C]` (C = max(C_in, C_out)).
    t: Vec<f32>,
}

/// `act(conv3x3(x) + bias + residual)` with stride 1 and padding 1; `u` from
/// [`transform_filters`].
pub(crate) fn conv3x3_winograd(
    x: &FeatureMap,
    u: &[f32],
    bias: &[f32],
    c_out: usize,
    epi: Epilogue,
    out: &mut FeatureMap,
) {
    let (h, w, c_in) = (x.height, x.width, x.channels);
    let (th, tw) = (h.div_ceil(2), w.div_ceil(2));
    // tile rows per band: enough tiles for one full product when the rows are narrow
    let band = CHUNK_TILES.div_ceil(tw).max(1);
    let zeros = vec![0f32; c_in];
    let image_out = h * w * c_out;
    for b in 0..x.batch {
        let input = &x.data[b * h * w * c_in..(b + 1) * h * w * c_in];
        let residual = epi
            .residual
            .map(|r| &r.data[b * image_out..(b + 1) * image_out]);
        let dst = &mut out.data[b * image_out..(b + 1) * image_out];
        dst.par_chunks_mut(2 * band * w * c_out)
            .enumerate()
            .for_each_init(
                || Scratch {
                    v: vec![0f32; 16 * CHUNK_TILES * c_in],
                    m: vec![0f32; 16 * CHUNK_TILES * c_out],
                    t: vec![0f32; 16 * c_in.max(c_out)],
                },
                |s, (bi, rows)| {
                    let ty0 = bi * band;
                    let tiles = (th - ty0).min(band) * tw;
                    let row0 = 2 * ty0;
                    for first in (0..tiles).step_by(CHUNK_TILES) {
                        let m = (tiles - first).min(CHUNK_TILES);
                        // 1. transformed input V_ξ[t, :] = (Bᵀ d B)_ξ
                        for t in 0..m {
                            let (ty, tx) = (ty0 + (first + t) / tw, (first + t) % tw);
                            let pixel = |r: usize, q: usize| -> &[f32] {
                                let (iy, ix) =
                                    ((2 * ty + r) as isize - 1, (2 * tx + q) as isize - 1);
                                if iy < 0 || ix < 0 || iy >= h as isize || ix >= w as isize {
                                    &zeros
                                } else {
                                    let at = (iy as usize * w + ix as usize) * c_in;
                                    &input[at..at + c_in]
                                }
                            };
                            // rows: t[r][j] = Bᵀ over the 4 columns of input row r
                            let tr = &mut s.t[..16 * c_in];
                            for r in 0..4 {
                                let (a, rest) =
                                    tr[r * 4 * c_in..(r + 1) * 4 * c_in].split_at_mut(c_in);
                                let (b1, rest) = rest.split_at_mut(c_in);
                                let (b2, b3) = rest.split_at_mut(c_in);
                                input_transform(
                                    [a, b1, b2, b3],
                                    [pixel(r, 0), pixel(r, 1), pixel(r, 2), pixel(r, 3)],
                                );
                            }
                            // columns: V[i][j] = Bᵀ over the 4 rows of t[·][j]
                            for j in 0..4 {
                                let d = |r: usize| &tr[(r * 4 + j) * c_in..(r * 4 + j + 1) * c_in];
                                let base = |i: usize| ((i * 4 + j) * CHUNK_TILES + t) * c_in;
                                let (v0, v1, v2, v3) =
                                    split4(&mut s.v, [base(0), base(1), base(2), base(3)], c_in);
                                input_transform([v0, v1, v2, v3], [d(0), d(1), d(2), d(3)]);
                            }
                        }
                        // 2. the 16 products M_ξ = V_ξ · U_ξ
                        for xi in 0..16 {
                            let v = &s.v[xi * CHUNK_TILES * c_in..][..m * c_in];
                            let mm = &mut s.m[xi * CHUNK_TILES * c_out..][..m * c_out];
                            product(
                                mm,
                                v,
                                &u[xi * c_in * c_out..(xi + 1) * c_in * c_out],
                                m,
                                c_out,
                                c_in,
                            );
                        }
                        // 3. output blocks Y = Aᵀ M A, bias, residual, activation
                        let tr = &mut s.t[..16 * c_out];
                        for t in 0..m {
                            let (ty, tx) = (ty0 + (first + t) / tw, (first + t) % tw);
                            let mrow = |i: usize, j: usize| {
                                &s.m[((i * 4 + j) * CHUNK_TILES + t) * c_out..][..c_out]
                            };
                            // over rows i: r[0][j] = M0j + M1j + M2j, r[1][j] = M1j − M2j − M3j
                            for j in 0..4 {
                                let (r0, r1) = tr[j * c_out..].split_at_mut(4 * c_out);
                                output_transform(
                                    &mut r0[..c_out],
                                    &mut r1[..c_out],
                                    [mrow(0, j), mrow(1, j), mrow(2, j), mrow(3, j)],
                                );
                            }
                            for dy in 0..2 {
                                let oy = 2 * ty + dy;
                                if oy >= h {
                                    continue;
                                }
                                let q =
                                    |j: usize| &tr[(dy * 4 + j) * c_out..(dy * 4 + j + 1) * c_out];
                                let (q0, q1, q2, q3) = (q(0), q(1), q(2), q(3));
                                for dx in 0..2 {
                                    let ox = 2 * tx + dx;
                                    if ox >= w {
                                        continue;
                                    }
                                    let at = ((oy - row0) * w + ox) * c_out;
                                    let o = &mut rows[at..at + c_out];
                                    let res_at = (oy * w + ox) * c_out;
                                    for i in 0..c_out {
                                        let v = if dx == 0 {
                                            q0[i] + q1[i] + q2[i]
                                        } else {
                                            q1[i] - q2[i] - q3[i]
                                        };
                                        o[i] = v + bias[i];
                                    }
                                    if let Some(r) = residual {
                                        o.iter_mut()
                                            .zip(&r[res_at..res_at + c_out])
                                            .for_each(|(o, r)| *o += r);
                                    }
                                    if epi.relu {
                                        o.iter_mut().for_each(|v| *v = v.max(0.0));
                                    }
                                }
                            }
                        }
                    }
                },
            );
    }
}

/// Four disjoint `len`-long windows of `buf` at increasing offsets.
fn split4(
    buf: &mut [f32],
    at: [usize; 4],
    len: usize,
) -> (&mut [f32], &mut [f32], &mut [f32], &mut [f32]) {
    let (_, rest) = buf.split_at_mut(at[0]);
    let (a, rest) = rest.split_at_mut(at[1] - at[0]);
    let (b, rest) = rest.split_at_mut(at[2] - at[1]);
    let (c, rest) = rest.split_at_mut(at[3] - at[2]);
    (
        &mut a[..len],
        &mut b[..len],
        &mut c[..len],
        &mut rest[..len],
    )
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
