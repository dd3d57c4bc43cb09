//! Transposed 2-D convolution whose kernel equals its stride (no padding), on channels-last f32
//! maps ([`FeatureMap`]): every input pixel paints its own disjoint `s×s` output block, so the
//! layer is ONE matrix product `[pixels, C_in] · [C_in, s·s·C_out]` followed by a scatter of each
//! product row into its block. Input rows run in parallel on rayon (each owns `s` output rows).

use candle_core::{Result, Tensor};
use rayon::prelude::*;

use super::conv2d::{accumulate, host_f32};
use super::feature_map::FeatureMap;

/// A `ConvTranspose2d` with `kernel == stride`, padding 0, packed for the CPU kernel.
#[derive(Debug, Clone)]
pub struct PackedConvTranspose2d {
    /// `[C_in, s·s·C_out]`, columns ordered `(i, j, c_out)`.
    weight: Vec<f32>,
    /// `[C_out]` (zeros when the layer has none).
    bias: Vec<f32>,
    c_in: usize,
    c_out: usize,
    stride: usize,
}

impl PackedConvTranspose2d {
    /// Packs `weight [C_in, C_out, s, s]` and `bias [C_out]` (any device/float dtype).
    pub fn new(weight: &Tensor, bias: Option<&Tensor>) -> Result<Self> {
        let (c_in, c_out, kh, kw) = weight.dims4()?;
        if kh != kw || kh == 0 {
            candle_core::bail!("packed conv-transpose: kernel {kh}×{kw} is not square");
        }
        let w = host_f32(&weight.permute((0, 2, 3, 1))?)?;
        let bias = match bias {
            Some(b) => host_f32(b)?,
            None => vec![0.0; c_out],
        };
        if bias.len() != c_out {
            candle_core::bail!(
                "packed conv-transpose: bias has {} values for {c_out} outputs",
                bias.len()
            );
        }
        Ok(Self {
            weight: w,
            bias,
            c_in,
            c_out,
            stride: kh,
        })
    }

    /// Packs a `candle_nn::ConvTranspose2d` whose stride equals its kernel (padding 0,
    /// output padding 0, dilation 1).
    pub fn from_candle(conv: &candle_nn::ConvTranspose2d) -> Result<Self> {
        let cfg = conv.config();
        let k = conv.weight().dim(2)?;
        if cfg.stride != k || cfg.padding != 0 || cfg.output_padding != 0 || cfg.dilation != 1 {
            candle_core::bail!("packed conv-transpose: only kernel == stride without padding ({cfg:?}, kernel {k})");
        }
        Self::new(conv.weight(), conv.bias())
    }

    /// `[B, H, W, C_in]` → `[B, s·H, s·W, C_out]`.
    pub fn forward(&self, x: &FeatureMap) -> Result<FeatureMap> {
        if x.channels != self.c_in {
            candle_core::bail!(
                "packed conv-transpose: input has {} channels, weight expects {}",
                x.channels,
                self.c_in
            );
        }
        let (s, c, n) = (
            self.stride,
            self.c_out,
            self.stride * self.stride * self.c_out,
        );
        let (w, k) = (x.width, self.c_in);
        let mut out = FeatureMap::zeros(x.batch, s * x.height, s * w, c);
        if out.data.is_empty() {
            return Ok(out);
        }
        let block_row = s * c;
        out.data
            .par_chunks_mut(s * s * w * c)
            .zip(x.data.par_chunks(w * k))
            .for_each_init(
                || vec![0f32; w * n],
                |prod, (rows, input)| {
                    prod.fill(0.0);
                    accumulate(prod, input, &self.weight, w, n, k);
                    // output row i of this input row, columns x·s..x·s+s = product row x, block i
                    for (i, line) in rows.chunks_exact_mut(s * w * c).enumerate() {
                        for (px, p) in line.chunks_exact_mut(block_row).zip(prod.chunks_exact(n)) {
                            let src = &p[i * block_row..(i + 1) * block_row];
                            for (dst, src) in px.chunks_exact_mut(c).zip(src.chunks_exact(c)) {
                                for ((d, &v), &b) in dst.iter_mut().zip(src).zip(&self.bias) {
                                    *d = v + b;
                                }
                            }
                        }
                    }
                },
            );
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::max_abs_diff;
    use candle_core::Device;
    use candle_nn::{ConvTranspose2d, ConvTranspose2dConfig, Module};

    #[test]
    fn packed_conv_transpose_equals_candle_over_odd_shapes() {
        let dev = Device::Cpu;
        for &(b, c_in, c_out, h, w, s) in &[
            (1, 3, 5, 7, 9, 4),
            (2, 17, 13, 5, 3, 2),
            (1, 8, 8, 1, 1, 4),
            (1, 6, 3, 4, 5, 1),
        ] {
            let x = Tensor::randn(0f32, 1.0, (b, c_in, h, w), &dev).unwrap();
            let wt = Tensor::randn(0f32, 0.3, (c_in, c_out, s, s), &dev).unwrap();
            let bias = Tensor::randn(0f32, 1.0, c_out, &dev).unwrap();
            let cfg = ConvTranspose2dConfig {
                stride: s,
                ..Default::default()
            };
            let conv = ConvTranspose2d::new(wt, Some(bias), cfg);
            let want = conv.forward(&x).unwrap();
            let got = PackedConvTranspose2d::from_candle(&conv)
                .unwrap()
                .forward(&FeatureMap::from_nchw(&x).unwrap())
                .unwrap()
                .to_nchw(&dev)
                .unwrap();
            assert_eq!(got.dims(), want.dims());
            let d = max_abs_diff(&got, &want);
            assert!(d < 1e-4, "b{b} {c_in}->{c_out} {h}x{w} s{s}: {d}");
        }
    }

    #[test]
    fn padded_transpose_is_refused() {
        let w = Tensor::zeros((2, 2, 3, 3), candle_core::DType::F32, &Device::Cpu).unwrap();
        let cfg = ConvTranspose2dConfig {
            stride: 2,
            ..Default::default()
        };
        assert!(PackedConvTranspose2d::from_candle(&ConvTranspose2d::new(w, None, cfg)).is_err());
    }
}
