//! LayerNorm over the last dimension with a vectorisable CPU kernel (rows in parallel; mean and
//! variance accumulated in 16 lanes; two passes over the row so the variance is exact for
//! large means), with or without the affine `weight`/`bias`. Other devices and dtypes use
//! candle's ops. Parameter names and init are those of `candle_nn::layer_norm`.

use candle_core::{CpuStorage, CustomOp1, CustomOp3, DType, Layout, Module, Result, Shape, Tensor};
use candle_nn::VarBuilder;
use rayon::prelude::*;

/// Rows per rayon task.
const ROWS_PER_TASK: usize = 32;
/// Accumulator lanes.
const LANES: usize = 16;

/// LayerNorm with an optional affine part.
#[derive(Debug, Clone)]
pub struct LayerNorm {
    affine: Option<(Tensor, Tensor)>,
    eps: f64,
}

/// Loads `weight [size]` and `bias [size]` under `vb` (as `candle_nn::layer_norm`).
pub fn layer_norm(size: usize, eps: f64, vb: VarBuilder) -> Result<LayerNorm> {
    let ln = candle_nn::layer_norm(size, eps, vb)?;
    let bias = match ln.bias() {
        Some(b) => b.clone(),
        None => ln.weight().zeros_like()?,
    };
    Ok(LayerNorm::new(ln.weight().clone(), bias, eps))
}

impl LayerNorm {
    /// Affine LayerNorm with `weight [C]` and `bias [C]`.
    pub fn new(weight: Tensor, bias: Tensor, eps: f64) -> Self {
        Self {
            affine: Some((weight, bias)),
            eps,
        }
    }

    /// LayerNorm without parameters.
    pub fn plain(eps: f64) -> Self {
        Self { affine: None, eps }
    }
}

impl Module for LayerNorm {
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let op = LayerNormOp {
            eps: self.eps as f32,
        };
        if x.device().is_cpu() && x.dtype() == DType::F32 {
            let x = x.contiguous()?;
            // (A bf16 model's f32 residual stream meets bf16 weights here: widened, C values.)
            return match &self.affine {
                Some((w, b)) => {
                    let f = |t: &Tensor| t.to_dtype(DType::F32)?.contiguous();
                    x.apply_op3_no_bwd(&f(w)?, &f(b)?, &op)
                }
                None => x.apply_op1_no_bwd(&op),
            };
        }
        if x.device().is_cpu() && x.dtype() == DType::BF16 {
            // bf16 activations: each row widened to f32, normalised by the same kernel and
            // rounded back once.
            let x = x.contiguous()?;
            return match &self.affine {
                Some((w, b)) => {
                    let f = |t: &Tensor| t.to_dtype(DType::F32)?.contiguous();
                    x.apply_op3_no_bwd(&f(w)?, &f(b)?, &op)
                }
                None => x.apply_op1_no_bwd(&op),
            };
        }
        reference(x, self.affine.as_ref(), self.eps)
    }
}

/// LayerNorm with candle ops, in f32 (the fallback and the test reference).
pub fn reference(x: &Tensor, affine: Option<&(Tensor, Tensor)>, eps: f64) -> Result<Tensor> {
    let dtype = x.dtype();
    let xf = x.to_dtype(DType::F32)?;
    let mu = xf.mean_keepdim(candle_core::D::Minus1)?;
    let xc = xf.broadcast_sub(&mu)?;
    let var = xc.sqr()?.mean_keepdim(candle_core::D::Minus1)?;
    let y = xc.broadcast_div(&(var + eps)?.sqrt()?)?;
    let y = match affine {
        Some((w, b)) => y
            .broadcast_mul(&w.to_dtype(DType::F32)?)?
            .broadcast_add(&b.to_dtype(DType::F32)?)?,
        None => y,
    };
    y.to_dtype(dtype)
}

/// The candle op.
#[derive(Debug, Clone, Copy)]
struct LayerNormOp {
    eps: f32,
}

/// The f32 data of a contiguous operand.
fn f32_data<'a>(s: &'a CpuStorage, l: &Layout, what: &str) -> Result<&'a [f32]> {
    super::contiguous_f32(s, l, "layer norm", what)
}

