//! Fused tiled attention with bf16 products: `softmax(scale · q kᵀ) v` where both products run
//! through the bf16 micro-kernel ([`super::gemm`]) with f32 accumulation and the online softmax
//! stays in f32 (the structure of [`crate::kernels::fused_attention`]).
//!
//! Per head the keys are packed once as the right operand of the score product (`[Lk, D]`)
//! and the values transposed into that of the output product (`[Dv, Lk]`); per (head, block of
//! [`QUERY_BLOCK`] queries) — the unit of work handed to rayon — the keys are visited in blocks
//! of [`KEY_BLOCK`]: scores into an f32 buffer, running max and sum, one rescale of the f32
//! accumulator per block, then the probabilities (rounded to bf16 as the product reads them)
//! times the values. Layout `[B, H, L, D]`, contiguous, bf16 or f32; the output has the dtype
//! of `q`.

use candle_core::backend::BackendStorage;
use candle_core::{CpuStorage, CustomOp3, DType, Layout, Result, Shape, Tensor};
use rayon::prelude::*;

use super::gemm::{gemm, gemm_overwrite, Lhs};
use super::pack::{PackedRhs, Strided, ToBf16Bits};
use super::{f32_to_bf16_bits, NR};
use crate::kernels::fast_exp::{exp_approx, max_of};

/// Query rows per unit of work.
pub const QUERY_BLOCK: usize = 128;
/// Keys per block of the online softmax (a multiple of the packed tile width, [`NR`]).
pub const KEY_BLOCK: usize = 8 * NR;

/// The candle op: `softmax(scale · q kᵀ) v` in bf16 products.
#[derive(Debug, Clone, Copy)]
pub struct Bf16Attention {
    /// Multiplier of the scores, usually `1/sqrt(D)`.
    pub scale: f32,
}

/// `softmax(q kᵀ / sqrt(D)) v` for contiguous CPU tensors `q [B,H,Lq,D]`, `k [B,H,Lk,D]`,
/// `v [B,H,Lk,Dv]` of dtype bf16 or f32 (all three alike) → `[B,H,Lq,Dv]` in the dtype of `q`.
pub fn bf16_attention(q: &Tensor, k: &Tensor, v: &Tensor) -> Result<Tensor> {
    if !q.device().is_cpu() {
        candle_core::bail!("bf16 attention: runs on the CPU only, got {:?}", q.device());
    }
    let d = q.dim(3)?;
    let scale = 1.0 / (d as f32).sqrt();
    q.apply_op3_no_bwd(k, v, &Bf16Attention { scale })
}

/// Sizes of one call: `bh` heads in all, `lq` queries, `lk` keys, `d` and `dv` channels.
#[derive(Debug, Clone, Copy)]
struct Dims {
    bh: usize,
    lq: usize,
    lk: usize,
    d: usize,
    dv: usize,
}

impl Dims {
    fn of(q: &Shape, k: &Shape, v: &Shape) -> Result<Self> {
        let (&[b, h, lq, d], &[kb, kh, lk, kd], &[vb, vh, vl, dv]) = (q.dims(), k.dims(), v.dims())
        else {
            candle_core::bail!("bf16 attention: shapes q {q:?}, k {k:?}, v {v:?} are not rank 4");
        };
        if (kb, kh, kd) != (b, h, d) || (vb, vh, vl) != (b, h, lk) || lk == 0 {
            candle_core::bail!("bf16 attention: shapes q {q:?}, k {k:?}, v {v:?} do not match");
        }
        Ok(Self {
            bh: b * h,
            lq,
            lk,
            d,
            dv,
        })
    }
}

/// A contiguous operand's values from its start offset.
fn values<'a, T>(data: &'a [T], layout: &Layout, operand: &str) -> Result<&'a [T]> {
    match layout.contiguous_offsets() {
        Some((a, b)) => Ok(&data[a..b]),
        None => candle_core::bail!("bf16 attention: operand `{operand}` is not contiguous"),
    }
}

