//! bf16 matrix products with f32 accumulation for the CPU: `out += A · Bᵀ` where the right
//! operand `B [n, k]` (a linear layer's weight, the keys or the transposed values of an
//! attention head) is packed once into bf16 pairs ([`PackedRhs`]), the left operand (f32 or
//! bf16 rows, [`Lhs`]) is rounded to bf16 tile by tile as the product runs, and the output is
//! f32.
//!
//! On CPUs with AVX512-BF16 the micro-kernel ([`avx512`]) multiplies with `vdpbf16ps`: one
//! instruction takes 16 output columns × one pair of `k` (the packed layout stores the two
//! `k` of a pair next to each other), 6 rows × 64 columns are held in 24 accumulators. On
//! other CPUs the portable kernel ([`portable`]) computes the same sums — products of
//! bf16-rounded values accumulated in f32 — with plain loops. [`Kernel::detect`] picks one at
//! run time; [`gemm`] runs the blocked product ([`gemm::gemm_with`] with an explicit kernel).

pub mod attention;
#[cfg(all(target_arch = "x86_64", lhmpp_bf16_intrinsics))]
pub mod avx512;
pub mod gemm;
pub mod linear;
pub mod pack;
pub mod portable;

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
    /// AVX512-BF16 `vdpbf16ps` (x86-64 CPUs reporting `avx512f` and `avx512bf16`).
    Avx512Bf16,
    /// Plain loops: f32 products of the bf16-rounded values, f32 sums.
    Portable,
}

impl Kernel {
    /// The fastest kernel this CPU runs (checked once, then cached).
    pub fn detect() -> Self {
        static DETECTED: std::sync::OnceLock<Kernel> = std::sync::OnceLock::new();
        *DETECTED.get_or_init(|| {
            if avx512::available() {
                Kernel::Avx512Bf16
            } else {
                Kernel::Portable
            }
        })
    }
}

#[cfg(not(all(target_arch = "x86_64", lhmpp_bf16_intrinsics)))]
mod avx512 {
    /// No AVX512-BF16 kernel in this build (not x86-64, or a compiler older than Rust 1.89).
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
}
