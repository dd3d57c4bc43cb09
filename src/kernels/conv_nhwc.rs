//! Dense 2-D convolution of one channels-last image with explicit zero padding and any kernel
//! size and stride, as matrix products ([`super::pointwise`]): a 1×1 stride-1 unpadded layer
//! multiplies the pixel rows in place; any other gathers the `kh·kw·C_in` values under each
//! output pixel (zeros off the image) into a per-thread block of rows first. The weight is
//! TFLite's `[C_out][kh][kw][C_in]`, whose rows are already in the gathered order.

use std::cell::RefCell;

use rayon::prelude::*;

use super::nhwc::{Epilogue, Padding, Shape};
use super::pointwise::{rows_per_task, PackedGemm};

/// Floats of gathered rows per block (128 KiB).
const GATHER_FLOATS: usize = 1 << 15;

thread_local! {
    /// Each thread's gather buffer, kept between calls.
    static GATHER: RefCell<Vec<f32>> = const { RefCell::new(Vec::new()) };
}

/// A packed `kh×kw` convolution with a stride.
#[derive(Debug, Clone)]
pub struct ConvNhwc {
    gemm: PackedGemm,
    kernel: (usize, usize),
    stride: (usize, usize),
    c_in: usize,
}

impl ConvNhwc {
    /// Packs `weight [C_out][kh][kw][C_in]` and `bias [C_out]`; `stride` is (rows, columns).
    pub fn new(
        weight: &[f32],
        bias: &[f32],
        c_out: usize,
        kernel: (usize, usize),
        c_in: usize,
        stride: (usize, usize),
    ) -> Self {
        assert!(stride.0 > 0 && stride.1 > 0, "conv: zero stride");
        let k = kernel.0 * kernel.1 * c_in;
        Self {
            gemm: PackedGemm::from_rows(weight, k, c_out, bias),
            kernel,
            stride,
            c_in,
        }
    }

    /// Input channels.
    pub fn in_channels(&self) -> usize {
        self.c_in
    }

    /// Output channels.
    pub fn out_channels(&self) -> usize {
        self.gemm.n()
    }

    /// Kernel (rows, columns).
    pub fn kernel(&self) -> (usize, usize) {
        self.kernel
    }

    /// Stride (rows, columns).
    pub fn stride(&self) -> (usize, usize) {
        self.stride
    }

    /// The output shape for an input shape and padding.
    pub fn out_shape(&self, input: Shape, pad: Padding) -> Shape {
        Shape::new(
            Padding::out_side(
                input.height,
                pad.top,
                pad.bottom,
                self.kernel.0,
                self.stride.0,
            ),
            Padding::out_side(
                input.width,
                pad.left,
                pad.right,
                self.kernel.1,
                self.stride.1,
            ),
            self.gemm.n(),
        )
    }

    /// `out = epi(conv(input padded by pad) + bias)`; `epi.residual` has the output's shape.
    pub fn run(&self, input: &[f32], shape: Shape, pad: Padding, epi: Epilogue, out: &mut [f32]) {
        assert_eq!(shape.channels, self.c_in, "conv: input channels");
        assert_eq!(input.len(), shape.len(), "conv: input length");
        let os = self.out_shape(shape, pad);
        assert_eq!(out.len(), os.len(), "conv: output length");
        let m = os.pixels();
        if m == 0 {
            return;
        }
        let direct = self.kernel == (1, 1) && self.stride == (1, 1) && pad == Padding::default();
        if direct {
            self.gemm.run(input, self.c_in, m, epi, out);
            return;
        }
        let k = self.gemm.k();
        let n = self.gemm.n();
        let block = (GATHER_FLOATS / k).clamp(12, 480) / 12 * 12;
        let rows = rows_per_task(m, m * n * k);
        out.par_chunks_mut(rows * n)
            .enumerate()
            .for_each(|(t, chunk)| {
                GATHER.with(|buf| {
                    let mut buf = buf.borrow_mut();
                    if buf.len() < block * k {
                        buf.resize(block * k, 0.0);
                    }
                    let first = t * rows;
                    let count = chunk.len() / n;
                    let mut r = 0;
                    while r < count {
                        let rm = block.min(count - r);
                        let rows_buf = &mut buf[..rm * k];
                        self.gather(input, shape, pad, os, first + r, rows_buf);
                        let e = Epilogue {
                            residual: epi
                                .residual
                                .map(|x| &x[(first + r) * n..(first + r + rm) * n]),
                            ..epi
                        };
                        self.gemm
                            .run_serial(rows_buf, k, rm, e, &mut chunk[r * n..(r + rm) * n]);
                        r += rm;
                    }
                });
            });
    }