/// The three operands with one element type.
enum Operands<'a> {
    Bf16([&'a [half::bf16]; 3]),
    F32([&'a [f32]; 3]),
}

impl CustomOp3 for Bf16Attention {
    fn name(&self) -> &'static str {
        "bf16-attention"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        let dims = Dims::of(l1.shape(), l2.shape(), l3.shape())?;
        let ops = match (s1, s2, s3) {
            (CpuStorage::BF16(q), CpuStorage::BF16(k), CpuStorage::BF16(v)) => Operands::Bf16([
                values(q, l1, "q")?,
                values(k, l2, "k")?,
                values(v, l3, "v")?,
            ]),
            (CpuStorage::F32(q), CpuStorage::F32(k), CpuStorage::F32(v)) => Operands::F32([
                values(q, l1, "q")?,
                values(k, l2, "k")?,
                values(v, l3, "v")?,
            ]),
            _ => candle_core::bail!(
                "bf16 attention: operands are {:?}, {:?}, {:?}; expected all bf16 or all f32",
                s1.dtype(),
                s2.dtype(),
                s3.dtype()
            ),
        };
        let mut out = vec![0f32; dims.bh * dims.lq * dims.dv];
        if dims.lq > 0 && dims.dv > 0 {
            match ops {
                Operands::Bf16([q, k, v]) => attend_all(self.scale, dims, q, k, v, &mut out)?,
                Operands::F32([q, k, v]) => attend_all(self.scale, dims, q, k, v, &mut out)?,
            }
        }
        let shape = Shape::from((l1.shape().dims()[0], l1.shape().dims()[1], dims.lq, dims.dv));
        let storage = if s1.dtype() == DType::BF16 {
            CpuStorage::BF16(
                out.par_iter()
                    .map(|&x| half::bf16::from_bits(f32_to_bf16_bits(x)))
                    .collect(),
            )
        } else {
            CpuStorage::F32(out)
        };
        Ok((storage, shape))
    }
}

/// Element types of the operands: they pack into bf16 and read as the left operand.
trait Operand: ToBf16Bits {
    fn lhs(data: &[Self], ld: usize) -> Lhs<'_>;
}

impl Operand for half::bf16 {
    fn lhs(data: &[Self], ld: usize) -> Lhs<'_> {
        Lhs::Bf16 { data, ld }
    }
}

impl Operand for f32 {
    fn lhs(data: &[Self], ld: usize) -> Lhs<'_> {
        Lhs::F32 { data, ld }
    }
}

/// Fills `out [BH, Lq, Dv]`: packs each head's keys and values, then one rayon task per
/// (head, query block).
fn attend_all<T: Operand>(
    scale: f32,
    dims: Dims,
    q: &[T],
    k: &[T],
    v: &[T],
    out: &mut [f32],
) -> Result<()> {
    let Dims { lq, lk, d, dv, .. } = dims;
    let packed: Vec<(PackedRhs, PackedRhs)> = (0..dims.bh)
        .into_par_iter()
        .map(|head| {
            let keys = PackedRhs::from_rows(&k[head * lk * d..(head + 1) * lk * d], lk, d)?;
            let values_t = PackedRhs::pack(
                Strided {
                    data: &v[head * lk * dv..(head + 1) * lk * dv],
                    col_stride: 1,
                    k_stride: dv,
                },
                dv,
                lk,
            )?;
            Ok((keys, values_t))
        })
        .collect::<Result<_>>()?;
    out.par_chunks_mut(lq * dv)
        .zip(packed.par_iter())
        .enumerate()
        .try_for_each(|(head, (out_head, (keys, values_t)))| {
            let q_head = &q[head * lq * d..(head + 1) * lq * d];
            out_head
                .par_chunks_mut(QUERY_BLOCK * dv)
                .enumerate()
                .try_for_each(|(block, out_block)| {
                    let rows = out_block.len() / dv;
                    let q_block = &q_head[block * QUERY_BLOCK * d..][..rows * d];
                    attend_block(
                        scale,
                        dims,
                        T::lhs(q_block, d),
                        rows,
                        keys,
                        values_t,
                        out_block,
                    )
                })
        })
}

