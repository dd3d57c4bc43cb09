//! The bf16 path of [`crate::kernels::linear::Linear`]: `act(x Wᵀ + b)` or
//! `r + g ⊙ (x Wᵀ + b)` with the weight packed once ([`PackedRhs`]), the product in bf16 with
//! f32 accumulation ([`super::gemm`]) and the bias, GELU, gate and residual applied in f32.
//! The output has the dtype of the input (bf16 or f32).

use candle_core::backend::BackendStorage;
use candle_core::{CpuStorage, CustomOp1, CustomOp2, DType, Layout, Result, Shape};
use rayon::prelude::*;

use super::gemm::{gemm, Lhs};
use super::{f32_to_bf16_bits, PackedRhs};
use crate::kernels::gelu::{gelu_in_place, gelu_tanh_in_place};
use crate::kernels::linear::Activation;

/// Rows per rayon task of the epilogues and conversions.
const EPILOGUE_ROWS: usize = 16;

/// The candle op: `act(x Wᵀ + b)` of `x [M, K]` (one operand) or `R + g ⊙ (x Wᵀ + b)` with
/// the residual `R [M, N]` as second operand.
#[derive(Debug, Clone, Copy)]
pub struct PackedLinear<'a> {
    /// The packed weight `[N, K]`.
    pub weight: &'a PackedRhs,
    /// The bias `[N]` in f32.
    pub bias: Option<&'a [f32]>,
    /// The gate `[N]` of the residual form.
    pub gate: Option<&'a [f32]>,
    /// What follows the affine map (the plain form only).
    pub act: Activation,
}

/// A contiguous CPU operand as the left operand of the product.
fn lhs<'a>(s: &'a CpuStorage, l: &Layout, k: usize) -> Result<Lhs<'a>> {
    let Some((a, b)) = l.contiguous_offsets() else {
        candle_core::bail!("bf16 linear: input is not contiguous");
    };
    Ok(match s {
        CpuStorage::BF16(d) => Lhs::Bf16 {
            data: &d[a..b],
            ld: k,
        },
        CpuStorage::F32(d) => Lhs::F32 {
            data: &d[a..b],
            ld: k,
        },
        other => candle_core::bail!(
            "bf16 linear: input is {:?}, expected bf16 or f32",
            other.dtype()
        ),
    })
}

/// A contiguous CPU operand's values as f32 (the residual).
fn f32_values(s: &CpuStorage, l: &Layout) -> Result<Vec<f32>> {
    let Some((a, b)) = l.contiguous_offsets() else {
        candle_core::bail!("bf16 linear: residual is not contiguous");
    };
    Ok(match s {
        CpuStorage::BF16(d) => d[a..b].par_iter().map(|v| v.to_f32()).collect(),
        CpuStorage::F32(d) => d[a..b].to_vec(),
        other => candle_core::bail!(
            "bf16 linear: residual is {:?}, expected bf16 or f32",
            other.dtype()
        ),
    })
}

/// `values` as a storage of `dtype` (bf16 rounded to nearest even).
fn to_storage(values: Vec<f32>, dtype: DType) -> CpuStorage {
    if dtype == DType::BF16 {
        let mut out = vec![half::bf16::ZERO; values.len()];
        out.par_chunks_mut(1 << 14)
            .zip(values.par_chunks(1 << 14))
            .for_each(|(o, v)| {
                for (o, &v) in o.iter_mut().zip(v) {
                    *o = half::bf16::from_bits(f32_to_bf16_bits(v));
                }
            });
        CpuStorage::BF16(out)
    } else {
        CpuStorage::F32(values)
    }
}

impl PackedLinear<'_> {
    fn run(
        &self,
        x: (&CpuStorage, &Layout),
        residual: Option<(&CpuStorage, &Layout)>,
    ) -> Result<(CpuStorage, Shape)> {
        let (m, k) = x.1.shape().dims2()?;
        let n = self.weight.n();
        if self.weight.k() != k {
            candle_core::bail!(
                "bf16 linear: input has {k} features, weight expects {}",
                self.weight.k()
            );
        }
        for (what, v) in [("bias", self.bias), ("gate", self.gate)] {
            if let Some(v) = v {
                if v.len() != n {
                    candle_core::bail!("bf16 linear: {what} has {} values, expected {n}", v.len());
                }
            }
        }
        let a = lhs(x.0, x.1, k)?;
        let residual = match residual {
            Some((s, l)) => {
                let r = f32_values(s, l)?;
                if r.len() != m * n {
                    candle_core::bail!(
                        "bf16 linear: residual has {} values, expected {m}×{n}",
                        r.len()
                    );
                }
                Some(r)
            }
            None => None,
        };
        let bias_rows = |mut out: Vec<f32>| {
            if let (Some(b), true) = (self.bias, n > 0) {
                out.par_chunks_mut(EPILOGUE_ROWS * n).for_each(|rows| {
                    for row in rows.chunks_exact_mut(n) {
                        row.iter_mut().zip(b).for_each(|(o, b)| *o += b);
                    }
                });
            }
            out
        };
        // The product accumulates onto bias (+ residual when no gate scales the product).
        let (init, gated) = match (residual, self.gate) {
            (Some(r), None) => (bias_rows(r), None),
            (Some(r), Some(g)) => (bias_rows(vec![0f32; m * n]), Some((r, g))),
            (None, _) => (bias_rows(vec![0f32; m * n]), None),
        };
        let mut out = init;
        gemm(a, m, self.weight.view(), &mut out, n, true)?;
        if n > 0 {
            if let Some((r, g)) = gated {
                out.par_chunks_mut(EPILOGUE_ROWS * n)
                    .zip(r.par_chunks(EPILOGUE_ROWS * n))
                    .for_each(|(o, r)| {
                        for (orow, rrow) in o.chunks_exact_mut(n).zip(r.chunks_exact(n)) {
                            for ((o, &r), &g) in orow.iter_mut().zip(rrow).zip(g) {
                                *o = r + g * *o;
                            }
                        }
                    });
            } else {
                match self.act {
                    Activation::Identity => {}
                    Activation::GeluErf => out
                        .par_chunks_mut(EPILOGUE_ROWS * n)
                        .for_each(gelu_in_place),
                    Activation::GeluTanh => out
                        .par_chunks_mut(EPILOGUE_ROWS * n)
                        .for_each(gelu_tanh_in_place),
                }
            }
        }
        Ok((to_storage(out, x.0.dtype()), Shape::from((m, n))))
    }
}

impl CustomOp1 for PackedLinear<'_> {
    fn name(&self) -> &'static str {
        "bf16-linear"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        self.run((s, l), None)
    }
}

impl CustomOp2 for PackedLinear<'_> {
    fn name(&self) -> &'static str {
        "bf16-linear-residual"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        self.run((s1, l1), Some((s2, l2)))
    }
}
