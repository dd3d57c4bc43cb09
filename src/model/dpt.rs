//! The LHM++ neural renderer (`neural_renderer.*`, official `PatchDPT4DecoderOnly` with a VGGT-style
//! `DPTHead`): splatted feature map → RGB image and mask.
//!
//! `patchify` cuts the map into 7×7 patches (token dim ordered `(ph, pw, c)`) and projects them
//! (Linear, no bias) to `embed_dim`; the tokens are split into 4 channel groups that play the
//! four "intermediate layers" of the DPT head: LayerNorm, 1×1 projections, UV sin/cos position
//! embedding ×0.1, resize (ConvT 4×, ConvT 2×, identity, Conv stride 2), `scratch.layer{1..4}_rn`,
//! RefineNet fusion (residual conv units, bilinear `align_corners=True`), `output_conv1`, bilinear
//! to (H, W), position embedding, `output_conv2`, sigmoid. The unused
//! `neural_renderer.transformer_block.*` weights of the checkpoint are not loaded.

use candle_core::{DType, Device, Module, Result, Tensor, D};
use candle_nn::{
    conv2d, conv2d_no_bias, conv_transpose2d, Conv2d, Conv2dConfig, ConvTranspose2d,
    ConvTranspose2dConfig, VarBuilder,
};

use super::ops::layer_norm::{layer_norm, LayerNorm};
use super::ops::linear::{linear_no_bias, Linear};

/// Neural-renderer configuration (official `neural_renderer` block of the config).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DptConfig {
    /// Channels of the splatted feature map (`enc_channels`, 128).
    pub in_channels: usize,
    /// Patch side (`enc_patch_size`, 7).
    pub patch_size: usize,
    /// Token size after patchify (`img_dim`, 1024); split into 4 groups for the head.
    pub embed_dim: usize,
    /// Fusion width of the DPT head (128).
    pub features: usize,
    /// Projection widths of the four DPT inputs ([128, 256, 512, 512]).
    pub out_channels: [usize; 4],
}

impl DptConfig {
    /// The released LHMPP-700M neural renderer.
    pub fn lhmpp_700m() -> Self {
        Self {
            in_channels: 128,
            patch_size: 7,
            embed_dim: 1024,
            features: 128,
            out_channels: [128, 256, 512, 512],
        }
    }

    /// A tiny renderer for tests (feature size of the tiny point backbone output).
    pub fn tiny() -> Self {
        Self {
            in_channels: 32,
            patch_size: 7,
            embed_dim: 64,
            features: 16,
            out_channels: [16, 32, 64, 64],
        }
    }

    /// Size of each of the four token groups the head reads.
    pub fn head_dim(&self) -> usize {
        self.embed_dim / 4
    }
}

/// Bad input to the neural renderer.
#[derive(Debug, thiserror::Error)]
pub enum DptError {
    /// The feature map has the wrong channel count or a size that is not a multiple of the patch.
    #[error("neural renderer: feature map {dims:?} must be [B, {channels}, H, W] with H, W multiples of {patch}")]
    BadInput {
        /// Dims received.
        dims: Vec<usize>,
        /// Channels expected.
        channels: usize,
        /// Patch size.
        patch: usize,
    },
}

fn conv3x3(c_in: usize, c_out: usize, vb: VarBuilder) -> Result<Conv2d> {
    let cfg = Conv2dConfig {
        padding: 1,
        ..Default::default()
    };
    conv2d(c_in, c_out, 3, cfg, vb)
}

fn conv1x1(c_in: usize, c_out: usize, vb: VarBuilder) -> Result<Conv2d> {
    conv2d(c_in, c_out, 1, Conv2dConfig::default(), vb)
}

/// 1-D sin/cos embedding of `pos` with `dim` channels (`[sin | cos]`, ω = 1/100^(2i/dim)).
fn sincos(dim: usize, pos: f64) -> impl Iterator<Item = f32> {
    let half = dim / 2;
    let omega = move |i: usize| 1.0 / 100f64.powf(i as f64 / half as f64);
    let s = (0..half).map(move |i| (pos * omega(i)).sin() as f32);
    let c = (0..half).map(move |i| (pos * omega(i)).cos() as f32);
    s.chain(c)
}

