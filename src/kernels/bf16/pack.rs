//! The packed right operand of the bf16 products and the conversion of left-operand rows.
//!
//! [`PackedRhs`] stores `B [n, k]` as tiles of [`NR`] output columns; inside a tile, pair `p`
//! of `k` is `NR × 2` bf16 values, column `j`'s `B[j, 2p]` then `B[j, 2p+1]` — the operand
//! layout of `vdpbf16ps`, whose 32-bit lanes each hold one pair. Columns past `n` and the
//! second half of the last pair of an odd `k` are zero.

use super::{f32_to_bf16_bits, NR};

/// A right operand `B [n, k]` packed once for [`super::gemm`] (see the module doc).
#[derive(Debug, Clone)]
pub struct PackedRhs {
    /// The bf16 bit patterns, `tiles × pairs × NR × 2`.
    data: Vec<u16>,
    n: usize,
    k: usize,
}

/// A source of values for [`PackedRhs::pack`]: element `(j, t)` of `B` (`j < n` output
/// column, `t < k`) at `j·col_stride + t·k_stride`.
#[derive(Debug, Clone, Copy)]
pub struct Strided<'a, T> {
    /// The values.
    pub data: &'a [T],
    /// Distance between consecutive output columns `j`.
    pub col_stride: usize,
    /// Distance between consecutive `t` along `k`.
    pub k_stride: usize,
}

/// Element types that can be packed: their bf16 bit pattern (f32 values are rounded to the
/// nearest bf16).
pub trait ToBf16Bits: Copy + Send + Sync {
    /// The bf16 bits of the value.
    fn bf16_bits(self) -> u16;
}

impl ToBf16Bits for f32 {
    #[inline(always)]
    fn bf16_bits(self) -> u16 {
        f32_to_bf16_bits(self)
    }
}

impl ToBf16Bits for half::bf16 {
    #[inline(always)]
    fn bf16_bits(self) -> u16 {
        self.to_bits()
    }
}

impl PackedRhs {
    /// Packs `B [n, k]` read through `src`; errors (naming the op) when an element would lie
    /// outside `src.data`.
    pub fn pack<T: ToBf16Bits>(
        src: Strided<'_, T>,
        n: usize,
        k: usize,
    ) -> candle_core::Result<Self> {
        if n > 0 && k > 0 {
            let last = (n - 1) * src.col_stride + (k - 1) * src.k_stride;
            if last >= src.data.len() {
                candle_core::bail!(
                    "bf16 pack: a {n}×{k} operand with strides ({}, {}) reaches element {last} of {}",
                    src.col_stride,
                    src.k_stride,
                    src.data.len()
                );
            }
        }
        let pairs = k.div_ceil(2);
        let tiles = n.div_ceil(NR);
        let mut data = vec![0u16; tiles * pairs * NR * 2];
        if pairs > 0 {
            let tile_len = pairs * NR * 2;
            // Pair by pair, so that the writes are sequential and the lines read (one per
            // column, or per pair of `k`) stay in the L1 cache while they are used.
            let fill = |(tile, dst): (usize, &mut [u16])| {
                let cols = NR.min(n - tile * NR);
                for (p, pair) in dst.chunks_exact_mut(NR * 2).enumerate() {
                    for (c, out) in pair[..cols * 2].chunks_exact_mut(2).enumerate() {
                        let base = (tile * NR + c) * src.col_stride + 2 * p * src.k_stride;
                        out[0] = src.data[base].bf16_bits();
                        if 2 * p + 1 < k {
                            out[1] = src.data[base + src.k_stride].bf16_bits();
                        }
                    }
                }
            };
            if n * k >= 1 << 16 {
                use rayon::prelude::*;
                data.par_chunks_mut(tile_len).enumerate().for_each(fill);
            } else {
                data.chunks_mut(tile_len).enumerate().for_each(fill);
            }
        }
        Ok(Self { data, n, k })
    }

