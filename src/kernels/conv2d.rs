//! 2-D convolution on channels-last f32 maps ([`FeatureMap`]) as tiled matrix products.
//!
//! The weight `[C_out, C_in, k, k]` is packed once as a `[k·k·C_in, C_out]` matrix (rows ordered
//! `(ky, kx, c_in)`). The output pixels are cut into tiles; per tile the `k·k·C_in` input values
//! under each output pixel are gathered into a small im2col buffer (for a 3×3 stride-1 tap row
//! that is one copy of `3·C_in` contiguous values) and ONE `gemm` product accumulates onto the
//! output tile, which was first filled with the bias (plus an optional residual); an optional
//! ReLU follows while the tile is in cache. A 1×1 stride-1 convolution skips the gather. Tiles
//! run in parallel on rayon, each product on one thread, so the buffers stay per-core.

use candle_core::{DType, Result, Tensor};
use gemm::Parallelism;
use rayon::prelude::*;

use super::feature_map::FeatureMap;
use super::matmul::{matmul_into, MatRef};
use super::winograd::{conv3x3_winograd, Variant, F4X4};

/// Output pixels per tile: the im2col tile (`TILE_PIXELS·k·k·C_in` floats, 2.4 MB at 3×3×128)
/// and the output tile stay in the L2/L3 caches while `gemm` runs over them.
const TILE_PIXELS: usize = 512;

/// Fewest input and output channels for which 3×3 layers default to Winograd.
const WINOGRAD_MIN_CHANNELS: usize = 32;

/// A convolution with square kernel, stride and zero padding, packed for the CPU kernel.
#[derive(Debug, Clone)]
pub struct PackedConv2d {
    /// `[k·k·C_in, C_out]`, rows ordered `(ky, kx, c_in)`.
    weight: Vec<f32>,
    /// `[C_out]` (zeros when the layer has none).
    bias: Vec<f32>,
    c_in: usize,
    c_out: usize,
    kernel: usize,
    stride: usize,
    padding: usize,
    /// 3×3 stride-1 padding-1 layers: the Winograd algorithm and its transformed filters.
    winograd: Option<(Variant, Vec<f32>)>,
}

/// What is added to the convolution before the optional ReLU.
#[derive(Debug, Clone, Copy, Default)]
pub struct Epilogue<'a> {
    /// A map of the output's shape added to the result.
    pub residual: Option<&'a FeatureMap>,
    /// `max(·, 0)` last.
    pub relu: bool,
}

impl PackedConv2d {
    /// Packs `weight [C_out, C_in, k, k]` and `bias [C_out]` (any device/float dtype).
    pub fn new(
        weight: &Tensor,
        bias: Option<&Tensor>,
        stride: usize,
        padding: usize,
    ) -> Result<Self> {
        let (c_out, c_in, kh, kw) = weight.dims4()?;
        if kh != kw || stride == 0 {
            candle_core::bail!(
                "packed conv2d: kernel {kh}×{kw} stride {stride} (square kernel, stride ≥ 1 only)"
            );
        }
        let w = host_f32(&weight.permute((2, 3, 1, 0))?)?;
        let bias = match bias {
            Some(b) => {
                let v = host_f32(b)?;
                if v.len() != c_out {
                    candle_core::bail!(
                        "packed conv2d: bias has {} values for {c_out} outputs",
                        v.len()
                    );
                }
                v
            }
            None => vec![0.0; c_out],
        };
        let packed = Self {
            weight: w,
            bias,
            c_in,
            c_out,
            kernel: kh,
            stride,
            padding,
            winograd: None,
        };
        // Narrow layers spend Winograd's savings on its transforms: on 2 cores (`lhmpp bench
        // cpu-peer --only conv3x3`) im2col is 2× faster at 16→16, F(4×4) 1.2× faster at 64→32
        // and 2× at 128→128.
        let variant = (c_in.min(c_out) >= WINOGRAD_MIN_CHANNELS).then_some(F4X4);
        Ok(packed.with_winograd(variant))
    }

    /// The same layer computing its 3×3 stride-1 padding-1 convolution with Winograd `variant`
    /// (the default is [`F4X4`] when both channel counts are at least 32), or through im2col +
    /// gemm with `None`. Other shapes always use
    /// im2col.
    pub fn with_winograd(mut self, variant: Option<Variant>) -> Self {
        let fits = self.kernel == 3 && self.stride == 1 && self.padding == 1;
        self.winograd = match variant {
            Some(v) if fits => Some((v, v.transform_filters(&self.weight, self.c_in, self.c_out))),
            _ => None,
        };
        self
    }

    /// Packs a `candle_nn::Conv2d` (groups 1, dilation 1 only).
    pub fn from_candle(conv: &candle_nn::Conv2d) -> Result<Self> {
        let cfg = conv.config();
        if cfg.groups != 1 || cfg.dilation != 1 {
            candle_core::bail!(
                "packed conv2d: groups {} dilation {} unsupported",
                cfg.groups,
                cfg.dilation
            );
        }
        Self::new(conv.weight(), conv.bias(), cfg.stride, cfg.padding)
    }

