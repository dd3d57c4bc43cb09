//! Scaled-dot-product attention shared by every block of the network (ViT, frame, joint and
//! PTv3 patch attention all call [`attention`]).
//!
//! Layout `[B, H, L, D]`, scale `1/sqrt(D)`, softmax in f32. On the CPU without a mask it runs
//! the fused tiled kernel of [`crate::kernels::fused_attention`] (bf16 queries: that of
//! [`crate::kernels::bf16::attention`], bf16 products with f32 accumulation); elsewhere (other devices,
//! masks) it runs [`attention_reference`], plain candle ops with queries processed in chunks so
//! the score matrix never exceeds [`SCORE_BUDGET_BYTES`].

use crate::kernels::bf16::attention::bf16_attention;
use crate::kernels::fused_attention::fused_attention;
use candle_core::{DType, Result, Tensor};

/// Upper bound for one chunk's score matrix (f32 bytes).
pub const SCORE_BUDGET_BYTES: usize = 256 << 20;

/// `softmax(q kᵀ / sqrt(D) + mask) v` for `q [B,H,Lq,D]`, `k, v [B,H,Lk,D]`.
///
/// `mask` is an additive f32 tensor broadcastable to `[B,H,Lq,Lk]` (rank 4). The output has
/// the dtype of `q`.
pub fn attention(q: &Tensor, k: &Tensor, v: &Tensor, mask: Option<&Tensor>) -> Result<Tensor> {
    if mask.is_none() && q.device().is_cpu() && q.dtype() == DType::BF16 {
        let bf16_contiguous = |t: &Tensor| t.to_dtype(DType::BF16)?.contiguous();
        return bf16_attention(
            &bf16_contiguous(q)?,
            &bf16_contiguous(k)?,
            &bf16_contiguous(v)?,
        );
    }
    if mask.is_none() && q.device().is_cpu() {
        let in_dtype = q.dtype();
        let f32_contiguous = |t: &Tensor| t.to_dtype(DType::F32)?.contiguous();
        return fused_attention(
            &f32_contiguous(q)?,
            &f32_contiguous(k)?,
            &f32_contiguous(v)?,
        )?
        .to_dtype(in_dtype);
    }
    attention_reference(q, k, v, mask)
}

/// The plain candle-ops attention: the fallback of [`attention`] off the CPU or with a mask,
/// and the reference the fused kernel is tested against. Same contract as [`attention`].
pub fn attention_reference(
    q: &Tensor,
    k: &Tensor,
    v: &Tensor,
    mask: Option<&Tensor>,
) -> Result<Tensor> {
    let (b, h, lq, _) = q.dims4()?;
    let per_row = b * h * k.dim(2)? * 4;
    let chunk = (SCORE_BUDGET_BYTES / per_row.max(1)).clamp(1, lq.max(1));
    attention_in_chunks(q, k, v, mask, chunk)
}

/// [`attention`] with an explicit number of query rows per chunk.
fn attention_in_chunks(
    q: &Tensor,
    k: &Tensor,
    v: &Tensor,
    mask: Option<&Tensor>,
    chunk: usize,
) -> Result<Tensor> {
    let (_, _, lq, d) = q.dims4()?;
    let in_dtype = q.dtype();
    let q = q.to_dtype(DType::F32)?;
    let kt = k.to_dtype(DType::F32)?.t()?.contiguous()?;
    let v = v.to_dtype(DType::F32)?.contiguous()?;
    let scale = 1.0 / (d as f64).sqrt();
    let mut outs = Vec::with_capacity(lq.div_ceil(chunk));
    let mut start = 0;
    while start < lq {
        let len = chunk.min(lq - start);
        let qc = q.narrow(2, start, len)?.contiguous()?;
        let mut scores = (qc.matmul(&kt)? * scale)?;
        if let Some(m) = mask {
            let m = if m.dim(2)? == 1 {
                m.clone()
            } else {
                m.narrow(2, start, len)?
            };
            scores = scores.broadcast_add(&m.to_dtype(DType::F32)?)?;
        }
        let probs = crate::kernels::softmax::softmax_last_dim(&scores)?;
        outs.push(probs.matmul(&v)?);
        start += len;
    }
    let out = if outs.len() == 1 {
        outs.pop().unwrap_or(q)
    } else {
        Tensor::cat(&outs, 2)?
    };
    out.to_dtype(in_dtype)
}

/// Splits `[B, L, H·D]` into heads `[B, H, L, D]`.
pub fn split_heads(x: &Tensor, heads: usize) -> Result<Tensor> {
    let (b, l, c) = x.dims3()?;
    x.reshape((b, l, heads, c / heads))?
        .transpose(1, 2)?
        .contiguous()
}

