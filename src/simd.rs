//! Run-time SIMD dispatch on x86-64: one loop, written once (portable and `#[inline(always)]`),
//! compiled again for AVX-512F and for AVX2 (with or without FMA), and the widest variant the
//! CPU has picked when it is called. Every variant computes the same as the portable loop; only
//! the instructions differ.

/// The instruction sets a dispatched loop is compiled for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Isa {
    /// AVX-512F.
    Avx512f,
    /// AVX2 (and FMA where the loop asks for it).
    Avx2,
    /// The baseline build (SSE2 on x86-64, or another architecture).
    Baseline,
}

impl Isa {
    /// The widest of [`Isa`] this CPU supports; with `fma`, AVX2 counts only together with FMA.
    pub(crate) fn widest(fma: bool) -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                return Self::Avx512f;
            }
            if std::arch::is_x86_feature_detected!("avx2")
                && (!fma || std::arch::is_x86_feature_detected!("fma"))
            {
                return Self::Avx2;
            }
        }
        let _ = fma;
        Self::Baseline
    }

    /// The name benchmarks print.
    pub(crate) fn name(self) -> &'static str {
        match self {
            Self::Avx512f => "AVX-512F",
            Self::Avx2 => "AVX2",
            Self::Baseline => "baseline",
        }
    }
}

/// Defines `fn NAME[GENERICS](ARGS) -> RET = PORTABLE;`: calls `PORTABLE(ARGS)` compiled for
/// the widest instruction set of the CPU ([`Isa::widest`]). Start with `avx2_fma;` for loops
/// that may use FMA with AVX2, or `avx2;` for AVX2 alone.
macro_rules! simd_dispatch {
    (avx2_fma; $($rest:tt)*) => {
        $crate::simd::simd_dispatch!(@define "avx2,fma", true; $($rest)*);
    };
    (avx2; $($rest:tt)*) => {
        $crate::simd::simd_dispatch!(@define "avx2", false; $($rest)*);
    };
    (
        @define $avx2:literal, $fma:literal;
        $(#[$attr:meta])*
        $vis:vis fn $name:ident [$($gen:tt)*] ($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)?
            = $portable:ident;
    ) => {
        $(#[$attr])*
        $vis fn $name<$($gen)*>($($arg: $ty),*) $(-> $ret)? {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f")]
                unsafe fn avx512<$($gen)*>($($arg: $ty),*) $(-> $ret)? {
                    $portable($($arg),*)
                }
                #[target_feature(enable = $avx2)]
                unsafe fn avx2<$($gen)*>($($arg: $ty),*) $(-> $ret)? {
                    $portable($($arg),*)
                }
                match $crate::simd::Isa::widest($fma) {
                    // SAFETY: the CPU supports AVX-512F (detected by `widest`).
                    $crate::simd::Isa::Avx512f => return unsafe { avx512($($arg),*) },
                    // SAFETY: the CPU supports the AVX2 features (detected by `widest`).
                    $crate::simd::Isa::Avx2 => return unsafe { avx2($($arg),*) },
                    $crate::simd::Isa::Baseline => {}
                }
            }
            $portable($($arg),*)
        }
    };
}
pub(crate) use simd_dispatch;

#[cfg(test)]
mod tests {
    use super::*;

    #[inline(always)]
    fn sum_portable(xs: &[f32], scale: f32) -> f32 {
        xs.iter().map(|x| x * scale).sum()
    }

    simd_dispatch! {
        avx2_fma;
        /// Test function.
        fn sum[](xs: &[f32], scale: f32) -> f32 = sum_portable;
    }

    #[inline(always)]
    fn apply_portable<F: Fn(f32) -> f32>(xs: &mut [f32], f: F) {
        xs.iter_mut().for_each(|x| *x = f(*x));
    }

    simd_dispatch! {
        avx2;
        fn apply[F: Fn(f32) -> f32](xs: &mut [f32], f: F) = apply_portable;
    }

    #[test]
    fn every_variant_computes_the_portable_result() {
        let xs: Vec<f32> = (0..1000).map(|i| i as f32 * 0.37).collect();
        assert_eq!(sum(&xs, 0.5).to_bits(), sum_portable(&xs, 0.5).to_bits());
        let mut a = xs.clone();
        apply(&mut a, |x| x * x - 1.0);
        let mut b = xs;
        apply_portable(&mut b, |x| x * x - 1.0);
        assert_eq!(a, b);
        assert!(["AVX-512F", "AVX2", "baseline"].contains(&Isa::widest(true).name()));
    }
}