    /// Output channels.
    pub fn out_channels(&self) -> usize {
        self.c_out
    }

    /// Output side for an input side.
    fn out_side(&self, side: usize) -> usize {
        (side + 2 * self.padding).saturating_sub(self.kernel) / self.stride + 1
    }

    /// `act(conv(x) + bias + residual)`.
    pub fn forward(&self, x: &FeatureMap, epi: Epilogue) -> Result<FeatureMap> {
        if x.channels != self.c_in {
            candle_core::bail!(
                "packed conv2d: input has {} channels, weight expects {}",
                x.channels,
                self.c_in
            );
        }
        if x.height + 2 * self.padding < self.kernel || x.width + 2 * self.padding < self.kernel {
            candle_core::bail!(
                "packed conv2d: input {}×{} smaller than the kernel",
                x.height,
                x.width
            );
        }
        let (oh, ow) = (self.out_side(x.height), self.out_side(x.width));
        let n = self.c_out;
        let pixels = x.batch * oh * ow;
        let mut out = FeatureMap::zeros(x.batch, oh, ow, n);
        if let Some(r) = epi.residual {
            out.check_same_shape(r, "conv2d residual")?;
        }
        if pixels == 0 || n == 0 {
            return Ok(out);
        }
        if let Some((variant, u)) = &self.winograd {
            conv3x3_winograd(*variant, x, u, &self.bias, epi, &mut out);
            return Ok(out);
        }
        let k = self.kernel * self.kernel * self.c_in;
        let direct = self.kernel == 1 && self.stride == 1 && self.padding == 0;
        let residual = epi.residual.map(|r| r.data.as_slice());
        out.data
            .par_chunks_mut(TILE_PIXELS * n)
            .enumerate()
            .for_each_init(
                || {
                    if direct {
                        Vec::new()
                    } else {
                        vec![0f32; TILE_PIXELS * k]
                    }
                },
                |cols, (t, tile)| {
                    let first = t * TILE_PIXELS;
                    let m = tile.len() / n;
                    let start = first * n;
                    match residual {
                        Some(r) => {
                            for (row, rrow) in
                                tile.chunks_exact_mut(n).zip(r[start..].chunks_exact(n))
                            {
                                for ((o, &r), &b) in row.iter_mut().zip(rrow).zip(&self.bias) {
                                    *o = r + b;
                                }
                            }
                        }
                        None => tile
                            .chunks_exact_mut(n)
                            .for_each(|row| row.copy_from_slice(&self.bias)),
                    }
                    let lhs: &[f32] = if direct {
                        &x.data[first * k..(first + m) * k]
                    } else {
                        self.gather(x, oh, ow, first, m, &mut cols[..m * k]);
                        &cols[..m * k]
                    };
                    accumulate(tile, lhs, &self.weight, m, n, k);
                    if epi.relu {
                        tile.iter_mut().for_each(|v| *v = v.max(0.0));
                    }
                },
            );
        Ok(out)
    }

    /// im2col of output pixels `first..first + m` into `cols [m, k·k·C_in]` (zeros off the map).
    fn gather(
        &self,
        x: &FeatureMap,
        oh: usize,
        ow: usize,
        first: usize,
        m: usize,
        cols: &mut [f32],
    ) {
        let (ks, c, s, p) = (self.kernel, self.c_in, self.stride, self.padding);
        let (h, w) = (x.height as isize, x.width as isize);
        let row_len = ks * c;
        for (i, col) in cols.chunks_exact_mut(ks * row_len).enumerate().take(m) {
            let q = first + i;
            let (b, oy, ox) = (q / (oh * ow), (q / ow) % oh, q % ow);
            let image = &x.data[b * x.height * x.width * c..(b + 1) * x.height * x.width * c];
            let x0 = (ox * s) as isize - p as isize;
            for (ky, dst) in col.chunks_exact_mut(row_len).enumerate() {
                let iy = (oy * s + ky) as isize - p as isize;
                if iy < 0 || iy >= h {
                    dst.fill(0.0);
                    continue;
                }
                let line = &image[iy as usize * w as usize * c..(iy as usize + 1) * w as usize * c];
                // columns x0..x0+ks: copy the in-bounds run in one go, zero the rest
                let lo = x0.max(0);
                let hi = (x0 + ks as isize).min(w);
                let skip = (lo - x0) as usize * c;
                dst[..skip].fill(0.0);
                if hi > lo {
                    let len = (hi - lo) as usize * c;
                    dst[skip..skip + len].copy_from_slice(&line[lo as usize * c..hi as usize * c]);
                    dst[skip + len..].fill(0.0);
                } else {
                    dst[skip..].fill(0.0);
                }
            }
        }
    }
}

/// The f32 values of a tensor (contiguous row-major copy on the host).
pub(crate) fn host_f32(t: &Tensor) -> Result<Vec<f32>> {
    t.to_device(&candle_core::Device::Cpu)?
        .to_dtype(DType::F32)?
        .flatten_all()?
        .to_vec1::<f32>()
}

