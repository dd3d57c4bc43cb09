//! The portable micro-kernel: the sums of the AVX512-BF16 one (f32 products of bf16 values,
//! f32 accumulation) with plain loops, for CPUs without `vdpbf16ps`.

use super::{bf16_bits_to_f32, NR};

/// `C[rows × cols] += A · Bᵀ` (or `=` when `add` is false) for one tile, as
/// [`super::avx512::tile`].
///
/// # Safety
/// `a` holds `(rows − 1)·lda + kc` values, `b` holds `kc·NR·2`, and `c` is valid for reads and
/// writes of `cols ≤ NR` values at each of `rows` rows `ldc` apart, touched by no one else
/// meanwhile.
#[allow(clippy::too_many_arguments)]
pub unsafe fn tile(
    rows: usize,
    kc: usize,
    a: &[u32],
    lda: usize,
    b: &[u16],
    c: *mut f32,
    ldc: usize,
    cols: usize,
    add: bool,
) {
    let b = &b[..kc * NR * 2];
    for r in 0..rows {
        let a_row = &a[r * lda..r * lda + kc];
        let mut acc = [0f32; NR];
        for (&pair, bp) in a_row.iter().zip(b.chunks_exact(NR * 2)) {
            let a0 = bf16_bits_to_f32(pair as u16);
            let a1 = bf16_bits_to_f32((pair >> 16) as u16);
            for (s, w) in acc.iter_mut().zip(bp.chunks_exact(2)) {
                *s += a0 * bf16_bits_to_f32(w[0]) + a1 * bf16_bits_to_f32(w[1]);
            }
        }
        // SAFETY: row `r < rows` of `c` holds `cols` values no one else touches (caller).
        let c_row = std::slice::from_raw_parts_mut(c.add(r * ldc), cols);
        if add {
            for (o, s) in c_row.iter_mut().zip(acc) {
                *o += s;
            }
        } else {
            c_row.copy_from_slice(&acc[..cols]);
        }
    }
}
