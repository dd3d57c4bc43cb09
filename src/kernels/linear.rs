//! Linear layer `y = x Wᵀ + b` (optionally followed by exact GELU) with a fused CPU path.
//!
//! On the CPU in f32 the leading dimensions of `x` are folded into the rows of ONE `gemm`
//! call (candle runs one small product per batch item), the bias is written into the output
//! before the product accumulates onto it (no separate broadcast add and no second buffer),
//! and the GELU is applied in place by [`super::gelu`] while the rows are still in cache.
//! A bf16 weight on the CPU is packed once for the bf16 product of [`super::bf16`]
//! ([`super::bf16::linear`]: bf16 or f32 input, f32 accumulation and epilogue, output in the
//! input's dtype). Other devices and dtypes use the plain candle ops. Weight names and
//! initialisation hints are those of `candle_nn::linear` (`weight [out, in]`, `bias [out]`).

use std::sync::Arc;

use candle_core::backend::BackendStorage;
use candle_core::{CpuStorage, CustomOp2, CustomOp3, DType, Layout, Module, Result, Shape, Tensor};
use candle_nn::VarBuilder;
use gemm::Parallelism;
use rayon::prelude::*;

use super::bf16::linear::PackedLinear;
use super::bf16::PackedRhs;
use super::gelu::{gelu_in_place, gelu_tanh_in_place};
use super::matmul::{matmul_into, MatRef};

/// Products smaller than this many multiply-adds run on one thread.
const PARALLEL_MIN_MACS: usize = 1 << 18;
/// Rows per rayon task of the GELU epilogue.
const EPILOGUE_ROWS: usize = 16;

/// What follows the affine map.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Activation {
    /// Nothing.
    Identity,
    /// Exact GELU, `x/2 · (1 + erf(x/√2))`.
    GeluErf,
    /// GELU with the tanh approximation (candle's `gelu`).
    GeluTanh,
}

/// A linear layer whose forward uses the fused CPU kernel when it can.
#[derive(Debug, Clone)]
pub struct Linear {
    weight: Tensor,
    bias: Option<Tensor>,
    /// The bias as host f32 values, kept when the layer runs the fused CPU path.
    cpu_bias: Option<Arc<Vec<f32>>>,
    /// A bf16 CPU weight packed for the bf16 product ([`super::bf16::linear`]).
    packed: Option<Arc<PackedRhs>>,
}

/// Loads `weight [out, in]` and `bias [out]` under `vb` (as `candle_nn::linear`).
pub fn linear(in_dim: usize, out_dim: usize, vb: VarBuilder) -> Result<Linear> {
    let l = candle_nn::linear(in_dim, out_dim, vb)?;
    Ok(Linear::new(l.weight().clone(), l.bias().cloned()))
}

/// Loads `weight [out, in]` only (as `candle_nn::linear_no_bias`).
pub fn linear_no_bias(in_dim: usize, out_dim: usize, vb: VarBuilder) -> Result<Linear> {
    let l = candle_nn::linear_no_bias(in_dim, out_dim, vb)?;
    Ok(Linear::new(l.weight().clone(), None))
}

impl Linear {
    /// Wraps `weight [out, in]` and an optional `bias [out]`.
    ///
    /// On the CPU in f32 the weight is re-laid out once as `[in, out]` in memory (the tensor
    /// stays the logical `[out, in]`): `gemm` then streams it without repacking, which helps most
    /// the few-row, long-`in` products of a ViT (`fc2`).
    /// A broadcast weight (a stride of 0: no values behind it, as the checkpoint's shape
    /// recorder gives) is kept as it is: laying it out would allocate the whole matrix.
    pub fn new(weight: Tensor, bias: Option<Tensor>) -> Self {
        let broadcast = weight.stride().contains(&0);
        let weight = if weight.device().is_cpu() && weight.dtype() == DType::F32 && !broadcast {
            weight
                .t()
                .and_then(|t| t.contiguous())
                .and_then(|t| t.t())
                .unwrap_or(weight)
        } else {
            weight
        };
        let packed = pack_bf16(&weight).map(Arc::new);
        let cpu_bias = bias
            .as_ref()
            .filter(|b| {
                b.device().is_cpu()
                    && (b.dtype() == DType::F32 || (b.dtype() == DType::BF16 && packed.is_some()))
            })
            .and_then(|b| {
                b.flatten_all()
                    .and_then(|b| b.to_dtype(DType::F32))
                    .and_then(|b| b.to_vec1::<f32>())
                    .ok()
            })
            .map(Arc::new);
        Self {
            weight,
            bias,
            cpu_bias,
            packed,
        }
    }