/// Merges heads `[B, H, L, D]` back into `[B, L, H·D]`.
pub fn merge_heads(x: &Tensor) -> Result<Tensor> {
    let (b, h, l, d) = x.dims4()?;
    x.transpose(1, 2)?.reshape((b, l, h * d))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::max_abs_diff as max_diff;
    use candle_core::Device;

    /// Naive reference: explicit loops over every (b, h, i).
    fn naive(q: &Tensor, k: &Tensor, v: &Tensor, mask: Option<&Tensor>) -> Vec<f32> {
        let (b, h, lq, d) = q.dims4().unwrap();
        let lk = k.dim(2).unwrap();
        let q = q.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let k = k.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let v = v.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let m = mask.map(|m| {
            m.broadcast_as((b, h, lq, lk))
                .unwrap()
                .flatten_all()
                .unwrap()
                .to_vec1::<f32>()
                .unwrap()
        });
        let mut out = vec![0f32; b * h * lq * d];
        for bh in 0..b * h {
            for i in 0..lq {
                let mut s: Vec<f64> = (0..lk)
                    .map(|j| {
                        let dot: f64 = (0..d)
                            .map(|c| {
                                q[(bh * lq + i) * d + c] as f64 * k[(bh * lk + j) * d + c] as f64
                            })
                            .sum();
                        dot / (d as f64).sqrt()
                            + m.as_ref().map_or(0.0, |m| m[(bh * lq + i) * lk + j] as f64)
                    })
                    .collect();
                let mx = s.iter().cloned().fold(f64::MIN, f64::max);
                s.iter_mut().for_each(|x| *x = (*x - mx).exp());
                let z: f64 = s.iter().sum();
                for c in 0..d {
                    out[(bh * lq + i) * d + c] = (0..lk)
                        .map(|j| s[j] / z * v[(bh * lk + j) * d + c] as f64)
                        .sum::<f64>() as f32;
                }
            }
        }
        out
    }

    #[test]
    fn attention_equals_naive_reference() {
        let dev = Device::Cpu;
        let q = Tensor::randn(0f32, 1.0, (2, 3, 7, 8), &dev).unwrap();
        let k = Tensor::randn(0f32, 1.0, (2, 3, 11, 8), &dev).unwrap();
        let v = Tensor::randn(0f32, 1.0, (2, 3, 11, 8), &dev).unwrap();
        let got = attention(&q, &k, &v, None)
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        assert!(max_diff(&got, &naive(&q, &k, &v, None)) < 1e-5);
    }

    #[test]
    fn chunked_queries_give_the_same_result() {
        let dev = Device::Cpu;
        let q = Tensor::randn(0f32, 1.0, (1, 2, 10, 4), &dev).unwrap();
        let k = Tensor::randn(0f32, 1.0, (1, 2, 9, 4), &dev).unwrap();
        let v = Tensor::randn(0f32, 1.0, (1, 2, 9, 4), &dev).unwrap();
        let mask = Tensor::randn(0f32, 1.0, (1, 1, 10, 9), &dev).unwrap();
        let whole = attention_in_chunks(&q, &k, &v, Some(&mask), 10).unwrap();
        let chunked = attention_in_chunks(&q, &k, &v, Some(&mask), 3).unwrap();
        let diff = crate::testing::max_abs_diff(&whole, &chunked);
        assert!(diff < 1e-6);
    }

    #[test]
    fn masked_keys_get_no_weight() {
        let dev = Device::Cpu;
        let q = Tensor::randn(0f32, 1.0, (1, 2, 5, 4), &dev).unwrap();
        let k = Tensor::randn(0f32, 1.0, (1, 2, 6, 4), &dev).unwrap();
        let v = Tensor::randn(0f32, 1.0, (1, 2, 6, 4), &dev).unwrap();
        let mut m = vec![0f32; 6];
        m[5] = f32::NEG_INFINITY;
        let mask = Tensor::from_vec(m, (1, 1, 1, 6), &dev).unwrap();
        let got = attention(&q, &k, &v, Some(&mask)).unwrap();
        let reference = attention(
            &q,
            &k.narrow(2, 0, 5).unwrap(),
            &v.narrow(2, 0, 5).unwrap(),
            None,
        )
        .unwrap();
        let diff = crate::testing::max_abs_diff(&got, &reference);
        assert!(diff < 1e-6);
        let naive_out = naive(&q, &k, &v, Some(&mask));
        let got = attention(&q, &k, &v, Some(&mask))
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        assert!(max_diff(&got, &naive_out) < 1e-5);
    }
}