/// One unit of work: `rows ≤ QUERY_BLOCK` queries of one head against all its keys.
fn attend_block(
    scale: f32,
    dims: Dims,
    q_block: Lhs,
    rows: usize,
    keys: &PackedRhs,
    values_t: &PackedRhs,
    out_block: &mut [f32],
) -> Result<()> {
    let Dims { lk, dv, .. } = dims;
    let mut scores = vec![0f32; rows * KEY_BLOCK];
    let mut probs = vec![half::bf16::ZERO; rows * KEY_BLOCK];
    let mut acc = vec![0f32; rows * dv];
    let mut row_max = vec![f32::NEG_INFINITY; rows];
    let mut row_sum = vec![0f32; rows];
    let mut key = 0;
    while key < lk {
        let n_keys = KEY_BLOCK.min(lk - key);
        gemm_overwrite(
            q_block,
            rows,
            keys.view().columns(key, n_keys)?,
            &mut scores,
            KEY_BLOCK,
            false,
        )?;
        for r in 0..rows {
            let s = &scores[r * KEY_BLOCK..r * KEY_BLOCK + n_keys];
            // `scale > 0`, so the largest scaled score is the scaled largest score.
            let new_max = row_max[r].max(scale * row_max_of(s));
            let correction = if row_max[r] == f32::NEG_INFINITY {
                0.0
            } else {
                exp_approx(row_max[r] - new_max)
            };
            let p = &mut probs[r * KEY_BLOCK..r * KEY_BLOCK + n_keys];
            row_sum[r] = row_sum[r] * correction + row_exp(s, scale, new_max, p);
            row_max[r] = new_max;
            if correction != 1.0 {
                acc[r * dv..(r + 1) * dv]
                    .iter_mut()
                    .for_each(|a| *a *= correction);
            }
        }
        let probs = Lhs::Bf16 {
            data: &probs,
            ld: KEY_BLOCK,
        };
        gemm(
            probs,
            rows,
            values_t.view().depth(key, n_keys)?,
            &mut acc,
            dv,
            false,
        )?;
        key += n_keys;
    }
    for r in 0..rows {
        let inv = 1.0 / row_sum[r];
        for (o, a) in out_block[r * dv..(r + 1) * dv]
            .iter_mut()
            .zip(&acc[r * dv..(r + 1) * dv])
        {
            *o = a * inv;
        }
    }
    Ok(())
}

/// Largest score of a row: AVX-512 where the CPU has it.
fn row_max_of(scores: &[f32]) -> f32 {
    #[cfg(all(target_arch = "x86_64", lhmpp_bf16_intrinsics))]
    if super::avx512::available() {
        // SAFETY: the CPU has AVX512F (checked).
        return unsafe { super::avx512::max_of(scores) };
    }
    max_of(scores)
}

/// `exp(scale·s − shift)` of a row's scores as bf16 probabilities, returning their f32 sum:
/// the AVX512-BF16 pass where the CPU has it, else [`exp_to_bf16`].
fn row_exp(scores: &[f32], scale: f32, shift: f32, probs: &mut [half::bf16]) -> f32 {
    #[cfg(all(target_arch = "x86_64", lhmpp_bf16_intrinsics))]
    if super::avx512::available() {
        let bits: &mut [u16] = bytemuck::cast_slice_mut(probs);
        // SAFETY: the CPU has AVX512F and AVX512-BF16 (checked).
        return unsafe { super::avx512::exp_to_bf16(scores, scale, shift, bits) };
    }
    exp_to_bf16(scores, scale, shift, probs)
}

/// The loop of [`exp_to_bf16`], inlined into each instruction-set variant.
#[inline(always)]
fn exp_to_bf16_portable(scores: &[f32], scale: f32, shift: f32, probs: &mut [half::bf16]) -> f32 {
    const LANES: usize = 16;
    let mut lanes = [0f32; LANES];
    let mut s_chunks = scores.chunks_exact(LANES);
    let mut p_chunks = probs.chunks_exact_mut(LANES);
    for (s, p) in (&mut s_chunks).zip(&mut p_chunks) {
        for i in 0..LANES {
            let e = exp_approx(s[i] * scale - shift);
            p[i] = half::bf16::from_bits(f32_to_bf16_bits(e));
            lanes[i] += e;
        }
    }
    let mut total = 0f32;
    for (s, p) in s_chunks.remainder().iter().zip(p_chunks.into_remainder()) {
        let e = exp_approx(s * scale - shift);
        *p = half::bf16::from_bits(f32_to_bf16_bits(e));
        total += e;
    }
    total + lanes.iter().sum::<f32>()
}