/// `out [m, n] += lhs [m, k] · rhs [k, n]`, all row-major, on the calling thread.
pub(crate) fn accumulate(out: &mut [f32], lhs: &[f32], rhs: &[f32], m: usize, n: usize, k: usize) {
    assert!(out.len() == m * n && lhs.len() == m * k && rhs.len() == k * n);
    let (lhs, rhs) = (MatRef::row_major(lhs, m, k), MatRef::row_major(rhs, k, n));
    matmul_into(out, n, lhs, rhs, true, 1.0, Parallelism::None);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::winograd::F2X2;
    use crate::testing::max_abs_diff;
    use candle_core::Device;
    use candle_nn::{Conv2d, Conv2dConfig, Module};

    /// `(batch, c_in, c_out, h, w, kernel, stride, padding)`.
    type Case = (usize, usize, usize, usize, usize, usize, usize, usize);

    fn check((b, c_in, c_out, h, w, k, stride, padding): Case) {
        let dev = Device::Cpu;
        let x = Tensor::randn(0f32, 1.0, (b, c_in, h, w), &dev).unwrap();
        let wt = Tensor::randn(0f32, 0.2, (c_out, c_in, k, k), &dev).unwrap();
        let bias = Tensor::randn(0f32, 1.0, c_out, &dev).unwrap();
        let cfg = Conv2dConfig {
            padding,
            stride,
            ..Default::default()
        };
        let conv = Conv2d::new(wt, Some(bias), cfg);
        let want = conv.forward(&x).unwrap();
        let res = Tensor::randn(0f32, 1.0, want.dims(), &dev).unwrap();
        let xm = FeatureMap::from_nchw(&x).unwrap();
        let rm = FeatureMap::from_nchw(&res).unwrap();
        let scale = want.abs().unwrap().flatten_all().unwrap().max(0).unwrap();
        let scale = scale.to_scalar::<f32>().unwrap().max(1.0);
        let want_epi = (&want + res).unwrap().relu().unwrap();
        let packed = PackedConv2d::from_candle(&conv).unwrap();
        let wide = c_in.min(c_out) >= WINOGRAD_MIN_CHANNELS;
        assert_eq!(
            packed.winograd.is_some(),
            (k, stride, padding, wide) == (3, 1, 1, true)
        );
        for variant in [Some(F4X4), Some(F2X2), None] {
            let packed = packed.clone().with_winograd(variant);
            let path = format!("winograd {:?}", packed.winograd.as_ref().map(|(v, _)| v.m));
            // F(4×4)'s transforms (entries up to 8, filter factors down to 1/24) cost about
            // one more decimal digit than direct summation: ~1e-5 of the largest output.
            let tol = scale
                * if packed.winograd.as_ref().is_some_and(|(v, _)| v.m == 4) {
                    1e-4
                } else {
                    1e-5
                };
            let case = format!("{path} b{b} {c_in}->{c_out} {h}x{w} k{k} s{stride} p{padding}");
            let got = packed.forward(&xm, Epilogue::default()).unwrap();
            let got = got.to_nchw(&dev).unwrap();
            assert_eq!(got.dims(), want.dims());
            let d = max_abs_diff(&got, &want);
            assert!(d < tol, "{case}: {d}");
            let epi = Epilogue {
                residual: Some(&rm),
                relu: true,
            };
            let got = packed.forward(&xm, epi).unwrap().to_nchw(&dev).unwrap();
            let d = max_abs_diff(&got, &want_epi);
            assert!(d < tol, "{case} with residual and ReLU: {d}");
        }
    }

    #[test]
    fn packed_conv_equals_candle_conv_over_odd_shapes() {
        check((1, 3, 5, 7, 9, 3, 1, 1));
        check((2, 17, 13, 23, 19, 3, 1, 1));
        check((1, 16, 8, 33, 34, 3, 2, 1));
        check((2, 5, 7, 9, 8, 3, 2, 1));
        check((1, 19, 11, 30, 29, 1, 1, 0));
        check((1, 8, 4, 1, 1, 3, 1, 1));
        check((1, 6, 4, 5, 6, 3, 1, 0));
    }

    #[test]
    fn many_tiles_and_wide_channels_match() {
        // more than one im2col tile per image with a boundary inside a row; Winograd bands of
        // one wide tile row split into several chunks, and bands of several narrow rows
        check((1, 64, 32, 37, 41, 3, 1, 1));
        check((1, 8, 8, 5, 400, 3, 1, 1));
        check((2, 8, 8, 41, 7, 3, 1, 1));
        check((1, 96, 96, 5, 700, 3, 1, 1));
    }

    #[test]
    fn wrong_channel_count_is_an_error() {
        let w = Tensor::zeros((4, 3, 3, 3), DType::F32, &Device::Cpu).unwrap();
        let p = PackedConv2d::new(&w, None, 1, 1).unwrap();
        let err = p
            .forward(&FeatureMap::zeros(1, 4, 4, 5), Epilogue::default())
            .unwrap_err();
        assert!(err.to_string().contains("5 channels"), "{err}");
    }
}
