//! A branch-free `exp` for f32 slices, written so that LLVM auto-vectorises the loop
//! (no calls to `f32::exp`, no float→int conversions; `2^n` is built from the bits of a
//! rounded float).
//!
//! `exp(x) = 2^n · exp(r)` with `n = round(x / ln 2)` and `r = x − n·ln 2 ∈ [−ln2/2, ln2/2]`;
//! `exp(r) = 1 + r·q(r)` with a fitted degree-4 `q` (relative error below 2e-7 on that interval).
//! Inputs are clamped to `[−87.3, 88.7]`: below, the result is the smallest normal f32
//! times a tiny factor (≈1e-38, not 0); `−∞` therefore maps to ≈1e-38.

/// `1 / ln 2`.
const LOG2_E: f32 = std::f32::consts::LOG2_E;
/// High part of `ln 2` (few mantissa bits, so `n · LN2_HI` is exact for |n| < 2^8).
const LN2_HI: f32 = 0.693_359_4;
/// Low part of `ln 2` (`ln 2 − LN2_HI`).
const LN2_LO: f32 = -2.121_944_4e-4;
/// `1.5 · 2^23`: adding it rounds a float of magnitude < 2^22 to an integer held in the low
/// mantissa bits.
const ROUND_MAGIC: f32 = 12_582_912.0;
/// Bits of [`ROUND_MAGIC`].
const ROUND_MAGIC_BITS: i32 = 0x4B40_0000;
/// Lowest input kept (`2^-126` is the smallest normal f32).
const MIN_INPUT: f32 = -87.3;
/// Highest input kept (just below f32 overflow).
const MAX_INPUT: f32 = 88.7;

/// `exp(x)` of one value; inlined into the loop of [`exp_shifted_sum`] so that it
/// vectorises.
#[inline(always)]
pub fn exp_approx(x: f32) -> f32 {
    let x = x.clamp(MIN_INPUT, MAX_INPUT);
    let t = x * LOG2_E + ROUND_MAGIC;
    let n = t - ROUND_MAGIC;
    let r = x - n * LN2_HI - n * LN2_LO;
    // `1 + r·q(r)` with `q` a degree-4 least-squares (near-minimax, relative) fit on
    // [−ln2/2, ln2/2]: relative error 1.0e-7 in exact arithmetic (1.7e-7 evaluated in f32),
    // exactly 1 at r = 0, one multiply-add fewer than the degree-6 Taylor polynomial it
    // replaced (3e-7).
    let q = 0.008_261_533_f32;
    let q = q * r + 0.041_898_75;
    let q = q * r + 0.166_681_14;
    let q = q * r + 0.499_991_4;
    let q = q * r + 0.999_999_5;
    let p = q * r + 1.0;
    let exponent = (t.to_bits() as i32).wrapping_sub(ROUND_MAGIC_BITS) + 127;
    let two_n = f32::from_bits((exponent << 23) as u32);
    p * two_n
}

crate::simd::simd_dispatch! {
    avx2_fma;
    /// Replaces every `x` of `xs` by `exp(x − shift)` and returns the sum of the results
    /// (accumulated in 8 lanes so that the sum vectorises too). Uses AVX-512 or AVX2 when the
    /// CPU has them (detected at run time), the baseline x86-64 / portable build otherwise.
    pub fn exp_shifted_sum[](xs: &mut [f32], shift: f32) -> f32 = exp_shifted_sum_portable;
}

/// The loop of [`exp_shifted_sum`], inlined into each instruction-set variant.
#[inline(always)]
fn exp_shifted_sum_portable(xs: &mut [f32], shift: f32) -> f32 {
    let mut lanes = [0f32; 8];
    let mut chunks = xs.chunks_exact_mut(8);
    for chunk in &mut chunks {
        for (x, lane) in chunk.iter_mut().zip(lanes.iter_mut()) {
            *x = exp_approx(*x - shift);
            *lane += *x;
        }
    }
    let mut total: f32 = 0.0;
    for x in chunks.into_remainder() {
        *x = exp_approx(*x - shift);
        total += *x;
    }
    total + lanes.iter().sum::<f32>()
}

/// Largest value of `xs` (`−∞` when empty), in 8 lanes so that it vectorises.
pub fn max_of(xs: &[f32]) -> f32 {
    let mut lanes = [f32::NEG_INFINITY; 8];
    let mut chunks = xs.chunks_exact(8);
    for chunk in &mut chunks {
        for (x, lane) in chunk.iter().zip(lanes.iter_mut()) {
            *lane = if *x > *lane { *x } else { *lane };
        }
    }
    let mut best = f32::NEG_INFINITY;
    for &x in chunks.remainder().iter().chain(lanes.iter()) {
        best = if x > best { x } else { best };
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn approximate_exp_is_within_half_a_micro_of_the_true_value_relatively() {
        let mut worst = 0f64;
        let mut x = -80.0f32;
        while x < 80.0 {
            let got = exp_approx(x) as f64;
            let want = (x as f64).exp();
            worst = worst.max(((got - want) / want).abs());
            x += 0.0137;
        }
        assert!(worst < 5e-7, "worst relative error {worst}");
    }

    #[test]
    fn exp_of_zero_is_one_and_minus_infinity_is_negligible() {
        assert!((exp_approx(0.0) - 1.0).abs() < 1e-7);
        assert!(exp_approx(f32::NEG_INFINITY) < 1e-37);
        assert!(exp_approx(-1000.0) < 1e-37);
    }

    #[test]
    fn shifted_sum_equals_the_sum_of_the_exponentials() {
        let mut xs: Vec<f32> = (0..37).map(|i| (i as f32) * 0.3 - 5.0).collect();
        let want: f64 = xs.iter().map(|&x| ((x - 2.0) as f64).exp()).sum();
        let got = exp_shifted_sum(&mut xs, 2.0) as f64;
        assert!(((got - want) / want).abs() < 1e-6);
        assert!((xs[0] as f64 - (-7.0f64).exp()).abs() < 1e-9);
    }

    #[test]
    fn every_instruction_set_variant_gives_the_portable_result() {
        let xs: Vec<f32> = (0..1037)
            .map(|i| ((i * 37) % 101) as f32 * 0.17 - 9.0)
            .collect();
        let mut portable = xs.clone();
        let want = exp_shifted_sum_portable(&mut portable, 1.5);
        let mut dispatched = xs.clone();
        let got = exp_shifted_sum(&mut dispatched, 1.5);
        assert!(((got - want) / want).abs() < 1e-6, "{got} vs {want}");
        let worst = portable
            .iter()
            .zip(&dispatched)
            .map(|(a, b)| ((a - b) / a).abs())
            .fold(0f32, f32::max);
        assert!(worst < 1e-6, "{worst}");
    }

    #[test]
    fn max_finds_the_largest_value_in_the_tail() {
        let mut xs = vec![-3.0f32; 19];
        xs[18] = 4.5;
        assert_eq!(max_of(&xs), 4.5);
        assert_eq!(max_of(&[]), f32::NEG_INFINITY);
    }
}
