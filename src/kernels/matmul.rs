//! The one checked entry point to the `gemm` crate's strided matrix product used by every CPU
//! kernel here (linear layers, convolutions, Winograd, attention), so that the unsafe call and
//! the bounds it relies on are stated once.

use gemm::Parallelism;

/// A read-only strided matrix: element `(i, j)` is `data[i·row_stride + j·col_stride]`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct MatRef<'a> {
    pub data: &'a [f32],
    pub rows: usize,
    pub cols: usize,
    pub row_stride: usize,
    pub col_stride: usize,
}

impl<'a> MatRef<'a> {
    /// A `rows × cols` matrix whose rows are `row_stride` elements apart (unit column stride).
    pub fn rows_apart(data: &'a [f32], rows: usize, cols: usize, row_stride: usize) -> Self {
        Self {
            data,
            rows,
            cols,
            row_stride,
            col_stride: 1,
        }
    }

    /// A dense row-major `rows × cols` matrix.
    pub fn row_major(data: &'a [f32], rows: usize, cols: usize) -> Self {
        Self::rows_apart(data, rows, cols, cols)
    }

    /// True when every element lies inside `data`.
    fn in_bounds(&self) -> bool {
        self.rows == 0
            || self.cols == 0
            || (self.rows - 1) * self.row_stride + (self.cols - 1) * self.col_stride
                < self.data.len()
    }
}

/// `out ← scale · lhs · rhs`, or `out ← out + scale · lhs · rhs` when `accumulate`, for
/// `out [m, n]` with rows `out_row_stride` elements apart (unit column stride). Panics if a
/// matrix reaches outside its slice, the inner sizes differ or the rows of `out` overlap.
pub(crate) fn matmul_into(
    out: &mut [f32],
    out_row_stride: usize,
    lhs: MatRef,
    rhs: MatRef,
    accumulate: bool,
    scale: f32,
    parallelism: Parallelism,
) {
    let (m, n, k) = (lhs.rows, rhs.cols, lhs.cols);
    assert_eq!(rhs.rows, k, "matmul: inner sizes differ");
    assert!(
        lhs.in_bounds() && rhs.in_bounds(),
        "matmul: operand out of bounds"
    );
    if m == 0 || n == 0 {
        return;
    }
    assert!(
        (m == 1 || out_row_stride >= n) && (m - 1) * out_row_stride + n <= out.len(),
        "matmul: output out of bounds"
    );
    if k == 0 {
        if !accumulate {
            out.chunks_mut(out_row_stride.max(n))
                .take(m)
                .for_each(|r| r[..n].fill(0.0));
        }
        return;
    }
    // SAFETY: `out` holds m rows of n values `out_row_stride` apart without overlap, and every
    // element of `lhs` (m × k) and `rhs` (k × n) lies in its slice: all asserted above.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            out.as_mut_ptr(),
            1,
            out_row_stride as isize,
            accumulate,
            lhs.data.as_ptr(),
            lhs.col_stride as isize,
            lhs.row_stride as isize,
            rhs.data.as_ptr(),
            rhs.col_stride as isize,
            rhs.row_stride as isize,
            if accumulate { 1.0 } else { 0.0 },
            scale,
            false,
            false,
            false,
            parallelism,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn naive(lhs: &MatRef, rhs: &MatRef) -> Vec<f32> {
        let at = |a: &MatRef, i: usize, j: usize| a.data[i * a.row_stride + j * a.col_stride];
        let mut out = vec![0.0; lhs.rows * rhs.cols];
        for i in 0..lhs.rows {
            for j in 0..rhs.cols {
                out[i * rhs.cols + j] = (0..lhs.cols).map(|t| at(lhs, i, t) * at(rhs, t, j)).sum();
            }
        }
        out
    }

    #[test]
    fn strided_products_overwrite_or_accumulate() {
        let data: Vec<f32> = (0..200).map(|v| (v % 17) as f32 - 8.0).collect();
        // lhs 3 × 4 with rows 6 apart; rhs 4 × 5 read transposed (column stride 4).
        let lhs = MatRef::rows_apart(&data, 3, 4, 6);
        let rhs = MatRef {
            data: &data[30..],
            rows: 4,
            cols: 5,
            row_stride: 1,
            col_stride: 4,
        };
        let want = naive(&lhs, &rhs);
        let mut out = vec![7.0; 3 * 8]; // rows 8 apart
        matmul_into(&mut out, 8, lhs, rhs, false, 1.0, Parallelism::None);
        for i in 0..3 {
            assert_eq!(&out[i * 8..i * 8 + 5], &want[i * 5..i * 5 + 5]);
            assert_eq!(&out[i * 8 + 5..i * 8 + 8], &[7.0; 3], "padding untouched");
        }
        matmul_into(&mut out, 8, lhs, rhs, true, 0.5, Parallelism::None);
        for i in 0..3 {
            for j in 0..5 {
                assert_eq!(out[i * 8 + j], 1.5 * want[i * 5 + j]);
            }
        }
        let mut empty_k = vec![3.0; 4];
        let none = MatRef::row_major(&[], 2, 0);
        matmul_into(
            &mut empty_k,
            2,
            none,
            MatRef::row_major(&[], 0, 2),
            false,
            1.0,
            Parallelism::None,
        );
        assert_eq!(empty_k, [0.0; 4], "k = 0 writes zeros");
    }

    #[test]
    #[should_panic(expected = "out of bounds")]
    fn an_operand_reaching_past_its_slice_panics() {
        let data = [1.0f32; 10];
        let mut out = [0.0f32; 4];
        let lhs = MatRef::rows_apart(&data, 2, 3, 8); // last element at 10
        matmul_into(
            &mut out,
            2,
            lhs,
            MatRef::row_major(&data, 3, 2),
            false,
            1.0,
            Parallelism::None,
        );
    }
}
