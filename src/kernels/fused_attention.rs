//! Fused tiled scaled-dot-product attention on the CPU, as a candle [`CustomOp3`].
//!
//! For every (batch·head, block of [`QUERY_BLOCK`] queries) — the unit of work handed to rayon —
//! the keys are visited in blocks of [`KEY_BLOCK`]: `S = scale · Q Kᵀ` through the `gemm`
//! matrix kernel into a small reused buffer, an online softmax (running row max and sum, one
//! rescale of the accumulator per block, exponentials from [`super::fast_exp`]), then
//! `O += P V` through `gemm` again. The `Lq × Lk` score matrix is never materialised; the
//! memory per unit of work is `QUERY_BLOCK × (KEY_BLOCK + D)` floats.
//!
//! Layout `[B, H, L, D]`, f32, contiguous (any start offset). No mask: call sites with a mask
//! use the plain candle path in `model::attention`.

use super::fast_exp::{exp_approx, exp_shifted_sum, max_of};
use super::matmul::{matmul_into, MatRef};
use candle_core::backend::BackendStorage;
use candle_core::{CpuStorage, CustomOp3, DType, Layout, Result, Shape, Tensor};
use gemm::Parallelism;
use rayon::prelude::*;

/// Query rows per unit of work.
pub const QUERY_BLOCK: usize = 128;
/// Keys per block of the online softmax.
pub const KEY_BLOCK: usize = 512;

/// Why the fused attention refused its inputs.
#[derive(Debug, thiserror::Error)]
pub enum FusedAttentionError {
    /// An operand is not f32.
    #[error("fused attention: operand `{operand}` is {dtype:?}, expected f32")]
    DType {
        /// `q`, `k` or `v`.
        operand: &'static str,
        /// Its dtype.
        dtype: DType,
    },
    /// An operand is not laid out contiguously.
    #[error("fused attention: operand `{operand}` is not contiguous")]
    NotContiguous {
        /// `q`, `k` or `v`.
        operand: &'static str,
    },
    /// The shapes do not form `q [B,H,Lq,D]`, `k [B,H,Lk,D]`, `v [B,H,Lk,Dv]` with `Lk > 0`.
    #[error("fused attention: shapes q {q:?}, k {k:?}, v {v:?} do not match")]
    Shapes {
        /// Shape of `q`.
        q: Vec<usize>,
        /// Shape of `k`.
        k: Vec<usize>,
        /// Shape of `v`.
        v: Vec<usize>,
    },
    /// The operands are not on the CPU.
    #[error("fused attention: runs on the CPU only, got {device}")]
    NotCpu {
        /// The device of `q`.
        device: String,
    },
}

/// The candle op: `softmax(scale · q kᵀ) v`.
#[derive(Debug, Clone, Copy)]
pub struct FusedAttention {
    /// Multiplier of the scores, usually `1/sqrt(D)`.
    pub scale: f32,
}

/// `softmax(q kᵀ / sqrt(D)) v` for contiguous f32 CPU tensors `q [B,H,Lq,D]`,
/// `k [B,H,Lk,D]`, `v [B,H,Lk,Dv]` → `[B,H,Lq,Dv]`.
pub fn fused_attention(q: &Tensor, k: &Tensor, v: &Tensor) -> Result<Tensor> {
    if !q.device().is_cpu() {
        return Err(candle_core::Error::wrap(FusedAttentionError::NotCpu {
            device: format!("{:?}", q.device()),
        }));
    }
    let d = q.dim(3)?;
    let scale = 1.0 / (d as f32).sqrt();
    q.apply_op3_no_bwd(k, v, &FusedAttention { scale })
}

