//! Softmax over the last dimension with the vectorised exponential of [`super::fast_exp`]
//! (rows in parallel), for f32 CPU tensors; candle's `softmax_last_dim` elsewhere. The fused
//! attention has its own online softmax; this one serves the masked attention path.

use candle_core::{CpuStorage, CustomOp1, DType, Layout, Result, Shape, Tensor};
use rayon::prelude::*;

use super::fast_exp::{exp_shifted_sum, max_of};

/// Rows per rayon task.
const ROWS_PER_TASK: usize = 16;

/// `softmax(x)` along the last dimension.
pub fn softmax_last_dim(x: &Tensor) -> Result<Tensor> {
    if x.device().is_cpu() && x.dtype() == DType::F32 {
        return x.contiguous()?.apply_op1_no_bwd(&SoftmaxOp);
    }
    candle_nn::ops::softmax_last_dim(x)
}

/// The candle op.
#[derive(Debug, Clone, Copy)]
struct SoftmaxOp;

impl CustomOp1 for SoftmaxOp {
    fn name(&self) -> &'static str {
        "softmax-last-dim"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        let mut out = super::contiguous_f32(s, l, "softmax", "input")?.to_vec();
        let c = l.shape().dims().last().copied().unwrap_or(0);
        if c > 0 {
            out.par_chunks_mut(ROWS_PER_TASK * c).for_each(|rows| {
                for row in rows.chunks_exact_mut(c) {
                    let m = max_of(row);
                    // A row of −∞ (fully masked) gives NaN in PyTorch; keep it finite (zeros).
                    let shift = if m == f32::NEG_INFINITY { 0.0 } else { m };
                    let inv = 1.0 / exp_shifted_sum(row, shift);
                    row.iter_mut().for_each(|v| *v *= inv);
                }
            });
        }
        Ok((CpuStorage::F32(out), l.shape().clone()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    #[test]
    fn softmax_equals_candle_softmax_on_odd_rows() {
        for &(rows, c) in &[(1usize, 1usize), (5, 7), (33, 513)] {
            let x = (Tensor::randn(0f32, 4.0, (rows, c), &Device::Cpu).unwrap() - 20.0).unwrap();
            let got = softmax_last_dim(&x).unwrap();
            let want = candle_nn::ops::softmax_last_dim(&x).unwrap();
            let d = crate::testing::max_abs_diff(&got, &want);
            assert!(d < 1e-6, "rows={rows} c={c}: {d}");
        }
    }

    #[test]
    fn rows_sum_to_one_with_large_logits() {
        let x = Tensor::new(
            &[[1000f32, 999.0, -1000.0], [-5.0, -5.0, -5.0]],
            &Device::Cpu,
        )
        .unwrap();
        let y = softmax_last_dim(&x).unwrap().to_vec2::<f32>().unwrap();
        for row in y {
            assert!((row.iter().sum::<f32>() - 1.0).abs() < 1e-6);
            assert!(row.iter().all(|v| v.is_finite()));
        }
    }
}