    /// The gathered rows of output pixels `first..first + rows.len() / k`.
    fn gather(
        &self,
        input: &[f32],
        shape: Shape,
        pad: Padding,
        os: Shape,
        first: usize,
        rows: &mut [f32],
    ) {
        let (kh, kw) = self.kernel;
        let c = self.c_in;
        let k = kh * kw * c;
        for (i, row) in rows.chunks_exact_mut(k).enumerate() {
            let q = first + i;
            let (oy, ox) = (q / os.width, q % os.width);
            for ky in 0..kh {
                let taps = &mut row[ky * kw * c..(ky + 1) * kw * c];
                let iy = (oy * self.stride.0 + ky).checked_sub(pad.top);
                let Some(iy) = iy.filter(|&y| y < shape.height) else {
                    taps.fill(0.0);
                    continue;
                };
                for kx in 0..kw {
                    let dst = &mut taps[kx * c..(kx + 1) * c];
                    match (ox * self.stride.1 + kx).checked_sub(pad.left) {
                        Some(ix) if ix < shape.width => {
                            let at = (iy * shape.width + ix) * c;
                            dst.copy_from_slice(&input[at..at + c]);
                        }
                        _ => dst.fill(0.0),
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::nhwc::Activation;

    fn values(n: usize, seed: u32) -> Vec<f32> {
        (0..n)
            .map(|i| (((i as u32).wrapping_mul(seed * 2 + 7919) % 1999) as f32 / 999.5) - 1.0)
            .collect()
    }

    /// Direct summation over the definition.
    #[allow(clippy::too_many_arguments)]
    fn reference(
        x: &[f32],
        s: Shape,
        w: &[f32],
        b: &[f32],
        c_out: usize,
        (kh, kw): (usize, usize),
        (sh, sw): (usize, usize),
        pad: Padding,
    ) -> (Vec<f32>, Shape) {
        let oh = Padding::out_side(s.height, pad.top, pad.bottom, kh, sh);
        let ow = Padding::out_side(s.width, pad.left, pad.right, kw, sw);
        let mut out = vec![0.0; oh * ow * c_out];
        for oy in 0..oh {
            for ox in 0..ow {
                for o in 0..c_out {
                    let mut acc = b[o] as f64;
                    for ky in 0..kh {
                        for kx in 0..kw {
                            let iy = (oy * sh + ky) as isize - pad.top as isize;
                            let ix = (ox * sw + kx) as isize - pad.left as isize;
                            if iy < 0 || ix < 0 || iy >= s.height as isize || ix >= s.width as isize
                            {
                                continue;
                            }
                            for c in 0..s.channels {
                                let xv =
                                    x[((iy as usize) * s.width + ix as usize) * s.channels + c];
                                let wv = w[((o * kh + ky) * kw + kx) * s.channels + c];
                                acc += xv as f64 * wv as f64;
                            }
                        }
                    }
                    out[(oy * ow + ox) * c_out + o] = acc as f32;
                }
            }
        }
        (out, Shape::new(oh, ow, c_out))
    }

    #[test]
    fn convolutions_match_direct_summation() {
        let cases = [
            // (h, w, c_in, c_out, kernel, stride, pad)
            (9, 11, 3, 24, (3, 3), (2, 2), Padding::uniform(1)),
            (7, 6, 8, 1, (3, 3), (1, 1), Padding::uniform(1)),
            (2, 2, 20, 13, (2, 2), (1, 1), Padding::default()),
            (5, 5, 16, 40, (1, 1), (1, 1), Padding::default()),
            (
                6,
                7,
                5,
                9,
                (1, 1),
                (2, 2),
                Padding {
                    top: 0,
                    left: 1,
                    bottom: 1,
                    right: 0,
                },
            ),
            (40, 31, 4, 18, (5, 5), (2, 2), Padding::uniform(2)),
        ];
        for (h, w, ci, co, k, st, pad) in cases {
            let s = Shape::new(h, w, ci);
            let x = values(s.len(), 1);
            let wt = values(co * k.0 * k.1 * ci, 2);
            let b = values(co, 3);
            let conv = ConvNhwc::new(&wt, &b, co, k, ci, st);
            let (want, os) = reference(&x, s, &wt, &b, co, k, st, pad);
            assert_eq!(conv.out_shape(s, pad), os);
            let mut got = vec![f32::NAN; os.len()];
            conv.run(&x, s, pad, Epilogue::default(), &mut got);
            let d = got
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f32::max);
            assert!(d < 1e-4, "{h}x{w}x{ci}->{co} k{k:?} s{st:?}: {d}");
            let res = values(os.len(), 4);
            let epi = Epilogue {
                pre: Activation::Relu6,
                residual: Some(&res),
                post: Activation::Relu,
            };
            conv.run(&x, s, pad, epi, &mut got);
            for i in 0..os.len() {
                let v = (want[i].clamp(0.0, 6.0) + res[i]).max(0.0);
                assert!((got[i] - v).abs() < 1e-4, "epilogue at {i}");
            }
        }
    }
}