/// The bf16 data of a contiguous bf16 input (`None` for other dtypes).
fn bf16_data<'a>(s: &'a CpuStorage, l: &Layout) -> Result<Option<&'a [half::bf16]>> {
    let CpuStorage::BF16(data) = s else {
        return Ok(None);
    };
    match l.contiguous_offsets() {
        Some((a, b)) => Ok(Some(&data[a..b])),
        None => candle_core::bail!("layer norm: input is not contiguous"),
    }
}

/// The channel count of `shape` (its last dimension), checked against the affine parameters.
fn channels(shape: &Shape, affine: Option<(&[f32], &[f32])>) -> Result<usize> {
    let c = shape.dims().last().copied().unwrap_or(0);
    if let Some((w, b)) = affine {
        if w.len() != c || b.len() != c {
            candle_core::bail!(
                "layer norm: {c} channels but weight has {} and bias {}",
                w.len(),
                b.len()
            );
        }
    }
    Ok(c)
}

impl LayerNormOp {
    /// The bf16 form of [`Self::run`]: rows widened to f32 in a small buffer.
    fn run_bf16(
        &self,
        x: &[half::bf16],
        shape: &Shape,
        affine: Option<(&[f32], &[f32])>,
    ) -> Result<(CpuStorage, Shape)> {
        let c = channels(shape, affine)?;
        let mut out = vec![half::bf16::ZERO; x.len()];
        if c > 0 {
            out.par_chunks_mut(ROWS_PER_TASK * c)
                .zip(x.par_chunks(ROWS_PER_TASK * c))
                .for_each(|(o, xi)| {
                    let (mut xf, mut yf) = (vec![0f32; c], vec![0f32; c]);
                    for (orow, xrow) in o.chunks_exact_mut(c).zip(xi.chunks_exact(c)) {
                        xf.iter_mut().zip(xrow).for_each(|(f, v)| *f = v.to_f32());
                        normalise_row(&xf, &mut yf, self.eps, affine);
                        orow.iter_mut().zip(&yf).for_each(|(o, &v)| {
                            *o = half::bf16::from_bits(super::bf16::f32_to_bf16_bits(v))
                        });
                    }
                });
        }
        Ok((CpuStorage::BF16(out), shape.clone()))
    }

    fn run(
        &self,
        x: &[f32],
        shape: &Shape,
        affine: Option<(&[f32], &[f32])>,
    ) -> Result<(CpuStorage, Shape)> {
        let c = channels(shape, affine)?;
        let mut out = vec![0f32; x.len()];
        if c > 0 {
            out.par_chunks_mut(ROWS_PER_TASK * c)
                .zip(x.par_chunks(ROWS_PER_TASK * c))
                .for_each(|(o, xi)| {
                    for (orow, xrow) in o.chunks_exact_mut(c).zip(xi.chunks_exact(c)) {
                        normalise_row(xrow, orow, self.eps, affine);
                    }
                });
        }
        Ok((CpuStorage::F32(out), shape.clone()))
    }
}

/// Sum of `xs` in [`LANES`] lanes (vectorises).
#[inline(always)]
fn lane_sum(xs: &[f32], f: impl Fn(f32) -> f32) -> f32 {
    let mut lanes = [0f32; LANES];
    let mut chunks = xs.chunks_exact(LANES);
    for ch in &mut chunks {
        for (l, &x) in lanes.iter_mut().zip(ch) {
            *l += f(x);
        }
    }
    let tail: f32 = chunks.remainder().iter().map(|&x| f(x)).sum();
    tail + lanes.iter().sum::<f32>()
}

/// Normalises one row.
#[inline(always)]
fn normalise_row(x: &[f32], out: &mut [f32], eps: f32, affine: Option<(&[f32], &[f32])>) {
    let c = x.len() as f32;
    let mean = lane_sum(x, |v| v) / c;
    let var = lane_sum(x, |v| (v - mean) * (v - mean)) / c;
    let inv = 1.0 / (var + eps).sqrt();
    match affine {
        Some((w, b)) => {
            for (((o, &v), &wi), &bi) in out.iter_mut().zip(x).zip(w).zip(b) {
                *o = (v - mean) * inv * wi + bi;
            }
        }
        None => {
            for (o, &v) in out.iter_mut().zip(x) {
                *o = (v - mean) * inv;
            }
        }
    }
}