    /// The packed bf16 weight when `x` (bf16 or f32 on the CPU) can take the bf16 product.
    fn bf16_path(&self, x: &Tensor) -> Option<&PackedRhs> {
        let packed = self.packed.as_deref()?;
        (x.device().is_cpu()
            && matches!(x.dtype(), DType::BF16 | DType::F32)
            && self.bias.is_some() == self.cpu_bias.is_some())
        .then_some(packed)
    }

    /// Whether `x` can take the fused CPU path.
    fn fused_path(&self, x: &Tensor) -> bool {
        x.device().is_cpu()
            && x.dtype() == DType::F32
            && self.weight.dtype() == DType::F32
            && weight_strides(self.weight.layout()).is_some()
            && self.bias.is_some() == self.cpu_bias.is_some()
    }

    /// The weight `[out, in]`.
    pub fn weight(&self) -> &Tensor {
        &self.weight
    }

    /// The bias `[out]`, if any.
    pub fn bias(&self) -> Option<&Tensor> {
        self.bias.as_ref()
    }

    /// `act(x Wᵀ + b)` for `x [..., in]` → `[..., out]`.
    pub fn forward_act(&self, x: &Tensor, act: Activation) -> Result<Tensor> {
        if let Some(weight) = self.bf16_path(x) {
            let op = PackedLinear {
                weight,
                bias: self.cpu_bias.as_deref().map(Vec::as_slice),
                gate: None,
                act,
            };
            return self.fused_bf16(x, &op, None);
        }
        if self.fused_path(x) {
            let op = FusedLinear {
                act,
                bias: self.cpu_bias.as_deref().map(Vec::as_slice),
                gate: None,
            };
            return self.fused(x, &op, None);
        }
        let y = self.plain(x)?;
        match act {
            Activation::Identity => Ok(y),
            Activation::GeluErf => y.gelu_erf(),
            Activation::GeluTanh => y.gelu(),
        }
    }

    /// `residual + gate ⊙ (x Wᵀ + b)` (gate `[out]` or `[1, out]`, broadcast over rows; none =
    /// ones): the residual branch of a transformer block in one output buffer, in the
    /// residual's dtype (an f32 residual stream around bf16 layers stays f32).
    pub fn forward_residual(
        &self,
        x: &Tensor,
        residual: &Tensor,
        gate: Option<&Tensor>,
    ) -> Result<Tensor> {
        if let Some(weight) = self.bf16_path(x).filter(|_| residual.device().is_cpu()) {
            let gate_values = match gate {
                Some(g) => Some(g.to_dtype(DType::F32)?.flatten_all()?.to_vec1::<f32>()?),
                None => None,
            };
            let op = PackedLinear {
                weight,
                bias: self.cpu_bias.as_deref().map(Vec::as_slice),
                gate: gate_values.as_deref(),
                act: Activation::Identity,
            };
            return self.fused_bf16(x, &op, Some(residual));
        }
        if self.fused_path(x) && residual.dtype() == DType::F32 && residual.device().is_cpu() {
            let gate_values = match gate {
                Some(g) => Some(g.to_dtype(DType::F32)?.flatten_all()?.to_vec1::<f32>()?),
                None => None,
            };
            let op = FusedLinear {
                act: Activation::Identity,
                bias: self.cpu_bias.as_deref().map(Vec::as_slice),
                gate: gate_values.as_deref(),
            };
            return self.fused(x, &op, Some(residual));
        }
        let y = self.plain(x)?;
        let y = match gate {
            Some(g) => y.broadcast_mul(&g.to_dtype(y.dtype())?)?,
            None => y,
        };
        residual + y.to_dtype(residual.dtype())?
    }

