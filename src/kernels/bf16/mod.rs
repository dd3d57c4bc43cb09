//! bf16 matrix products with f32 accumulation for the CPU: `out += A · Bᵀ` where the right
//! operand `B [n, k]` (a linear layer's weight, the keys or the transposed values of an
//! attention head) is packed once into bf16 pairs ([`PackedRhs`]), the left operand (f32 or
//! bf16 rows, [`Lhs`]) is rounded to bf16 tile by tile as the product runs, and the output is
//! f32.
//!
//! On CPUs with AMX-BF16 (and an OS that grants the tile state) the tile kernel ([`amx`])
//! multiplies 32 × 32 output blocks with `tdpbf16ps`. On CPUs with AVX512-BF16 the
//! micro-kernel ([`avx512`]) multiplies with `vdpbf16ps`: one
//! instruction takes 16 output columns × one pair of `k` (the packed layout stores the two
//! `k` of a pair next to each other), 6 rows × 64 columns are held in 24 accumulators. On
//! x86-64 CPUs with AVX2 and FMA but no AVX512-BF16 the [`avx2`] kernel computes the same
//! sums — products of bf16-rounded values accumulated in f32 — with eight-lane fused
//! multiply-adds; elsewhere the portable kernel ([`portable`]) with plain loops. [`Kernel::detect`] picks one at
//! run time; [`gemm`] runs the blocked product ([`gemm::gemm_with`] with an explicit kernel).

#[cfg(all(target_arch = "x86_64", lhmpp_bf16_intrinsics))]
pub mod amx;
pub mod attention;
#[cfg(target_arch = "x86_64")]
pub mod avx2;
#[cfg(all(target_arch = "x86_64", lhmpp_bf16_intrinsics))]
pub mod avx512;
pub mod gathered;
pub mod gemm;
pub mod linear;
pub mod pack;
pub mod portable;

use candle_core::{CpuStorage, DType, Tensor};
pub use gemm::{gemm, gemm_with, Lhs};
pub use pack::PackedRhs;

/// Output columns per packed tile of the right operand (four 16-lane vectors).
pub const NR: usize = 64;
/// Rows per micro-kernel call.
pub const MR: usize = 6;
/// Pairs of `k` per block: one packed tile of that depth (`NR × 2·KC_PAIRS` bf16, 32 KiB)
/// stays in the L1 cache while the rows of a block stream past it.
pub const KC_PAIRS: usize = 128;
/// Rows per block of the left operand converted to bf16 at a time (`MC × 2·KC_PAIRS` bf16,
/// 192 KiB, stays in the L2 cache while the tiles of the right operand pass).
pub const MC: usize = 384;

/// Which micro-kernel runs the products.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kernel {
    /// Intel AMX `tdpbf16ps` on tile registers, with AVX512-BF16 for the edges ([`amx`]).
    Amx,
    /// AVX512-BF16 `vdpbf16ps` (x86-64 CPUs reporting `avx512f` and `avx512bf16`).
    Avx512Bf16,
    /// AVX2 + FMA: f32 fused multiply-adds of the bf16 values widened in registers ([`avx2`]).
    Avx2,
    /// Plain loops: f32 products of the bf16-rounded values, f32 sums.
    Portable,
}

/// The environment variable that picks a slower kernel than [`Kernel::detect`] would
/// (`avx512`, `avx2` or `portable`), to compare kernels on one machine.
pub const KERNEL_ENV: &str = "LHMPP_BF16_KERNEL";

impl Kernel {
    /// The fastest kernel this CPU runs, or the one [`KERNEL_ENV`] names when this CPU runs it
    /// (checked once, then cached).
    pub fn detect() -> Self {
        static DETECTED: std::sync::OnceLock<Kernel> = std::sync::OnceLock::new();
        *DETECTED.get_or_init(|| {
            let fastest = Self::available()
                .into_iter()
                .next()
                .unwrap_or(Kernel::Portable);
            let Ok(name) = std::env::var(KERNEL_ENV) else {
                return fastest;
            };
            match Self::available().into_iter().find(|k| k.name() == name) {
                Some(k) => k,
                None => {
                    tracing::warn!(
                        "{KERNEL_ENV}={name}: not a bf16 kernel this CPU runs ({}); using {}",
                        Self::available()
                            .iter()
                            .map(|k| k.name())
                            .collect::<Vec<_>>()
                            .join(", "),
                        fastest.name()
                    );
                    fastest
                }
            }
        })
    }

    /// The kernels this CPU runs, fastest first (the portable one always last).
    pub fn available() -> Vec<Kernel> {
        let mut kernels = Vec::new();
        if amx::available() {
            kernels.push(Kernel::Amx);
        }
        if avx512::available() {
            kernels.push(Kernel::Avx512Bf16);
        }
        #[cfg(target_arch = "x86_64")]
        if avx2::available() {
            kernels.push(Kernel::Avx2);
        }
        kernels.push(Kernel::Portable);
        kernels
    }