/// VGGT's `create_uv_grid` + `position_grid_to_embed` × `ratio` as `[1, C, h, w]`:
/// UV spans normalised by the image diagonal (`aspect = W / H` of the full image), x half then y half.
pub fn uv_position_embedding(
    channels: usize,
    h: usize,
    w: usize,
    aspect: f64,
    ratio: f64,
    device: &Device,
) -> Result<Tensor> {
    let diag = (aspect * aspect + 1.0).sqrt();
    let (span_x, span_y) = (aspect / diag, 1.0 / diag);
    let lin = |n: usize, span: f64| -> Vec<f64> {
        let lo = -span * (n as f64 - 1.0) / n as f64;
        let hi = -lo;
        (0..n)
            .map(|i| {
                if n == 1 {
                    lo
                } else {
                    lo + (hi - lo) * i as f64 / (n - 1) as f64
                }
            })
            .collect()
    };
    let half = channels / 2;
    // The x half depends on the column only and the y half on the row only: encode each
    // column and row once ((h + w)·C sines instead of h·w·C).
    let encode = |vals: Vec<f64>| -> Vec<Vec<f32>> {
        vals.into_iter()
            .map(|v| sincos(half, v).map(|e| e * ratio as f32).collect())
            .collect()
    };
    let xe = encode(lin(w, span_x));
    let ye = encode(lin(h, span_y));
    let mut data = Vec::with_capacity(h * w * channels);
    for y in &ye {
        for x in &xe {
            data.extend_from_slice(x);
            data.extend_from_slice(y);
        }
    }
    Tensor::from_vec(data, (h, w, channels), device)?
        .permute((2, 0, 1))?
        .unsqueeze(0)
}

/// DPT `ResidualConvUnit`: `conv2(relu(conv1(relu(x)))) + relu(x)` — the official ReLU is in
/// place, so the skip adds the rectified input.
#[derive(Debug, Clone)]
struct ResidualConvUnit {
    conv1: Conv2d,
    conv2: Conv2d,
}

impl ResidualConvUnit {
    fn new(features: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            conv1: conv3x3(features, features, vb.pp("conv1"))?,
            conv2: conv3x3(features, features, vb.pp("conv2"))?,
        })
    }

    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let x = x.relu()?;
        let out = self.conv2.forward(&self.conv1.forward(&x)?.relu()?)?;
        out + x
    }
}

/// DPT `FeatureFusionBlock` (`scratch.refinenet{i}`).
#[derive(Debug, Clone)]
struct FusionBlock {
    res1: Option<ResidualConvUnit>,
    res2: ResidualConvUnit,
    out_conv: Conv2d,
}

impl FusionBlock {
    fn new(features: usize, has_residual: bool, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            res1: if has_residual {
                Some(ResidualConvUnit::new(features, vb.pp("resConfUnit1"))?)
            } else {
                None
            },
            res2: ResidualConvUnit::new(features, vb.pp("resConfUnit2"))?,
            out_conv: conv1x1(features, features, vb.pp("out_conv"))?,
        })
    }

    /// `x` (+ `res1(skip)`) → `res2` → bilinear to `size` (or ×2) → `out_conv`.
    fn forward(
        &self,
        x: &Tensor,
        skip: Option<&Tensor>,
        size: Option<(usize, usize)>,
    ) -> Result<Tensor> {
        let mut out = x.clone();
        if let (Some(res1), Some(skip)) = (&self.res1, skip) {
            out = (out + res1.forward(skip)?)?;
        }
        let out = self.res2.forward(&out)?;
        let (_, _, h, w) = out.dims4()?;
        let (th, tw) = size.unwrap_or((2 * h, 2 * w));
        self.out_conv
            .forward(&out.upsample_bilinear2d(th, tw, true)?)
    }
}

/// The resize layer of one DPT input.
#[derive(Debug, Clone)]
enum Resize {
    Up(ConvTranspose2d),
    Identity,
    Down(Conv2d),
}

impl Resize {
    fn forward(&self, x: &Tensor) -> Result<Tensor> {
        match self {
            Resize::Up(c) => c.forward(x),
            Resize::Identity => Ok(x.clone()),
            Resize::Down(c) => c.forward(x),
        }
    }
}