crate::simd::simd_dispatch! {
    avx2_fma;
    /// Writes `exp(scale·s − shift)` of every score `s` as bf16 into `probs` (the left operand
    /// of the product with the values, read in place) and returns the sum of the f32 values:
    /// scaling, exponential, rounding and sum in one pass over the scores.
    fn exp_to_bf16[](scores: &[f32], scale: f32, shift: f32, probs: &mut [half::bf16]) -> f32
        = exp_to_bf16_portable;
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    /// `softmax(q·kᵀ/√d)·v` with stock candle ops, in f32.
    fn attention_reference(q: &Tensor, k: &Tensor, v: &Tensor) -> candle_core::Result<Tensor> {
        let d = q.dim(3)? as f64;
        let scores = (q.matmul(&k.t()?.contiguous()?)? / d.sqrt())?;
        candle_nn::ops::softmax_last_dim(&scores)?.matmul(v)
    }

    #[test]
    fn bf16_attention_matches_the_f32_reference_on_rounded_inputs() {
        let dev = Device::Cpu;
        for &(b, h, lq, lk, d, dv) in &[
            (1, 1, 1, 1, 1, 1),
            (1, 2, 5, 7, 9, 3),
            (2, 3, 130, 600, 64, 64),
            (1, 1, 129, 1100, 33, 70),
        ] {
            let r = |shape: (usize, usize, usize, usize)| {
                Tensor::randn(0f32, 1.0, shape, &dev)
                    .unwrap()
                    .to_dtype(DType::BF16)
                    .unwrap()
            };
            let (q, k, v) = (r((b, h, lq, d)), r((b, h, lk, d)), r((b, h, lk, dv)));
            let f = |t: &Tensor| t.to_dtype(DType::F32).unwrap();
            let want = attention_reference(&f(&q), &f(&k), &f(&v)).unwrap();
            let got = bf16_attention(&q, &k, &v).unwrap();
            assert_eq!(got.dtype(), DType::BF16);
            assert_eq!(got.dims(), want.dims());
            let d_bf16 = crate::testing::max_abs_diff(&got, &want);
            // Outputs are averages of unit-normal values: the probabilities' bf16 rounding (2^-9
            // relative each) and the output's (2^-9 of |out| ≤ ~3) bound the error.
            assert!(d_bf16 < 0.03, "{b}×{h}×{lq}×{lk}×{d}×{dv}: {d_bf16}");
            let got = bf16_attention(&f(&q), &f(&k), &f(&v)).unwrap();
            assert_eq!(got.dtype(), DType::F32);
            let d_f32 = crate::testing::max_abs_diff(&got, &want);
            assert!(d_f32 < 0.02, "f32 in: {d_f32}");
        }
    }

    #[test]
    fn the_dispatched_row_passes_match_the_portable_loops() {
        // 37 values: two full vectors and a masked tail; scores up to 40 below the maximum.
        let scores: Vec<f32> = (0..37)
            .map(|i| ((i * 29) % 37) as f32 * -1.1 + 3.0)
            .collect();
        let (scale, shift) = (0.7, 0.7 * 3.0);
        assert_eq!(row_max_of(&scores), max_of(&scores));
        assert_eq!(row_max_of(&[]), f32::NEG_INFINITY);
        let mut want = vec![half::bf16::ZERO; 37];
        let mut got = [half::bf16::from_f32(9.0); 38];
        let want_sum = exp_to_bf16_portable(&scores, scale, shift, &mut want);
        let got_sum = row_exp(&scores, scale, shift, &mut got[..37]);
        assert!(
            ((got_sum - want_sum) / want_sum).abs() < 1e-6,
            "{got_sum} vs {want_sum}"
        );
        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
            let exact = (f64::from(scores[i]) * 0.7 - 2.1).exp();
            assert!(
                (g.to_f64() - exact).abs() <= exact / 256.0,
                "{i}: {g} vs {exact}"
            );
            assert!(
                (g.to_f64() - w.to_f64()).abs() <= exact / 128.0,
                "{i}: {g} vs {w}"
            );
        }
        assert_eq!(got[37].to_f32(), 9.0, "wrote past the row");
    }

    #[test]
    fn mismatched_operands_are_errors_naming_the_op() {
        let dev = Device::Cpu;
        let q = Tensor::zeros((1, 1, 2, 4), DType::BF16, &dev).unwrap();
        let k = Tensor::zeros((1, 1, 3, 5), DType::BF16, &dev).unwrap();
        let e = bf16_attention(&q, &k, &k).unwrap_err();
        assert!(e.to_string().contains("bf16 attention"), "{e}");
        let k = Tensor::zeros((1, 1, 3, 4), DType::F32, &dev).unwrap();
        let e = bf16_attention(&q, &k, &k).unwrap_err();
        assert!(e.to_string().contains("bf16 attention"), "{e}");
    }
}
