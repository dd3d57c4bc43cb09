//! Scaled dot-product attention for the point blocks, `[B, H, L, D]` layout, softmax in f32,
//! scale `1/sqrt(D)`. Queries are processed in chunks so that the score matrix never exceeds a
//! fixed budget (a patch of 4,096 points with 16 heads would otherwise need 1 GiB).
//!
//! Private stand-in for the shared `model::attention` helper (owned by `model-image`); a later
//! task replaces both by one fused CPU kernel.

use candle_core::{DType, Result, Tensor};

/// Largest number of score elements materialised at once (8 MiB of f32: small enough for the
/// allocator to reuse the buffer instead of mapping fresh pages for every chunk).
const SCORE_BUDGET: usize = 1 << 21;

/// `softmax(q kᵀ / sqrt(D)) v` for `q [B, H, Lq, D]`, `k, v [B, H, Lk, D]` → `[B, H, Lq, D]`.
pub fn attention(q: &Tensor, k: &Tensor, v: &Tensor) -> Result<Tensor> {
    let (b, h, lq, d) = q.dims4()?;
    let lk = k.dim(2)?;
    let bh = b * h;
    let scale = 1.0 / (d as f64).sqrt();
    let q = (q.reshape((bh, lq, d))? * scale)?;
    let kt = k.reshape((bh, lk, d))?.t()?.contiguous()?;
    let v = v.reshape((bh, lk, d))?.contiguous()?;
    let chunk = (SCORE_BUDGET / (bh * lk).max(1)).clamp(1, lq.max(1));
    let mut outs = Vec::with_capacity(lq.div_ceil(chunk));
    let mut start = 0;
    while start < lq {
        let len = chunk.min(lq - start);
        let qc = q.narrow(1, start, len)?.contiguous()?;
        let scores = qc.matmul(&kt)?;
        let probs =
            candle_nn::ops::softmax_last_dim(&scores.to_dtype(DType::F32)?)?.to_dtype(v.dtype())?;
        outs.push(probs.matmul(&v)?);
        start += len;
    }
    let out = if outs.len() == 1 {
        outs.pop().expect("one chunk")
    } else {
        Tensor::cat(&outs, 1)?
    };
    out.reshape((b, h, lq, d))
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    #[test]
    fn chunked_attention_equals_the_plain_formula() -> Result<()> {
        let dev = Device::Cpu;
        // 2 heads × 4,000 keys: the 300 queries are split into two chunks by the budget
        let q = Tensor::randn(0f32, 1.0, (1, 2, 300, 4), &dev)?;
        let k = Tensor::randn(0f32, 1.0, (1, 2, 4000, 4), &dev)?;
        let v = Tensor::randn(0f32, 1.0, (1, 2, 4000, 4), &dev)?;
        const { assert!(SCORE_BUDGET / (2 * 4000) < 300) };
        let got = attention(&q, &k, &v)?;
        let s = (q.matmul(&k.t()?)? * 0.5)?;
        let want = candle_nn::ops::softmax_last_dim(&s)?.matmul(&v)?;
        let diff = (got - want)?
            .abs()?
            .flatten_all()?
            .max(0)?
            .to_scalar::<f32>()?;
        assert!(diff < 1e-5, "{diff}");
        Ok(())
    }
}