/// The VGGT-style `DPTHead` (`neural_renderer.dense_predictor`), output_dim 4.
#[derive(Debug, Clone)]
struct DptHead {
    norm: LayerNorm,
    projects: Vec<Conv2d>,
    resize: Vec<Resize>,
    layer_rn: Vec<Conv2d>,
    refine: Vec<FusionBlock>,
    output_conv1: Conv2d,
    output_conv2a: Conv2d,
    output_conv2b: Conv2d,
}

impl DptHead {
    fn new(cfg: &DptConfig, vb: VarBuilder) -> Result<Self> {
        let dim_in = cfg.head_dim();
        let oc = cfg.out_channels;
        let f = cfg.features;
        let projects = (0..4)
            .map(|i| conv1x1(dim_in, oc[i], vb.pp("projects").pp(i)))
            .collect::<Result<Vec<_>>>()?;
        let rl = vb.pp("resize_layers");
        let up = |i: usize, k: usize| -> Result<Resize> {
            let cfg = ConvTranspose2dConfig {
                stride: k,
                ..Default::default()
            };
            Ok(Resize::Up(conv_transpose2d(
                oc[i],
                oc[i],
                k,
                cfg,
                rl.pp(i),
            )?))
        };
        let down = Conv2dConfig {
            padding: 1,
            stride: 2,
            ..Default::default()
        };
        let resize = vec![
            up(0, 4)?,
            up(1, 2)?,
            Resize::Identity,
            Resize::Down(conv2d(oc[3], oc[3], 3, down, rl.pp(3))?),
        ];
        let scratch = vb.pp("scratch");
        let pad1 = Conv2dConfig {
            padding: 1,
            ..Default::default()
        };
        let layer_rn = (0..4)
            .map(|i| conv2d_no_bias(oc[i], f, 3, pad1, scratch.pp(format!("layer{}_rn", i + 1))))
            .collect::<Result<Vec<_>>>()?;
        let refine = (0..4)
            .map(|i| FusionBlock::new(f, i != 3, scratch.pp(format!("refinenet{}", i + 1))))
            .collect::<Result<Vec<_>>>()?;
        let oc2 = scratch.pp("output_conv2");
        Ok(Self {
            norm: layer_norm(dim_in, 1e-5, vb.pp("norm"))?,
            projects,
            resize,
            layer_rn,
            refine,
            output_conv1: conv3x3(f, f / 2, scratch.pp("output_conv1"))?,
            output_conv2a: conv3x3(f / 2, 32, oc2.pp("0"))?,
            output_conv2b: conv1x1(32, 4, oc2.pp("2"))?,
        })
    }

    /// Four token groups `[B, hh·ww, dim_in]` → logits `[B, 4, H, W]` for an image of (H, W).
    fn forward(
        &self,
        groups: &[Tensor],
        hh: usize,
        ww: usize,
        image: (usize, usize),
    ) -> Result<Tensor> {
        let (h_img, w_img) = image;
        let aspect = w_img as f64 / h_img as f64;
        let device = groups[0].device();
        let mut feats = Vec::with_capacity(4);
        for (i, g) in groups.iter().enumerate() {
            let b = g.dim(0)?;
            let x = self.norm.forward(g)?;
            let x = x.transpose(1, 2)?.reshape((b, x.dim(2)?, hh, ww))?;
            let x = self.projects[i].forward(&x)?;
            let pe = uv_position_embedding(x.dim(1)?, hh, ww, aspect, 0.1, device)?;
            let x = x.broadcast_add(&pe.to_dtype(x.dtype())?)?;
            feats.push(self.resize[i].forward(&x)?);
        }
        let rn = feats
            .iter()
            .zip(&self.layer_rn)
            .map(|(f, c)| c.forward(f))
            .collect::<Result<Vec<_>>>()?;
        let size = |t: &Tensor| -> Result<(usize, usize)> {
            let (_, _, h, w) = t.dims4()?;
            Ok((h, w))
        };
        let out = self.refine[3].forward(&rn[3], None, Some(size(&rn[2])?))?;
        let out = self.refine[2].forward(&out, Some(&rn[2]), Some(size(&rn[1])?))?;
        let out = self.refine[1].forward(&out, Some(&rn[1]), Some(size(&rn[0])?))?;
        let out = self.refine[0].forward(&out, Some(&rn[0]), None)?;
        let out = self.output_conv1.forward(&out)?;
        let out = out.upsample_bilinear2d(h_img, w_img, true)?;
        let pe = uv_position_embedding(out.dim(1)?, h_img, w_img, aspect, 0.1, device)?;
        let out = out.broadcast_add(&pe.to_dtype(out.dtype())?)?;
        self.output_conv2b
            .forward(&self.output_conv2a.forward(&out)?.relu()?)
    }
}