    /// The candle-ops path: `x Wᵀ + b`.
    fn plain(&self, x: &Tensor) -> Result<Tensor> {
        let y = x.broadcast_matmul(&self.weight.t()?)?;
        match &self.bias {
            Some(b) => y.broadcast_add(b),
            None => Ok(y),
        }
    }

    /// Runs the fused op on `x` folded to rows (and the residual, reshaped alike).
    fn fused(&self, x: &Tensor, op: &FusedLinear, residual: Option<&Tensor>) -> Result<Tensor> {
        let dims = x.dims().to_vec();
        let k = *dims.last().unwrap_or(&0);
        let n = self.weight.dim(0)?;
        let rows = x.elem_count() / k.max(1);
        let x2 = x.reshape((rows, k))?;
        let y = match residual {
            Some(r) => {
                let r2 = r.reshape((rows, n))?.contiguous()?;
                x2.apply_op3_no_bwd(&self.weight, &r2, op)?
            }
            None => x2.apply_op2_no_bwd(&self.weight, op)?,
        };
        let mut out_dims = dims;
        if let Some(last) = out_dims.last_mut() {
            *last = n;
        }
        y.reshape(out_dims)
    }

    /// Runs the bf16 op on `x` folded to contiguous rows (and the residual, reshaped alike).
    fn fused_bf16(
        &self,
        x: &Tensor,
        op: &PackedLinear,
        residual: Option<&Tensor>,
    ) -> Result<Tensor> {
        let dims = x.dims().to_vec();
        let k = *dims.last().unwrap_or(&0);
        let n = op.weight.n();
        let rows = x.elem_count() / k.max(1);
        let x2 = x.reshape((rows, k))?.contiguous()?;
        let y = match residual {
            Some(r) => {
                let r2 = r.reshape((rows, n))?.contiguous()?;
                x2.apply_op2_no_bwd(&r2, op)?
            }
            None => x2.apply_op1_no_bwd(op)?,
        };
        let mut out_dims = dims;
        if let Some(last) = out_dims.last_mut() {
            *last = n;
        }
        y.reshape(out_dims)
    }

    /// `gelu_erf(x Wᵀ + b)`.
    pub fn forward_gelu(&self, x: &Tensor) -> Result<Tensor> {
        self.forward_act(x, Activation::GeluErf)
    }
}

impl Module for Linear {
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        self.forward_act(x, Activation::Identity)
    }
}

/// A bf16 `[out, in]` CPU weight packed for the bf16 product, or `None` for other weights.
fn pack_bf16(weight: &Tensor) -> Option<PackedRhs> {
    if !(weight.device().is_cpu() && weight.dtype() == DType::BF16) {
        return None;
    }
    let (n, k) = weight.dims2().ok()?;
    let values = weight
        .flatten_all()
        .and_then(|w| w.to_vec1::<half::bf16>())
        .ok()?;
    PackedRhs::from_rows(&values, n, k).ok()
}

/// The candle op: `act(x Wᵀ + b)` with `x [M, K]`, `W [N, K]` (two operands), or
/// `R + g ⊙ (x Wᵀ + b)` with the residual `R [M, N]` as third operand.
#[derive(Debug, Clone, Copy)]
struct FusedLinear<'a> {
    act: Activation,
    bias: Option<&'a [f32]>,
    gate: Option<&'a [f32]>,
}

/// `(out, in)` element strides of a `[out, in]` weight stored row-major or transposed
/// (`[in, out]` in memory), or `None` for other layouts.
fn weight_strides(l: &Layout) -> Option<(usize, usize)> {
    let (&[n, k], &[s0, s1]) = (l.shape().dims(), l.stride()) else {
        return None;
    };
    if (s0 == k || n == 1) && s1 == 1 {
        Some((k, 1))
    } else if s0 == 1 && (s1 == n || k == 1) {
        Some((1, n))
    } else {
        None
    }
}

/// The f32 data of a contiguous operand.
fn f32_data<'a>(s: &'a CpuStorage, l: &Layout, what: &str) -> Result<&'a [f32]> {
    super::contiguous_f32(s, l, "fused linear", what)
}

