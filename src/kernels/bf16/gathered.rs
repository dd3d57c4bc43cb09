//! Gathered bf16 products: `out[M, N] = b + X · W₀ᵀ + Σ_o scatter(outs_o, X[ins_o] · W_oᵀ)`,
//! the shape of a submanifold sparse convolution (one weight per kernel offset, each offset
//! pairing input rows with output rows). The centre product writes the f32 accumulator, each
//! offset gathers its input rows (bf16), multiplies them with its packed weight and adds the
//! products to its output rows; the bias and the rounding to the input's dtype end it.

use candle_core::backend::BackendStorage;
use candle_core::{CpuStorage, CustomOp1, Layout, Result, Shape};
use rayon::prelude::*;

use super::gemm::{gemm_overwrite, gemm_uninit, Lhs};
use super::pack::round_to_bf16;
use super::{Kernel, PackedRhs};

/// The input rows an offset reads and the output rows its products add to (same length).
#[derive(Debug, Clone, Default)]
pub struct OffsetPairs {
    /// Rows of the input.
    pub inputs: Vec<u32>,
    /// Rows of the output, each at most once per offset.
    pub outputs: Vec<u32>,
}

/// The candle op over `X [M, K]` in bf16, giving `[M, N]` in bf16.
#[derive(Debug, Clone, Copy)]
pub struct GatheredProducts<'a> {
    /// `W₀ [N, K]`, applied to every row in place.
    pub centre: &'a PackedRhs,
    /// The other offsets' packed weights `[N, K]`.
    pub weights: &'a [PackedRhs],
    /// The row pairs of each of `weights` (same length).
    pub pairs: &'a [OffsetPairs],
    /// `[N]`.
    pub bias: &'a [f32],
}

impl GatheredProducts<'_> {
    /// The sums `out[M, N]` without the bias, in f32, for the input rows `x` (`m` rows of `k`).
    fn products(&self, x: &[half::bf16], m: usize, k: usize) -> Result<Vec<f32>> {
        let n = self.centre.n();
        if self.centre.k() != k || self.bias.len() != n {
            candle_core::bail!(
                "sparse conv: input has {k} channels, weight expects {} (bias {} of {n})",
                self.centre.k(),
                self.bias.len()
            );
        }
        let mut acc: Vec<f32> = Vec::with_capacity(m * n);
        gemm_uninit(
            Kernel::detect(),
            Lhs::Bf16 { data: x, ld: k },
            m,
            self.centre.view(),
            &mut acc.spare_capacity_mut()[..m * n],
            n,
            true,
            None,
        )?;
        // SAFETY: `gemm_uninit` initialised all m × n values (rows n apart, no gaps).
        unsafe { acc.set_len(m * n) };
        if self.weights.len() != self.pairs.len() {
            candle_core::bail!(
                "sparse conv: {} offset weights for {} neighbour lists",
                self.weights.len(),
                self.pairs.len()
            );
        }
        let mut gathered: Vec<u16> = Vec::new();
        let mut products: Vec<f32> = Vec::new();
        for (w, pairs) in self.weights.iter().zip(self.pairs) {
            let p = pairs.inputs.len();
            if p == 0 {
                continue;
            }
            if w.n() != n || w.k() != k || pairs.outputs.len() != p {
                candle_core::bail!(
                    "sparse conv: an offset's weight is {}×{} (expected {n}×{k}) or its pairs differ in length",
                    w.n(),
                    w.k()
                );
            }
            if let Some(&bad) = pairs
                .inputs
                .iter()
                .chain(&pairs.outputs)
                .find(|&&r| r as usize >= m)
            {
                candle_core::bail!("sparse conv: row {bad} of a neighbour pair is past {m} rows");
            }
            gathered.resize(p * k, 0);
            gathered
                .par_chunks_mut(k)
                .zip(pairs.inputs.par_iter())
                .for_each(|(dst, &row)| {
                    let row = row as usize * k;
                    dst.copy_from_slice(bytemuck::cast_slice(&x[row..row + k]))
                });
            products.resize(p * n, 0.0);
            let lhs = Lhs::Bf16 {
                data: bytemuck::cast_slice(&gathered),
                ld: k,
            };
            gemm_overwrite(lhs, p, w.view(), &mut products, n, true)?;
            for (src, &row) in products.chunks_exact(n).zip(&pairs.outputs) {
                let dst = &mut acc[row as usize * n..(row as usize + 1) * n];
                dst.iter_mut().zip(src).for_each(|(d, s)| *d += s);
            }
        }
        Ok(acc)
    }
}