/// The neural renderer (`neural_renderer`): patchify + DPT head.
#[derive(Debug, Clone)]
pub struct NeuralRenderer {
    cfg: DptConfig,
    patchify: Linear,
    head: DptHead,
}

impl NeuralRenderer {
    /// Build from `vb = root.pp("neural_renderer")`.
    pub fn new(cfg: &DptConfig, vb: VarBuilder) -> Result<Self> {
        let p = cfg.patch_size;
        Ok(Self {
            cfg: cfg.clone(),
            patchify: linear_no_bias(
                p * p * cfg.in_channels,
                cfg.embed_dim,
                vb.pp("patchify").pp("1"),
            )?,
            head: DptHead::new(cfg, vb.pp("dense_predictor"))?,
        })
    }

    /// Cut `[B, C, H, W]` into `(ph, pw, c)`-ordered patch vectors `[B, hh·ww, p·p·C]`.
    pub fn patch_tokens(&self, features: &Tensor) -> Result<Tensor> {
        let (b, c, h, w) = features.dims4()?;
        let p = self.cfg.patch_size;
        let (hh, ww) = (h / p, w / p);
        features
            .reshape((b, c, hh, p, ww, p))?
            .permute((0, 2, 4, 3, 5, 1))?
            .reshape((b, hh * ww, p * p * c))
    }