impl FusedLinear<'_> {
    fn run(
        &self,
        x: (&CpuStorage, &Layout),
        w: (&CpuStorage, &Layout),
        residual: Option<(&CpuStorage, &Layout)>,
    ) -> Result<(CpuStorage, Shape)> {
        let (m, k) = x.1.shape().dims2()?;
        let (n, wk) = w.1.shape().dims2()?;
        if wk != k {
            candle_core::bail!("fused linear: input has {k} features, weight expects {wk}");
        }
        for (what, v) in [("bias", self.bias), ("gate", self.gate)] {
            if let Some(v) = v {
                if v.len() != n {
                    candle_core::bail!("fused linear: {what} has {} values, expected {n}", v.len());
                }
            }
        }
        let xd = f32_data(x.0, x.1, "input")?;
        let CpuStorage::F32(wdata) = w.0 else {
            candle_core::bail!("fused linear: weight is {:?}, expected f32", w.0.dtype());
        };
        let Some(w_strides) = weight_strides(w.1) else {
            candle_core::bail!(
                "fused linear: weight layout {:?} is not dense",
                w.1.stride()
            );
        };
        let wd = Weight {
            data: &wdata[w.1.start_offset()..w.1.start_offset() + n * k],
            strides: w_strides,
        };
        let rd = match residual {
            Some((s, l)) => {
                let r = f32_data(s, l, "residual")?;
                if r.len() != m * n {
                    candle_core::bail!(
                        "fused linear: residual has {} values, expected {m}×{n}",
                        r.len()
                    );
                }
                Some(r)
            }
            None => None,
        };
        let out = match rd {
            None => linear_f32(xd, wd, self.bias, m, n, k, self.act),
            Some(r) => residual_linear_f32(xd, wd, self.bias, self.gate, r, m, n, k),
        };
        Ok((CpuStorage::F32(out), Shape::from((m, n))))
    }
}

/// Threading for one `m × n × k` product.
fn parallelism(m: usize, n: usize, k: usize) -> Parallelism {
    let threads = rayon::current_num_threads();
    if m * n * k >= PARALLEL_MIN_MACS && threads > 1 {
        Parallelism::Rayon(threads)
    } else {
        Parallelism::None
    }
}

/// A dense `[n, k]` weight: its `n·k` values and the element strides of its two axes
/// (`(k, 1)` row-major, `(1, n)` stored transposed).
#[derive(Debug, Clone, Copy)]
pub struct Weight<'a> {
    /// The values.
    pub data: &'a [f32],
    /// Strides of the output axis and of the input axis.
    pub strides: (usize, usize),
}

/// `out += x Wᵀ` on raw slices (`out [m, n]`, `x [m, k]` row-major).
fn accumulate_product(out: &mut [f32], x: &[f32], w: Weight, m: usize, n: usize, k: usize) {
    assert!(out.len() == m * n && x.len() == m * k && w.data.len() == n * k);
    assert!(w.strides == (k, 1) || w.strides == (1, n) || n == 1 || k == 1);
    // `Wᵀ [k, n]`: element (t, j) is W[j, t].
    let wt = MatRef {
        data: w.data,
        rows: k,
        cols: n,
        row_stride: w.strides.1,
        col_stride: w.strides.0,
    };
    let x = MatRef::row_major(x, m, k);
    matmul_into(out, n, x, wt, true, 1.0, parallelism(m, n, k));
}

/// `act(x Wᵀ + b)` on raw slices: `x [m, k]` row-major, `w [n, k]`, `b [n]` → `[m, n]`.
pub fn linear_f32(
    x: &[f32],
    w: Weight,
    bias: Option<&[f32]>,
    m: usize,
    n: usize,
    k: usize,
    act: Activation,
) -> Vec<f32> {
    let mut out: Vec<f32> = match bias {
        Some(b) => {
            let mut v = Vec::with_capacity(m * n);
            for _ in 0..m {
                v.extend_from_slice(b);
            }
            v
        }
        None => vec![0f32; m * n],
    };
    accumulate_product(&mut out, x, w, m, n, k);
    if n > 0 {
        match act {
            Activation::Identity => {}
            Activation::GeluErf => out
                .par_chunks_mut(EPILOGUE_ROWS * n)
                .for_each(gelu_in_place),
            Activation::GeluTanh => out
                .par_chunks_mut(EPILOGUE_ROWS * n)
                .for_each(gelu_tanh_in_place),
        }
    }
    out
}