    /// Packs a row-major `[n, k]` matrix (a linear layer's weight).
    pub fn from_rows<T: ToBf16Bits>(data: &[T], n: usize, k: usize) -> candle_core::Result<Self> {
        Self::pack(
            Strided {
                data,
                col_stride: k,
                k_stride: 1,
            },
            n,
            k,
        )
    }

    /// Output columns `n`.
    pub fn n(&self) -> usize {
        self.n
    }

    /// Inner size `k`.
    pub fn k(&self) -> usize {
        self.k
    }

    /// Pairs of `k` (`k` rounded up to even, halved).
    pub fn pairs(&self) -> usize {
        self.k.div_ceil(2)
    }

    /// Number of [`NR`]-column tiles.
    pub fn tiles(&self) -> usize {
        self.n.div_ceil(NR)
    }

    /// The packed values of tile `tile` from pair `pair` on.
    pub(crate) fn tile(&self, tile: usize, pair: usize) -> &[u16] {
        let start = (tile * self.pairs() + pair) * NR * 2;
        let end = (tile + 1) * self.pairs() * NR * 2;
        &self.data[start..end]
    }

    /// Element `(j, t)` as f32 (tests and the reference).
    pub fn get(&self, j: usize, t: usize) -> f32 {
        let (tile, c) = (j / NR, j % NR);
        super::bf16_bits_to_f32(self.data[(tile * self.pairs() + t / 2) * NR * 2 + c * 2 + (t & 1)])
    }
}

/// Writes the bf16 bits of `src` into `dst` (same length), 16 values per instruction where the
/// CPU has AVX512-BF16 (the same rounding as [`convert_portable`]).
pub fn round_to_bf16(src: &[f32], dst: &mut [u16]) {
    #[cfg(all(target_arch = "x86_64", lhmpp_bf16_intrinsics))]
    if matches!(
        super::Kernel::detect(),
        super::Kernel::Avx512Bf16 | super::Kernel::Amx
    ) {
        // SAFETY: those kernels run only where AVX512-BF16 does.
        unsafe { super::avx512::convert(src, dst) };
        return;
    }
    convert_portable(src, dst)
}

/// Writes the bf16 bits of `src` into `dst` (same length) with the portable rounding.
pub fn convert_portable(src: &[f32], dst: &mut [u16]) {
    for (d, &s) in dst.iter_mut().zip(src) {
        *d = f32_to_bf16_bits(s);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packing_places_pairs_and_pads_with_zeros() {
        let (n, k) = (70, 5);
        let w: Vec<f32> = (0..n * k).map(|v| v as f32).collect();
        let p = PackedRhs::from_rows(&w, n, k).unwrap();
        assert_eq!((p.tiles(), p.pairs()), (2, 3));
        for j in 0..n {
            for t in 0..k {
                assert_eq!(p.get(j, t), half::bf16::from_f32(w[j * k + t]).to_f32());
            }
        }
        // Pair 2 of column 3: (t=4, padding 0).
        let t0 = p.tile(0, 2);
        assert_eq!(super::super::bf16_bits_to_f32(t0[3 * 2]), w[3 * k + 4]);
        assert_eq!(t0[3 * 2 + 1], 0);
        // Column 69 is lane 5 of tile 1; lanes past it are zero.
        assert!(p.tile(1, 0)[6 * 2..NR * 2].iter().all(|&b| b == 0));
        // Transposed source: B[j, t] = w[t * n + j].
        let q = PackedRhs::pack(
            Strided {
                data: &w,
                col_stride: 1,
                k_stride: n,
            },
            n,
            k,
        )
        .unwrap();
        assert_eq!(q.get(7, 3), half::bf16::from_f32(w[3 * n + 7]).to_f32());
    }

    #[test]
    fn an_operand_reaching_past_its_slice_is_an_error() {
        let w = vec![0f32; 10];
        let e = PackedRhs::from_rows(&w, 3, 4).unwrap_err();
        assert!(e.to_string().contains("bf16 pack"), "{e}");
    }
}