impl CustomOp1 for LayerNormOp {
    fn name(&self) -> &'static str {
        "layer-norm-plain"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> Result<(CpuStorage, Shape)> {
        if let Some(x) = bf16_data(s, l)? {
            return self.run_bf16(x, l.shape(), None);
        }
        self.run(f32_data(s, l, "input")?, l.shape(), None)
    }
}

impl CustomOp3 for LayerNormOp {
    fn name(&self) -> &'static str {
        "layer-norm"
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
        let w = f32_data(s2, l2, "weight")?;
        let b = f32_data(s3, l3, "bias")?;
        if let Some(x) = bf16_data(s1, l1)? {
            return self.run_bf16(x, l1.shape(), Some((w, b)));
        }
        self.run(f32_data(s1, l1, "input")?, l1.shape(), Some((w, b)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::max_abs_diff;
    use candle_core::{Device, D};

    #[test]
    fn fast_layer_norm_equals_the_candle_reference_with_and_without_affine() {
        let dev = Device::Cpu;
        for &(rows, c) in &[(1usize, 1usize), (3, 7), (70, 384), (5, 1025)] {
            // A large common offset checks the two-pass variance.
            let x = (Tensor::randn(0f32, 1.0, (rows, c), &dev).unwrap() + 300.0).unwrap();
            let w = Tensor::randn(0f32, 1.0, c, &dev).unwrap();
            let b = Tensor::randn(0f32, 1.0, c, &dev).unwrap();
            let affine = (w.clone(), b.clone());
            let got = LayerNorm::new(w, b, 1e-6).forward(&x).unwrap();
            let want = reference(&x, Some(&affine), 1e-6).unwrap();
            assert!(max_abs_diff(&got, &want) < 1e-3, "rows={rows} c={c}");
            let got = LayerNorm::plain(1e-5).forward(&x).unwrap();
            let want = reference(&x, None, 1e-5).unwrap();
            assert!(max_abs_diff(&got, &want) < 1e-3, "plain rows={rows} c={c}");
        }
    }

    #[test]
    fn normalised_rows_have_zero_mean_and_unit_variance() {
        let x = Tensor::randn(5f32, 3.0, (4, 9, 64), &Device::Cpu).unwrap();
        let y = LayerNorm::plain(1e-6).forward(&x).unwrap();
        let mean = y
            .mean_keepdim(D::Minus1)
            .unwrap()
            .abs()
            .unwrap()
            .max_all()
            .unwrap();
        let var = y.sqr().unwrap().mean_keepdim(D::Minus1).unwrap();
        let var_err = (var - 1.0).unwrap().abs().unwrap().max_all().unwrap();
        assert!(mean.to_scalar::<f32>().unwrap() < 1e-5);
        assert!(var_err.to_scalar::<f32>().unwrap() < 1e-4);
    }

    #[test]
    fn bf16_input_is_normalised_in_f32_and_rounded_once() {
        let dev = Device::Cpu;
        let x = Tensor::randn(2f32, 3.0, (37, 384), &dev)
            .unwrap()
            .to_dtype(DType::BF16)
            .unwrap();
        let w = Tensor::randn(1f32, 0.5, 384, &dev)
            .unwrap()
            .to_dtype(DType::BF16)
            .unwrap();
        let b = Tensor::randn(0f32, 0.5, 384, &dev)
            .unwrap()
            .to_dtype(DType::BF16)
            .unwrap();
        let affine = (w.clone(), b.clone());
        let got = LayerNorm::new(w, b, 1e-6).forward(&x).unwrap();
        assert_eq!(got.dtype(), DType::BF16);
        let want = reference(&x.to_dtype(DType::F32).unwrap(), Some(&affine), 1e-6).unwrap();
        // One bf16 rounding of values up to ~5: 2^-8 relative.
        assert!(max_abs_diff(&got, &want) < 0.04);
        let got = LayerNorm::plain(1e-6).forward(&x).unwrap();
        let want = reference(&x.to_dtype(DType::F32).unwrap(), None, 1e-6).unwrap();
        assert!(max_abs_diff(&got, &want) < 0.04);
    }
}