/// `r + g ⊙ (x Wᵀ + b)` on raw row-major slices (`r [m, n]`, `g [n]`).
#[allow(clippy::too_many_arguments)]
pub fn residual_linear_f32(
    x: &[f32],
    w: Weight,
    bias: Option<&[f32]>,
    gate: Option<&[f32]>,
    residual: &[f32],
    m: usize,
    n: usize,
    k: usize,
) -> Vec<f32> {
    match gate {
        None => {
            // The residual (plus bias) is the initial value the product accumulates onto.
            let mut out = residual.to_vec();
            if let Some(b) = bias {
                for row in out.chunks_exact_mut(n) {
                    row.iter_mut().zip(b).for_each(|(o, b)| *o += b);
                }
            }
            accumulate_product(&mut out, x, w, m, n, k);
            out
        }
        Some(g) => {
            let mut out = linear_f32(x, w, bias, m, n, k, Activation::Identity);
            if n > 0 {
                out.par_chunks_mut(EPILOGUE_ROWS * n)
                    .zip(residual.par_chunks(EPILOGUE_ROWS * n))
                    .for_each(|(o, r)| {
                        for (orow, rrow) in o.chunks_exact_mut(n).zip(r.chunks_exact(n)) {
                            for ((o, &r), &g) in orow.iter_mut().zip(rrow).zip(g) {
                                *o = r + g * *o;
                            }
                        }
                    });
            }
            out
        }
    }
}

impl CustomOp2 for FusedLinear<'_> {
    fn name(&self) -> &'static str {
        "fused-linear"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> Result<(CpuStorage, Shape)> {
        self.run((s1, l1), (s2, l2), None)
    }
}