    /// The kernel's name as [`KERNEL_ENV`] takes it.
    pub fn name(self) -> &'static str {
        match self {
            Kernel::Amx => "amx",
            Kernel::Avx512Bf16 => "avx512",
            Kernel::Avx2 => "avx2",
            Kernel::Portable => "portable",
        }
    }

    /// Whether this CPU runs the kernel.
    pub fn runs_here(self) -> bool {
        match self {
            Kernel::Amx => amx::available(),
            Kernel::Avx512Bf16 => avx512::available(),
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => avx2::available(),
            #[cfg(not(target_arch = "x86_64"))]
            Kernel::Avx2 => false,
            Kernel::Portable => true,
        }
    }
}

#[cfg(not(all(target_arch = "x86_64", lhmpp_bf16_intrinsics)))]
mod avx512 {
    /// No AVX512-BF16 kernel in this build (not x86-64, or a compiler older than Rust 1.89).
    pub fn available() -> bool {
        false
    }
}

#[cfg(not(all(target_arch = "x86_64", lhmpp_bf16_intrinsics)))]
mod amx {
    /// No AMX kernel in this build (not x86-64, or a compiler older than Rust 1.89).
    pub fn available() -> bool {
        false
    }
}

/// `x` rounded to the nearest bf16 (ties to even) as its bit pattern; NaN stays a quiet NaN.
/// Branch-free so that loops over slices vectorise.
#[inline(always)]
pub fn f32_to_bf16_bits(x: f32) -> u16 {
    let b = x.to_bits();
    let rounded = b.wrapping_add(0x7fff + ((b >> 16) & 1)) >> 16;
    let nan = (b >> 16) | 0x0040;
    (if b & 0x7fff_ffff > 0x7f80_0000 {
        nan
    } else {
        rounded
    }) as u16
}

/// `t` in f32: a contiguous bf16 CPU tensor is widened by a vectorised loop over its values
/// in parallel chunks (exact: a bf16 value is the top half of its f32); any other tensor goes
/// through candle's `to_dtype`, which widens one value at a time.
pub fn widened_to_f32(t: &Tensor) -> candle_core::Result<Tensor> {
    if t.dtype() != DType::BF16 || !t.device().is_cpu() || !t.is_contiguous() {
        return t.to_dtype(DType::F32);
    }
    let mut out = vec![0f32; t.elem_count()];
    {
        let (guard, layout) = t.storage_and_layout();
        let (candle_core::Storage::Cpu(CpuStorage::BF16(data)), Some((start, end))) =
            (&*guard, layout.contiguous_offsets())
        else {
            return t.to_dtype(DType::F32);
        };
        let src: &[half::bf16] = &data[start..end];
        const CHUNK: usize = 1 << 16;
        crate::kernels::parallel::for_each_chunk(&mut out, CHUNK, |i, dst| {
            let src = &src[i * CHUNK..i * CHUNK + dst.len()];
            for (d, s) in dst.iter_mut().zip(src) {
                *d = bf16_bits_to_f32(s.to_bits());
            }
        });
    }
    Tensor::from_vec(out, t.shape(), t.device())
}

/// The f32 value of a bf16 bit pattern (exact).
#[inline(always)]
pub fn bf16_bits_to_f32(b: u16) -> f32 {
    f32::from_bits((b as u32) << 16)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounding_matches_the_half_crate() {
        let mut state = 0x1234_5678u32;
        for _ in 0..100_000 {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            let x = f32::from_bits(state);
            let want = half::bf16::from_f32(x);
            let got = f32_to_bf16_bits(x);
            if x.is_nan() {
                assert!(bf16_bits_to_f32(got).is_nan(), "{x}");
            } else {
                assert_eq!(got, want.to_bits(), "{x:e}");
            }
        }
        for x in [
            0.0f32,
            -0.0,
            1.0,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MAX,
        ] {
            assert_eq!(f32_to_bf16_bits(x), half::bf16::from_f32(x).to_bits());
        }
        assert_eq!(bf16_bits_to_f32(f32_to_bf16_bits(1.5)), 1.5);
    }

    #[test]
    fn widening_equals_candles_conversion_in_any_layout() {
        let dev = candle_core::Device::Cpu;
        let x = Tensor::randn(0f32, 3.0, (2, 5, 70_000), &dev)
            .unwrap()
            .to_dtype(DType::BF16)
            .unwrap();
        for t in [
            x.clone(),
            x.transpose(1, 2).unwrap(),
            x.narrow(2, 7, 1000).unwrap(),
        ] {
            let got = widened_to_f32(&t).unwrap();
            let want = t.to_dtype(DType::F32).unwrap();
            assert_eq!(got.dims(), want.dims());
            let d = crate::testing::max_abs_diff(&got, &want);
            assert_eq!(d, 0.0);
        }
    }
}