/// The f32 data of one operand from its start offset, or why not.
fn contiguous_f32<'a>(
    storage: &'a CpuStorage,
    layout: &Layout,
    operand: &'static str,
) -> std::result::Result<&'a [f32], FusedAttentionError> {
    let CpuStorage::F32(data) = storage else {
        return Err(FusedAttentionError::DType {
            operand,
            dtype: storage.dtype(),
        });
    };
    match layout.contiguous_offsets() {
        Some((start, end)) => Ok(&data[start..end]),
        None => Err(FusedAttentionError::NotContiguous { operand }),
    }
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
    /// Checks the three shapes against each other.
    fn of(q: &Shape, k: &Shape, v: &Shape) -> std::result::Result<Self, FusedAttentionError> {
        let bad = || FusedAttentionError::Shapes {
            q: q.dims().to_vec(),
            k: k.dims().to_vec(),
            v: v.dims().to_vec(),
        };
        let (&[b, h, lq, d], &[kb, kh, lk, kd], &[vb, vh, vl, dv]) = (q.dims(), k.dims(), v.dims())
        else {
            return Err(bad());
        };
        if (kb, kh, kd) != (b, h, d) || (vb, vh, vl) != (b, h, lk) || lk == 0 {
            return Err(bad());
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

impl CustomOp3 for FusedAttention {
    fn name(&self) -> &'static str {
        "fused-attention"
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
        let inputs = (|| {
            let dims = Dims::of(l1.shape(), l2.shape(), l3.shape())?;
            let q = contiguous_f32(s1, l1, "q")?;
            let k = contiguous_f32(s2, l2, "k")?;
            let v = contiguous_f32(s3, l3, "v")?;
            Ok::<_, FusedAttentionError>((dims, q, k, v))
        })();
        let (dims, q, k, v) = inputs.map_err(candle_core::Error::wrap)?;
        let mut out = vec![0f32; dims.bh * dims.lq * dims.dv];
        if dims.lq > 0 && dims.dv > 0 {
            attend_all(self.scale, dims, q, k, v, &mut out);
        }
        let b = l1.shape().dims()[0];
        let h = l1.shape().dims()[1];
        Ok((CpuStorage::F32(out), Shape::from((b, h, dims.lq, dims.dv))))
    }
}

/// Fills `out [BH, Lq, Dv]`, one rayon task per (head, query block).
fn attend_all(scale: f32, dims: Dims, q: &[f32], k: &[f32], v: &[f32], out: &mut [f32]) {
    let Dims { lq, lk, d, dv, .. } = dims;
    // Keys transposed once per head (`[D, Lk]`): the score products then read them with unit
    // stride along the keys, which `gemm` streams without repacking.
    let mut kt = vec![0f32; k.len()];
    kt.par_chunks_mut(lk * d)
        .zip(k.par_chunks(lk * d))
        .for_each(|(dst, src)| {
            for (j, row) in src.chunks_exact(d).enumerate() {
                for (c, &val) in row.iter().enumerate() {
                    dst[c * lk + j] = val;
                }
            }
        });
    let k = &kt;
    out.par_chunks_mut(lq * dv)
        .enumerate()
        .for_each(|(head, out_head)| {
            let q_head = &q[head * lq * d..(head + 1) * lq * d];
            let k_head = &k[head * lk * d..(head + 1) * lk * d];
            let v_head = &v[head * lk * dv..(head + 1) * lk * dv];
            out_head
                .par_chunks_mut(QUERY_BLOCK * dv)
                .enumerate()
                .for_each(|(block, out_block)| {
                    let rows = out_block.len() / dv;
                    let q_block = &q_head[block * QUERY_BLOCK * d..][..rows * d];
                    attend_block(scale, dims, q_block, k_head, v_head, out_block);
                });
        });
}

/// One unit of work: `rows ≤ QUERY_BLOCK` queries of one head against all its keys.
fn attend_block(
    scale: f32,
    dims: Dims,
    q_block: &[f32],
    k_head: &[f32],
    v_head: &[f32],
    out_block: &mut [f32],
) {
    let Dims { lk, d, dv, .. } = dims;
    let rows = q_block.len() / d;
    // `k_head` is `[D, Lk]` (keys transposed).
    let mut scores = vec![0f32; rows * KEY_BLOCK];
    let mut acc = vec![0f32; rows * dv];
    let mut row_max = vec![f32::NEG_INFINITY; rows];
    let mut row_sum = vec![0f32; rows];
    let mut key = 0;
    while key < lk {
        let keys = KEY_BLOCK.min(lk - key);
        let k_block = &k_head[key..];
        let v_block = &v_head[key * dv..(key + keys) * dv];
        // Scores `rows × keys` (rows KEY_BLOCK apart) = scale · Q · K, K read as `d × keys`
        // with rows `lk` apart from column `key` of the `[D, Lk]` head.
        matmul_into(
            &mut scores,
            KEY_BLOCK,
            MatRef::row_major(q_block, rows, d),
            MatRef::rows_apart(k_block, d, keys, lk),
            false,
            scale,
            Parallelism::None,
        );
        for r in 0..rows {
            let s = &mut scores[r * KEY_BLOCK..r * KEY_BLOCK + keys];
            let new_max = row_max[r].max(max_of(s));
            let correction = if row_max[r] == f32::NEG_INFINITY {
                0.0
            } else {
                exp_approx(row_max[r] - new_max)
            };
            row_sum[r] = row_sum[r] * correction + exp_shifted_sum(s, new_max);
            row_max[r] = new_max;
            if correction != 1.0 {
                acc[r * dv..(r + 1) * dv]
                    .iter_mut()
                    .for_each(|a| *a *= correction);
            }
        }
        matmul_into(
            &mut acc,
            dv,
            MatRef::rows_apart(&scores, rows, keys, KEY_BLOCK),
            MatRef::row_major(v_block, keys, dv),
            true,
            1.0,
            Parallelism::None,
        );
        key += keys;
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
}