    /// Feature map `[B, C, H, W]` (H, W multiples of `patch_size`) → (rgb `[B,3,H,W]`,
    /// mask `[B,1,H,W]`), both in [0, 1].
    pub fn forward(&self, features: &Tensor) -> Result<(Tensor, Tensor)> {
        let dims = features.dims().to_vec();
        let p = self.cfg.patch_size;
        let ok = dims.len() == 4
            && dims[1] == self.cfg.in_channels
            && dims[2] % p == 0
            && dims[3] % p == 0
            && dims[2] > 0
            && dims[3] > 0;
        if !ok {
            return Err(candle_core::Error::wrap(DptError::BadInput {
                dims,
                channels: self.cfg.in_channels,
                patch: p,
            }));
        }
        let (h, w) = (dims[2], dims[3]);
        let tokens = self.patchify.forward(&self.patch_tokens(features)?)?;
        let d = self.cfg.head_dim();
        let groups = (0..4)
            .map(|i| tokens.narrow(D::Minus1, i * d, d)?.contiguous())
            .collect::<Result<Vec<_>>>()?;
        let logits = self.head.forward(&groups, h / p, w / p, (h, w))?;
        let out = candle_nn::ops::sigmoid(&logits.to_dtype(DType::F32)?)?;
        Ok((out.narrow(1, 0, 3)?, out.narrow(1, 3, 1)?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_nn::VarMap;

    fn renderer() -> Result<NeuralRenderer> {
        let vm = VarMap::new();
        let vb = VarBuilder::from_varmap(&vm, DType::F32, &Device::Cpu);
        NeuralRenderer::new(&DptConfig::tiny(), vb.pp("neural_renderer"))
    }

    #[test]
    fn renders_rgb_and_mask_of_the_input_size_in_unit_range() -> Result<()> {
        let r = renderer()?;
        let feats = Tensor::randn(0f32, 1.0, (2, 32, 35, 21), &Device::Cpu)?;
        let (rgb, mask) = r.forward(&feats)?;
        assert_eq!(rgb.dims(), &[2, 3, 35, 21]);
        assert_eq!(mask.dims(), &[2, 1, 35, 21]);
        for t in [&rgb, &mask] {
            let v = t.flatten_all()?.to_vec1::<f32>()?;
            assert!(v.iter().all(|x| (0.0..=1.0).contains(x)));
            // not a constant image: the features reach the output
            let (lo, hi) = v
                .iter()
                .fold((1f32, 0f32), |(l, h), &x| (l.min(x), h.max(x)));
            assert!(hi - lo > 1e-4, "flat output {lo}..{hi}");
        }
        let (rgb2, mask2) = r.forward(&feats)?;
        let d = (rgb - rgb2)?
            .abs()?
            .flatten_all()?
            .max(0)?
            .to_scalar::<f32>()?
            + (mask - mask2)?
                .abs()?
                .flatten_all()?
                .max(0)?
                .to_scalar::<f32>()?;
        assert_eq!(d, 0.0, "two runs differ");
        Ok(())
    }

    #[test]
    fn rejects_sizes_that_are_not_patch_multiples() -> Result<()> {
        let r = renderer()?;
        let bad = Tensor::zeros((1, 32, 20, 21), DType::F32, &Device::Cpu)?;
        let err = r.forward(&bad).unwrap_err().to_string();
        assert!(err.contains("multiples of 7"), "{err}");
        let wrong_c = Tensor::zeros((1, 8, 21, 21), DType::F32, &Device::Cpu)?;
        assert!(r.forward(&wrong_c).is_err());
        Ok(())
    }

    #[test]
    fn patch_tokens_are_ordered_row_column_channel() -> Result<()> {
        let r = renderer()?;
        // value = c * 10000 + y * 100 + x, so each token entry names its source pixel
        let (c, h, w) = (32usize, 14usize, 7usize);
        let data: Vec<f32> = (0..c * h * w)
            .map(|i| {
                let (ci, y, x) = (i / (h * w), (i / w) % h, i % w);
                (ci * 10000 + y * 100 + x) as f32
            })
            .collect();
        let t = Tensor::from_vec(data, (1, c, h, w), &Device::Cpu)?;
        let tok = r.patch_tokens(&t)?;
        assert_eq!(tok.dims(), &[1, 2, 7 * 7 * 32]);
        let second = tok.get(0)?.get(1)?.to_vec1::<f32>()?;
        // second patch starts at row 7; entry (ph=1, pw=2, c=3)
        let at = (7 + 2) * 32 + 3;
        assert_eq!(second[at], (3 * 10000 + 8 * 100 + 2) as f32);
        Ok(())
    }

    #[test]
    fn uv_embedding_is_sin_zero_cos_one_at_the_centre() -> Result<()> {
        let pe = uv_position_embedding(8, 1, 1, 0.6, 0.1, &Device::Cpu)?;
        let v = pe.flatten_all()?.to_vec1::<f32>()?;
        // x half: sin(0) x2, cos(0) x2; y half the same; times 0.1
        assert_eq!(v, vec![0.0, 0.0, 0.1, 0.1, 0.0, 0.0, 0.1, 0.1]);
        let pe = uv_position_embedding(4, 2, 3, 1.5, 1.0, &Device::Cpu)?;
        // x of the first column: -span_x * (w-1)/w with span_x = 1.5 / sqrt(1.5² + 1)
        let x0 = -(1.5 / (1.5f64 * 1.5 + 1.0).sqrt()) * 2.0 / 3.0;
        let got = pe.get(0)?.get(0)?.get(0)?.get(0)?.to_scalar::<f32>()?;
        assert!((got as f64 - x0.sin()).abs() < 1e-6);
        Ok(())
    }

    #[test]
    fn bilinear_resize_aligns_corners() -> Result<()> {
        let t = Tensor::new(&[[[[0f32, 2.0], [4.0, 6.0]]]], &Device::Cpu)?;
        let u = t
            .upsample_bilinear2d(3, 3, true)?
            .flatten_all()?
            .to_vec1::<f32>()?;
        assert_eq!(u, vec![0.0, 1.0, 2.0, 2.0, 3.0, 4.0, 4.0, 5.0, 6.0]);
        Ok(())
    }
}
