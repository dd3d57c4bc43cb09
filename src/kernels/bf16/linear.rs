//! The bf16 path of [`crate::kernels::linear::Linear`]: `act(x Wᵀ + b)` or
//! `r + g ⊙ (x Wᵀ + b)` with the weight packed once ([`PackedRhs`]), the product in bf16 with
//! f32 accumulation ([`super::gemm`]) and the bias, GELU, gate and residual applied in f32.
//! The output has the dtype of the input (bf16 or f32).

use std::mem::MaybeUninit;

use candle_core::backend::BackendStorage;
use candle_core::{CpuStorage, CustomOp1, CustomOp2, DType, Layout, Result, Shape};

use super::gemm::{gemm_uninit, Lhs, RowEpilogue};
use super::pack::round_to_bf16;
use super::Kernel;
use super::{bf16_bits_to_f32, PackedRhs};
use crate::kernels::gelu::{gelu_in_place, gelu_tanh_in_place};
use crate::kernels::linear::Activation;

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

thread_local! {
    /// Each thread's f32 accumulator for products with a bf16 output, kept between calls (as
    /// large as the largest such product the thread ran).
    static SCRATCH: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Runs `f` on `len` uninitialised f32 values: the thread's [`SCRATCH`] buffer, or a fresh
/// one when that is in use further up this thread's stack.
fn with_scratch<R>(len: usize, f: impl FnOnce(&mut [MaybeUninit<f32>]) -> R) -> R {
    SCRATCH.with(|cell| match cell.try_borrow_mut() {
        Ok(mut buf) => {
            buf.clear();
            buf.reserve(len);
            f(&mut buf.spare_capacity_mut()[..len])
        }
        Err(_) => {
            let mut fresh: Vec<f32> = Vec::with_capacity(len);
            f(&mut fresh.spare_capacity_mut()[..len])
        }
    })
}

/// The bf16 output shared by the epilogue calls, which write disjoint values.
#[derive(Clone, Copy)]
struct Bf16Ptr(*mut half::bf16);
// SAFETY: each (row, column) of the output is written by one epilogue call only (see `run`).
unsafe impl Send for Bf16Ptr {}
unsafe impl Sync for Bf16Ptr {}

impl Bf16Ptr {
    /// The pointer (a method, so that closures capture the whole `Sync` wrapper).
    fn get(self) -> *mut half::bf16 {
        self.0
    }
}

/// The residual operand, read row segment by row segment in the epilogue.
#[derive(Clone, Copy)]
enum Residual<'a> {
    Bf16(&'a [half::bf16]),
    F32(&'a [f32]),
}

impl<'a> Residual<'a> {
    /// A contiguous CPU operand.
    fn of(s: &'a CpuStorage, l: &Layout) -> Result<Self> {
        let Some((a, b)) = l.contiguous_offsets() else {
            candle_core::bail!("bf16 linear: residual is not contiguous");
        };
        Ok(match s {
            CpuStorage::BF16(d) => Residual::Bf16(&d[a..b]),
            CpuStorage::F32(d) => Residual::F32(&d[a..b]),
            other => candle_core::bail!(
                "bf16 linear: residual is {:?}, expected bf16 or f32",
                other.dtype()
            ),
        })
    }

    fn len(&self) -> usize {
        match self {
            Residual::Bf16(d) => d.len(),
            Residual::F32(d) => d.len(),
        }
    }
}

impl PackedLinear<'_> {
    /// The f32 epilogue of `values`, columns `col..` of output row `row` (rows `n` wide): bias,
    /// then the activation, or `r + g ⊙ y` with the residual.
    fn epilogue(
        &self,
        values: &mut [f32],
        row: usize,
        col: usize,
        n: usize,
        residual: Option<Residual>,
    ) {
        let cols = col..col + values.len();
        if let Some(b) = self.bias {
            values
                .iter_mut()
                .zip(&b[cols.clone()])
                .for_each(|(o, b)| *o += b);
        }
        match residual {
            Some(r) => {
                let base = row * n + col;
                let len = values.len();
                match (r, self.gate) {
                    (Residual::F32(r), Some(g)) => values
                        .iter_mut()
                        .zip(&r[base..base + len])
                        .zip(&g[cols])
                        .for_each(|((o, r), g)| *o = r + g * *o),
                    (Residual::F32(r), None) => values
                        .iter_mut()
                        .zip(&r[base..base + len])
                        .for_each(|(o, r)| *o += r),
                    (Residual::Bf16(r), Some(g)) => values
                        .iter_mut()
                        .zip(&r[base..base + len])
                        .zip(&g[cols])
                        .for_each(|((o, r), g)| *o = bf16_bits_to_f32(r.to_bits()) + g * *o),
                    (Residual::Bf16(r), None) => values
                        .iter_mut()
                        .zip(&r[base..base + len])
                        .for_each(|(o, r)| *o += bf16_bits_to_f32(r.to_bits())),
                }
            }
            None => match self.act {
                Activation::Identity => {}
                Activation::GeluErf => gelu_in_place(values),
                Activation::GeluTanh => gelu_tanh_in_place(values),
            },
        }
    }

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
                let r = Residual::of(s, l)?;
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
        // The product overwrites the accumulator, so it starts uninitialised: no zeroing pass
        // over m × n values, and each fresh page's first touch is a write (a zeroed
        // `vec![0.0; len]` maps the shared zero page, and the first write after a read of each
        // page was a copy-on-write fault with a TLB flush on every core: 16 % of a 700M bf16
        // forward on 2 cores).
        //
        // The epilogue runs on each row segment of a task as soon as its products are done,
        // while the values are in the cache: f32 bias, activation or gated residual, then (bf16
        // input) the rounding into the output.
        let product = |acc: &mut [MaybeUninit<f32>], epilogue: RowEpilogue| {
            let weight = self.weight.view();
            gemm_uninit(Kernel::detect(), a, m, weight, acc, n, true, Some(epilogue))
        };
        // The output takes the residual's dtype (an f32 residual stream stays f32, rounded
        // nowhere), else the input's.
        let bf16_out = match &residual {
            Some(Residual::F32(_)) => false,
            Some(Residual::Bf16(_)) => true,
            None => x.0.dtype() == DType::BF16,
        };
        let storage = if bf16_out {
            let mut out: Vec<half::bf16> = Vec::with_capacity(m * n);
            let dst = Bf16Ptr(out.as_mut_ptr());
            let epilogue = |row: usize, col: usize, values: &mut [f32]| {
                self.epilogue(values, row, col, n, residual);
                // SAFETY: `out` has room for `m × n` values; the gemm passes each (row, column)
                // once, so no two calls write the same output values.
                let o = unsafe {
                    std::slice::from_raw_parts_mut(dst.get().add(row * n + col), values.len())
                };
                round_to_bf16(values, bytemuck::cast_slice_mut(o));
            };
            // The f32 accumulator is scratch here: the thread's buffer, reused from call to
            // call, so that its pages are not faulted in afresh for every layer (a nested call
            // on this thread, while rayon waits, takes a fresh one).
            with_scratch(m * n, |acc| product(acc, &epilogue))?;
            // SAFETY: the epilogue wrote all m × n values (each (row, column) once, no gaps).
            unsafe { out.set_len(m * n) };
            CpuStorage::BF16(out)
        } else {
            let mut acc: Vec<f32> = Vec::with_capacity(m * n);
            let epilogue = |row: usize, col: usize, values: &mut [f32]| {
                self.epilogue(values, row, col, n, residual)
            };
            product(&mut acc.spare_capacity_mut()[..m * n], &epilogue)?;
            // SAFETY: `gemm_uninit` initialised all m × n values (rows n apart, no gaps).
            unsafe { acc.set_len(m * n) };
            CpuStorage::F32(acc)
        };
        Ok((storage, Shape::from((m, n))))
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