impl CustomOp1 for GatheredProducts<'_> {
    fn name(&self) -> &'static str {
        "bf16-sparse-conv"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        let (m, k) = l.shape().dims2()?;
        let Some((a, b)) = l.contiguous_offsets() else {
            candle_core::bail!("sparse conv: input is not contiguous");
        };
        let n = self.centre.n();
        let CpuStorage::BF16(d) = s else {
            candle_core::bail!("sparse conv: input is {:?}, expected bf16", s.dtype());
        };
        let mut acc = self.products(&d[a..b], m, k)?;
        // The bias in f32, then one rounding per output row.
        let mut out = vec![half::bf16::ZERO; m * n];
        out.par_chunks_mut(n.max(1))
            .zip(acc.par_chunks_mut(n.max(1)))
            .for_each(|(o, v)| {
                v.iter_mut().zip(self.bias).for_each(|(v, b)| *v += b);
                round_to_bf16(v, bytemuck::cast_slice_mut(o));
            });
        let storage = CpuStorage::BF16(out);
        Ok((storage, Shape::from((m, n))))
    }
}

/// Rounds f32 values to bf16 bits one by one (tests).
#[cfg(test)]
fn rounded(v: &[f32]) -> Vec<half::bf16> {
    v.iter()
        .map(|&x| half::bf16::from_bits(super::f32_to_bf16_bits(x)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device, Tensor};

    fn values(n: usize, seed: u32) -> Vec<f32> {
        (0..n)
            .map(|i| (((i as u32).wrapping_mul(2_654_435_761) ^ seed) % 1000) as f32 / 500.0 - 1.0)
            .collect()
    }

    #[test]
    fn gathered_products_equal_per_offset_sums_and_a_bad_pair_is_an_error() -> Result<()> {
        let (m, k, n) = (90, 24, 40);
        let x = rounded(&values(m * k, 1));
        let weights: Vec<Vec<f32>> = (0..3)
            .map(|o| {
                rounded(&values(n * k, 10 + o))
                    .iter()
                    .map(|v| v.to_f32())
                    .collect()
            })
            .collect();
        let bias = values(n, 7);
        let pairs = [
            OffsetPairs {
                inputs: (1..m as u32).collect(),
                outputs: (0..m as u32 - 1).collect(),
            },
            OffsetPairs {
                inputs: vec![5, 0, 89],
                outputs: vec![2, 88, 3],
            },
        ];
        let packed = |w: &[f32]| PackedRhs::from_rows(w, n, k).unwrap();
        let offset_weights = [packed(&weights[1]), packed(&weights[2])];
        let op = GatheredProducts {
            centre: &packed(&weights[0]),
            weights: &offset_weights,
            pairs: &pairs,
            bias: &bias,
        };
        let xt = Tensor::from_vec(x.clone(), (m, k), &Device::Cpu)?;
        let got = xt.apply_op1_no_bwd(&op)?;
        assert_eq!(got.dtype(), DType::BF16);
        let got: Vec<f32> = got.flatten_all()?.to_dtype(DType::F32)?.to_vec1()?;
        let xf: Vec<f32> = x.iter().map(|v| v.to_f32()).collect();
        let dot = |w: &[f32], row: usize, j: usize| -> f32 {
            (0..k).map(|t| xf[row * k + t] * w[j * k + t]).sum()
        };
        for i in 0..m {
            for j in 0..n {
                let mut want = bias[j] + dot(&weights[0], i, j);
                for (o, p) in pairs.iter().enumerate() {
                    for (&src, &dst) in p.inputs.iter().zip(&p.outputs) {
                        if dst as usize == i {
                            want += dot(&weights[o + 1], src as usize, j);
                        }
                    }
                }
                let g = got[i * n + j];
                // One bf16 rounding of the output (2⁻⁸ relative) plus f32 sums.
                assert!(
                    (g - want).abs() <= 4e-3 * want.abs() + 1e-3,
                    "({i}, {j}): {g} vs {want}"
                );
            }
        }
        let mut bad = pairs.clone();
        bad[1].inputs[0] = m as u32;
        let op = GatheredProducts { pairs: &bad, ..op };
        let e = xt.apply_op1_no_bwd(&op).unwrap_err().to_string();
        assert!(
            e.contains("sparse conv") && e.contains("past 90 rows"),
            "{e}"
        );
        Ok(())
    }
}