impl CustomOp3 for FusedLinear<'_> {
    fn name(&self) -> &'static str {
        "fused-linear-residual"
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
        self.run((s1, l1), (s2, l2), Some((s3, l3)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::max_abs_diff;
    use candle_core::Device;

    fn reference(x: &Tensor, w: &Tensor, b: Option<&Tensor>, act: Activation) -> Tensor {
        let y = x.broadcast_matmul(&w.t().unwrap()).unwrap();
        let y = match b {
            Some(b) => y.broadcast_add(b).unwrap(),
            None => y,
        };
        match act {
            Activation::Identity => y,
            Activation::GeluErf => y.gelu_erf().unwrap(),
            Activation::GeluTanh => y.gelu().unwrap(),
        }
    }

    #[test]
    fn fused_linear_equals_matmul_plus_bias_plus_gelu_over_odd_shapes() {
        let dev = Device::Cpu;
        for &(lead, k, n) in &[
            (&[1usize][..], 1usize, 1usize),
            (&[7], 13, 5),
            (&[2, 3, 37], 64, 96),
            (&[261], 384, 1536),
            (&[4, 1], 17, 3),
        ] {
            let mut xs = lead.to_vec();
            xs.push(k);
            let x = Tensor::randn(0f32, 1.0, xs, &dev).unwrap();
            let w = Tensor::randn(0f32, 0.2, (n, k), &dev).unwrap();
            let b = Tensor::randn(0f32, 1.0, n, &dev).unwrap();
            for act in [
                Activation::Identity,
                Activation::GeluErf,
                Activation::GeluTanh,
            ] {
                for bias in [true, false] {
                    let l = Linear::new(w.clone(), bias.then(|| b.clone()));
                    let got = l.forward_act(&x, act).unwrap();
                    let want = reference(&x, &w, bias.then_some(&b), act);
                    assert_eq!(got.dims(), want.dims());
                    let d = max_abs_diff(&got, &want);
                    assert!(d < 1e-4, "{lead:?} k={k} n={n} {act:?} bias={bias}: {d}");
                }
            }
        }
    }

    #[test]
    fn residual_form_equals_residual_plus_gated_linear() {
        let dev = Device::Cpu;
        let x = Tensor::randn(0f32, 1.0, (2, 37, 48), &dev).unwrap();
        let r = Tensor::randn(0f32, 1.0, (2, 37, 24), &dev).unwrap();
        let w = Tensor::randn(0f32, 0.2, (24, 48), &dev).unwrap();
        let b = Tensor::randn(0f32, 1.0, 24, &dev).unwrap();
        let g = Tensor::randn(0f32, 1.0, (1, 24), &dev).unwrap();
        for bias in [true, false] {
            let l = Linear::new(w.clone(), bias.then(|| b.clone()));
            let lin = reference(&x, &w, bias.then_some(&b), Activation::Identity);
            let got = l.forward_residual(&x, &r, Some(&g)).unwrap();
            let want = (&r + lin.broadcast_mul(&g).unwrap()).unwrap();
            assert!(max_abs_diff(&got, &want) < 1e-4, "gated, bias={bias}");
            let got = l.forward_residual(&x, &r, None).unwrap();
            let want = (&r + &lin).unwrap();
            assert!(max_abs_diff(&got, &want) < 1e-4, "ungated, bias={bias}");
        }
    }

    #[test]
    fn row_major_and_transposed_weight_storage_give_the_same_result() {
        let dev = Device::Cpu;
        let x = Tensor::randn(0f32, 1.0, (19, 33), &dev).unwrap();
        let w = Tensor::randn(0f32, 0.2, (21, 33), &dev).unwrap();
        let b = Tensor::randn(0f32, 1.0, 21, &dev).unwrap();
        let transposed = Linear::new(w.clone(), Some(b.clone()));
        assert_eq!(transposed.weight().stride(), &[1, 21]);
        let row_major = Linear {
            weight: w.clone(),
            ..transposed.clone()
        };
        assert_eq!(row_major.weight().stride(), &[33, 1]);
        let want = reference(&x, &w, Some(&b), Activation::GeluErf);
        for l in [transposed, row_major] {
            let got = l.forward_gelu(&x).unwrap();
            assert!(max_abs_diff(&got, &want) < 1e-4);
        }
    }

    #[test]
    fn non_contiguous_input_is_handled() {
        let dev = Device::Cpu;
        let x = Tensor::randn(0f32, 1.0, (8, 6), &dev).unwrap().t().unwrap();
        let w = Tensor::randn(0f32, 1.0, (5, 8), &dev).unwrap();
        let l = Linear::new(w.clone(), None);
        let got = l.forward(&x).unwrap();
        let want = reference(&x, &w, None, Activation::Identity);
        assert!(max_abs_diff(&got, &want) < 1e-4);
    }

    #[test]
    fn other_dtypes_fall_back_to_candle_ops() {
        let dev = Device::Cpu;
        let x = Tensor::randn(0f32, 1.0, (3, 4), &dev).unwrap();
        let w = Tensor::randn(0f32, 1.0, (2, 4), &dev).unwrap();
        let b = Tensor::randn(0f32, 1.0, 2, &dev).unwrap();
        let l = Linear::new(
            w.to_dtype(DType::F64).unwrap(),
            Some(b.to_dtype(DType::F64).unwrap()),
        );
        let got = l
            .forward_gelu(&x.to_dtype(DType::F64).unwrap())
            .unwrap()
            .to_dtype(DType::F32)
            .unwrap();
        let want = reference(&x, &w, Some(&b), Activation::GeluErf);
        assert!(max_abs_diff(&got, &want) < 1e-5);
    }

    /// `t` rounded to bf16 and back to f32.
    fn bf16_rounded(t: &Tensor) -> Tensor {
        t.to_dtype(DType::BF16)
            .unwrap()
            .to_dtype(DType::F32)
            .unwrap()
    }

    #[test]
    fn bf16_weights_take_the_packed_product_and_match_f32_on_rounded_values() {
        let dev = Device::Cpu;
        for &(lead, k, n) in &[
            (&[1usize][..], 1usize, 1usize),
            (&[7], 13, 5),
            (&[2, 37], 64, 96),
            (&[261], 385, 130),
        ] {
            let mut xs = lead.to_vec();
            xs.push(k);
            let x = bf16_rounded(&Tensor::randn(0f32, 1.0, xs, &dev).unwrap());
            let w = bf16_rounded(&Tensor::randn(0f32, 0.2, (n, k), &dev).unwrap());
            let b = bf16_rounded(&Tensor::randn(0f32, 1.0, n, &dev).unwrap());
            let l = Linear::new(
                w.to_dtype(DType::BF16).unwrap(),
                Some(b.to_dtype(DType::BF16).unwrap()),
            );
            assert!(l.packed.is_some());
            for act in [
                Activation::Identity,
                Activation::GeluErf,
                Activation::GeluTanh,
            ] {
                let want = reference(&x, &w, Some(&b), act);
                // f32 input: f32 output, only the accumulation order differs.
                let got = l.forward_act(&x, act).unwrap();
                assert_eq!(got.dtype(), DType::F32);
                let d = max_abs_diff(&got, &want);
                assert!(d < 1e-4, "{lead:?} k={k} n={n} {act:?}: {d}");
                // bf16 input: bf16 output, one more rounding (2^-8 relative).
                let got = l
                    .forward_act(&x.to_dtype(DType::BF16).unwrap(), act)
                    .unwrap();
                assert_eq!(got.dtype(), DType::BF16);
                assert_eq!(got.dims(), want.dims());
                let scale = want
                    .abs()
                    .unwrap()
                    .max_keepdim(0)
                    .unwrap()
                    .max_keepdim(1)
                    .unwrap();
                let scale = scale
                    .flatten_all()
                    .unwrap()
                    .max(0)
                    .unwrap()
                    .to_scalar::<f32>()
                    .unwrap();
                let d = max_abs_diff(&got, &want);
                assert!(
                    d <= scale / 128.0 + 1e-6,
                    "{lead:?} k={k} n={n} {act:?}: {d} of {scale}"
                );
            }
        }
    }

    #[test]
    fn bf16_residual_form_equals_residual_plus_gated_linear() {
        let dev = Device::Cpu;
        let x = bf16_rounded(&Tensor::randn(0f32, 1.0, (2, 37, 48), &dev).unwrap());
        let r = bf16_rounded(&Tensor::randn(0f32, 1.0, (2, 37, 24), &dev).unwrap());
        let w = bf16_rounded(&Tensor::randn(0f32, 0.2, (24, 48), &dev).unwrap());
        let b = bf16_rounded(&Tensor::randn(0f32, 1.0, 24, &dev).unwrap());
        let g = Tensor::randn(0f32, 1.0, (1, 24), &dev).unwrap();
        let bf = |t: &Tensor| t.to_dtype(DType::BF16).unwrap();
        let l = Linear::new(bf(&w), Some(bf(&b)));
        let lin = reference(&x, &w, Some(&b), Activation::Identity);
        for gate in [Some(&g), None] {
            let want = match gate {
                Some(g) => (&r + lin.broadcast_mul(g).unwrap()).unwrap(),
                None => (&r + &lin).unwrap(),
            };
            let got = l.forward_residual(&x, &r, gate).unwrap();
            assert!(
                max_abs_diff(&got, &want) < 1e-4,
                "f32 in, gate {}",
                gate.is_some()
            );
            let got = l.forward_residual(&bf(&x), &bf(&r), gate).unwrap();
            assert_eq!(got.dtype(), DType::BF16);
            let rounded = max_abs_diff(&got, &want);
            assert!(rounded < 0.1, "bf16 in, gate {}", gate.is_some());
            // bf16 input, f32 residual stream: the output stays f32, unrounded.
            let got = l.forward_residual(&bf(&x), &r, gate).unwrap();
            assert_eq!(got.dtype(), DType::F32);
            let d = max_abs_diff(&got, &want);
            assert!(
                d < 1e-4 && d < rounded,
                "f32 residual, gate {}: {d}",
                gate.is_some()
            );
        }
    }
}
