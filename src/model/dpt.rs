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
//!
//! The GS-supervised LHMPP-700M-PixelShuffle (`neural_renderer.type: mlp_pixelshuffle`,
//! `PatchMLPPixelShuffleDPT4DecoderOnly` with `MLPPixelShuffleDPTHead`) keeps the same front and
//! `refinenet4..2`, then replaces `refinenet1` and the output convolutions with
//! `refinenet2(..) + l1_residual_fuse(layer1_rn)` (1×1), `refinenet1_ps_mlp` (1×1 to 4·u²),
//! `pixel_shuffle(u)` (u = `pixel_shuffle_factor`, 2), bilinear (`align_corners=True`) to (H, W)
//! and sigmoid: no position embedding after the fusion ([`DptConfig::pixel_shuffle`]).
//!
//! With f32 weights and input on the CPU the head runs channels-last on the packed kernels of
//! [`super::ops`] (the token rows already are NHWC): 3×3 convolutions by Winograd F(4×4, 3×3)
//! or im2col + gemm with the bias, ReLUs and residual adds in their epilogues, the stride-sized
//! transposed convolutions as one gemm + scatter, each fusion block's 1×1 `out_conv` before its
//! (commuting) bilinear resize, and the sigmoid before a single NCHW copy at the end. Other
//! devices and dtypes, and [`NeuralRenderer::with_candle_ops`], run the stock candle ops.

use std::time::{Duration, Instant};

use candle_core::{DType, Device, Module, Result, Tensor, D};
use candle_nn::{
    conv2d, conv2d_no_bias, conv_transpose2d, Conv2d, Conv2dConfig, ConvTranspose2d,
    ConvTranspose2dConfig, VarBuilder,
};
use rayon::prelude::*;

use super::ops::conv2d::{Epilogue, PackedConv2d};
use super::ops::conv_transpose::PackedConvTranspose2d;
use super::ops::feature_map::FeatureMap;
use super::ops::layer_norm::{layer_norm, LayerNorm};
use super::ops::linear::{linear_no_bias, Linear};
use super::ops::upsample::upsample_bilinear;

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
    /// `Some(u)`: the `MLPPixelShuffleDPTHead` of `neural_renderer.type: mlp_pixelshuffle`
    /// (`pixel_shuffle_factor` u, 2 in the release) instead of the DPT head's last fusion block
    /// and output convolutions; `None`: the DPT head (`patch_4dptonly`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pixel_shuffle: Option<usize>,
    /// `true`: the four DPT inputs are the whole `embed_dim`-wide tokens, four times
    /// (`PatchDPTDecoderOnly` of LHMPPS-700M, `neural_renderer.type: patch_dptonly`, depth 1:
    /// `DPTHead(dim_in=1024, intermediate_layer_idx=[0, 0, 0, 0])`); `false`: four
    /// `embed_dim / 4` channel groups (`PatchDPT4DecoderOnly`).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub shared_tokens: bool,
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
            pixel_shuffle: None,
            shared_tokens: false,
        }
    }

    /// The neural renderer of the released LHMPP-700M-PixelShuffle (`mlp_pixelshuffle`,
    /// `pixel_shuffle_factor: 2`).
    pub fn lhmpp_700m_pixelshuffle() -> Self {
        Self {
            pixel_shuffle: Some(2),
            ..Self::lhmpp_700m()
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
            pixel_shuffle: None,
            shared_tokens: false,
        }
    }

    /// Size of each of the four token groups the head reads.
    pub fn head_dim(&self) -> usize {
        if self.shared_tokens {
            self.embed_dim
        } else {
            self.embed_dim / 4
        }
    }

    /// The four inputs of the head from the patchified tokens `[B, N, embed_dim]`.
    fn token_groups(&self, tokens: &Tensor) -> Result<Vec<Tensor>> {
        let d = self.head_dim();
        (0..4)
            .map(|i| match self.shared_tokens {
                true => Ok(tokens.clone()),
                false => tokens.narrow(D::Minus1, i * d, d)?.contiguous(),
            })
            .collect()
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

/// The two halves of VGGT's UV position embedding × `ratio`: per column the `channels / 2`
/// x-channels and per row the `channels / 2` y-channels (pixel (y, x) gets `column[x] ++ row[y]`).
/// UV spans are normalised by the image diagonal (`aspect = W / H` of the full image).
pub fn uv_embedding_tables(
    channels: usize,
    h: usize,
    w: usize,
    aspect: f64,
    ratio: f64,
) -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
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
    (encode(lin(w, span_x)), encode(lin(h, span_y)))
}

/// VGGT's `create_uv_grid` + `position_grid_to_embed` × `ratio` as `[1, C, h, w]`
/// (see [`uv_embedding_tables`]).
pub fn uv_position_embedding(
    channels: usize,
    h: usize,
    w: usize,
    aspect: f64,
    ratio: f64,
    device: &Device,
) -> Result<Tensor> {
    let (xe, ye) = uv_embedding_tables(channels, h, w, aspect, ratio);
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

/// Wall-clock time of each stage of one neural-renderer forward, in order of first use
/// (repeated stages, such as the four fusion blocks' units, add up under one name).
#[derive(Debug, Default, Clone)]
pub struct StageTimes {
    /// `(stage, time)` pairs.
    pub stages: Vec<(&'static str, Duration)>,
}

impl StageTimes {
    fn add(&mut self, name: &'static str, d: Duration) {
        match self.stages.iter_mut().find(|(n, _)| *n == name) {
            Some((_, t)) => *t += d,
            None => self.stages.push((name, d)),
        }
    }
}

/// Laps the stages of one forward into an optional [`StageTimes`].
struct Clock<'a> {
    times: Option<&'a mut StageTimes>,
    last: Instant,
}

impl Clock<'_> {
    /// Charges the time since the previous lap to `name`.
    fn lap(&mut self, name: &'static str) {
        if let Some(t) = self.times.as_deref_mut() {
            let now = Instant::now();
            t.add(name, now - self.last);
            self.last = now;
        }
    }
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
        clock: &mut Clock,
    ) -> Result<Tensor> {
        let mut out = x.clone();
        if let (Some(res1), Some(skip)) = (&self.res1, skip) {
            out = (out + res1.forward(skip)?)?;
        }
        let out = self.res2.forward(&out)?;
        clock.lap("fusion residual units");
        let (_, _, h, w) = out.dims4()?;
        let (th, tw) = size.unwrap_or((2 * h, 2 * w));
        let up = out.upsample_bilinear2d(th, tw, true)?;
        clock.lap("fusion upsample");
        let out = self.out_conv.forward(&up)?;
        clock.lap("fusion out_conv");
        Ok(out)
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

/// What follows the shared `refinenet4 → refinenet3 → refinenet2` trunk of the head.
#[derive(Debug, Clone)]
enum HeadTail {
    /// `DPTHead`: `refinenet1` (×2 upsample), `output_conv1`, bilinear to (H, W), position
    /// embedding, `output_conv2` (3×3, ReLU, 1×1 to 4).
    Dpt {
        refine1: Box<FusionBlock>,
        output_conv1: Conv2d,
        output_conv2a: Conv2d,
        output_conv2b: Conv2d,
    },
    /// `MLPPixelShuffleDPTHead`: `+ l1_residual_fuse(layer1_rn)` (1×1), `refinenet1_ps_mlp`
    /// (1×1 to 4·u²), `pixel_shuffle(u)`, bilinear to (H, W); no position embedding.
    PixelShuffle {
        l1_residual_fuse: Conv2d,
        ps_mlp: Conv2d,
        factor: usize,
    },
}

/// `F.pixel_shuffle(x, u)`: `[B, C·u², H, W]` → `[B, C, H·u, W·u]`, with
/// `out[c, y·u + i, x·u + j] = in[c·u² + i·u + j, y, x]`.
pub fn pixel_shuffle(x: &Tensor, u: usize) -> Result<Tensor> {
    let (b, cu, h, w) = x.dims4()?;
    if u == 0 || cu % (u * u) != 0 {
        candle_core::bail!("pixel_shuffle: {cu} channels are not a multiple of {u}²");
    }
    let c = cu / (u * u);
    x.reshape((b, c, u, u, h, w))?
        .permute((0, 1, 4, 2, 5, 3))?
        .reshape((b, c, h * u, w * u))
}

/// [`pixel_shuffle`] on a channels-last map.
fn pixel_shuffle_nhwc(x: &FeatureMap, u: usize) -> Result<FeatureMap> {
    if u == 0 || x.channels % (u * u) != 0 {
        candle_core::bail!(
            "pixel_shuffle: {} channels are not a multiple of {u}²",
            x.channels
        );
    }
    let c = x.channels / (u * u);
    let (h, w) = (x.height * u, x.width * u);
    let mut out = FeatureMap::zeros(x.batch, h, w, c);
    out.data
        .par_chunks_mut(w * c)
        .enumerate()
        .for_each(|(row, dst)| {
            let (bi, oy) = (row / h, row % h);
            let (y, i) = (oy / u, oy % u);
            for ox in 0..w {
                let (xx, j) = (ox / u, ox % u);
                let src = &x.data[((bi * x.height + y) * x.width + xx) * x.channels..];
                for (ci, v) in dst[ox * c..(ox + 1) * c].iter_mut().enumerate() {
                    *v = src[ci * u * u + i * u + j];
                }
            }
        });
    Ok(out)
}

/// The VGGT-style `DPTHead` (`neural_renderer.dense_predictor`), output_dim 4, or its
/// `MLPPixelShuffleDPTHead` variant (same front and first three fusion blocks).
#[derive(Debug, Clone)]
struct DptHead {
    norm: LayerNorm,
    projects: Vec<Conv2d>,
    resize: Vec<Resize>,
    layer_rn: Vec<Conv2d>,
    /// `refinenet4`, `refinenet3`, `refinenet2`, in the order they run.
    trunk: Vec<FusionBlock>,
    tail: HeadTail,
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
        let trunk = [4usize, 3, 2]
            .into_iter()
            .map(|i| FusionBlock::new(f, i != 4, scratch.pp(format!("refinenet{i}"))))
            .collect::<Result<Vec<_>>>()?;
        let tail = match cfg.pixel_shuffle {
            None => {
                let oc2 = scratch.pp("output_conv2");
                HeadTail::Dpt {
                    refine1: Box::new(FusionBlock::new(f, true, scratch.pp("refinenet1"))?),
                    output_conv1: conv3x3(f, f / 2, scratch.pp("output_conv1"))?,
                    output_conv2a: conv3x3(f / 2, 32, oc2.pp("0"))?,
                    output_conv2b: conv1x1(32, 4, oc2.pp("2"))?,
                }
            }
            Some(u) => HeadTail::PixelShuffle {
                l1_residual_fuse: conv1x1(f, f, vb.pp("l1_residual_fuse"))?,
                ps_mlp: conv1x1(f, 4 * u * u, vb.pp("refinenet1_ps_mlp"))?,
                factor: u,
            },
        };
        Ok(Self {
            norm: layer_norm(dim_in, 1e-5, vb.pp("norm"))?,
            projects,
            resize,
            layer_rn,
            trunk,
            tail,
        })
    }

    /// Four token groups `[B, hh·ww, dim_in]` → logits `[B, 4, H, W]` for an image of (H, W).
    fn forward(
        &self,
        groups: &[Tensor],
        hh: usize,
        ww: usize,
        image: (usize, usize),
        clock: &mut Clock,
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
        clock.lap("norm, projects, resize");
        let rn = feats
            .iter()
            .zip(&self.layer_rn)
            .map(|(f, c)| c.forward(f))
            .collect::<Result<Vec<_>>>()?;
        clock.lap("layer_rn");
        let size = |t: &Tensor| -> Result<(usize, usize)> {
            let (_, _, h, w) = t.dims4()?;
            Ok((h, w))
        };
        let out = self.trunk[0].forward(&rn[3], None, Some(size(&rn[2])?), clock)?;
        let out = self.trunk[1].forward(&out, Some(&rn[2]), Some(size(&rn[1])?), clock)?;
        let out = self.trunk[2].forward(&out, Some(&rn[1]), Some(size(&rn[0])?), clock)?;
        match &self.tail {
            HeadTail::Dpt {
                refine1,
                output_conv1,
                output_conv2a,
                output_conv2b,
            } => {
                let out = refine1.forward(&out, Some(&rn[0]), None, clock)?;
                let out = output_conv1.forward(&out)?;
                clock.lap("output_conv1");
                let out = out.upsample_bilinear2d(h_img, w_img, true)?;
                let pe = uv_position_embedding(out.dim(1)?, h_img, w_img, aspect, 0.1, device)?;
                let out = out.broadcast_add(&pe.to_dtype(out.dtype())?)?;
                clock.lap("full-size upsample + position");
                let out = output_conv2b.forward(&output_conv2a.forward(&out)?.relu()?)?;
                clock.lap("output_conv2");
                Ok(out)
            }
            HeadTail::PixelShuffle {
                l1_residual_fuse,
                ps_mlp,
                factor,
            } => {
                let out = (out + l1_residual_fuse.forward(&rn[0])?)?;
                let out = pixel_shuffle(&ps_mlp.forward(&out)?, *factor)?;
                clock.lap("pixel-shuffle tail");
                let out = out.upsample_bilinear2d(h_img, w_img, true)?;
                clock.lap("full-size upsample");
                Ok(out)
            }
        }
    }
}

/// `conv2(relu(conv1(relu(x)))) + relu(x)` packed for the channels-last CPU kernels.
#[derive(Debug, Clone)]
struct CpuResidualUnit {
    conv1: PackedConv2d,
    conv2: PackedConv2d,
}

impl CpuResidualUnit {
    fn new(unit: &ResidualConvUnit) -> Result<Self> {
        Ok(Self {
            conv1: PackedConv2d::from_candle(&unit.conv1)?,
            conv2: PackedConv2d::from_candle(&unit.conv2)?,
        })
    }

    /// The unit on `x` (consumed: its ReLU is the skip), plus `extra` if given; the bias, ReLUs
    /// and both additions ride in the convolutions' epilogues.
    fn forward(&self, mut x: FeatureMap, extra: Option<&FeatureMap>) -> Result<FeatureMap> {
        x.relu_in_place();
        let hidden = self.conv1.forward(
            &x,
            Epilogue {
                residual: None,
                relu: true,
            },
        )?;
        if let Some(e) = extra {
            x.add_assign(e)?;
        }
        self.conv2.forward(
            &hidden,
            Epilogue {
                residual: Some(&x),
                relu: false,
            },
        )
    }
}

/// A fusion block packed for the CPU kernels.
#[derive(Debug, Clone)]
struct CpuFusion {
    res1: Option<CpuResidualUnit>,
    res2: CpuResidualUnit,
    out_conv: PackedConv2d,
}

impl CpuFusion {
    fn new(block: &FusionBlock) -> Result<Self> {
        Ok(Self {
            res1: block.res1.as_ref().map(CpuResidualUnit::new).transpose()?,
            res2: CpuResidualUnit::new(&block.res2)?,
            out_conv: PackedConv2d::from_candle(&block.out_conv)?,
        })
    }

    /// As [`FusionBlock::forward`]. The 1×1 `out_conv` and the bilinear resize commute (the
    /// interpolation weights sum to one), so the convolution runs on the smaller of the two maps.
    fn forward(
        &self,
        x: FeatureMap,
        skip: Option<FeatureMap>,
        size: Option<(usize, usize)>,
        clock: &mut Clock,
    ) -> Result<FeatureMap> {
        let x = match (&self.res1, skip) {
            (Some(res1), Some(skip)) => res1.forward(skip, Some(&x))?,
            _ => x,
        };
        let out = self.res2.forward(x, None)?;
        clock.lap("fusion residual units");
        let (th, tw) = size.unwrap_or((2 * out.height, 2 * out.width));
        if th * tw >= out.height * out.width {
            let out = self.out_conv.forward(&out, Epilogue::default())?;
            clock.lap("fusion out_conv");
            let up = upsample_bilinear(&out, th, tw)?;
            clock.lap("fusion upsample");
            Ok(up)
        } else {
            let up = upsample_bilinear(&out, th, tw)?;
            clock.lap("fusion upsample");
            let out = self.out_conv.forward(&up, Epilogue::default())?;
            clock.lap("fusion out_conv");
            Ok(out)
        }
    }
}

/// The resize layer of one DPT input, packed for the CPU kernels.
#[derive(Debug, Clone)]
enum CpuResize {
    Up(PackedConvTranspose2d),
    Identity,
    Down(PackedConv2d),
}

/// [`HeadTail`] packed for the CPU kernels.
#[derive(Debug, Clone)]
enum CpuTail {
    Dpt {
        refine1: Box<CpuFusion>,
        output_conv1: PackedConv2d,
        output_conv2a: PackedConv2d,
        output_conv2b: PackedConv2d,
    },
    PixelShuffle {
        l1_residual_fuse: PackedConv2d,
        ps_mlp: PackedConv2d,
        factor: usize,
    },
}

/// The DPT head packed once for the channels-last f32 CPU kernels (used when the head's
/// input is f32 on the CPU).
#[derive(Debug, Clone)]
struct CpuHead {
    projects: Vec<PackedConv2d>,
    resize: Vec<CpuResize>,
    layer_rn: Vec<PackedConv2d>,
    trunk: Vec<CpuFusion>,
    tail: CpuTail,
}

impl CpuHead {
    fn new(head: &DptHead) -> Result<Self> {
        let packed = |convs: &[Conv2d]| -> Result<Vec<PackedConv2d>> {
            convs.iter().map(PackedConv2d::from_candle).collect()
        };
        Ok(Self {
            projects: packed(&head.projects)?,
            resize: head
                .resize
                .iter()
                .map(|r| {
                    Ok(match r {
                        Resize::Up(c) => CpuResize::Up(PackedConvTranspose2d::from_candle(c)?),
                        Resize::Identity => CpuResize::Identity,
                        Resize::Down(c) => CpuResize::Down(PackedConv2d::from_candle(c)?),
                    })
                })
                .collect::<Result<Vec<_>>>()?,
            layer_rn: packed(&head.layer_rn)?,
            trunk: head
                .trunk
                .iter()
                .map(CpuFusion::new)
                .collect::<Result<Vec<_>>>()?,
            tail: match &head.tail {
                HeadTail::Dpt {
                    refine1,
                    output_conv1,
                    output_conv2a,
                    output_conv2b,
                } => CpuTail::Dpt {
                    refine1: Box::new(CpuFusion::new(refine1)?),
                    output_conv1: PackedConv2d::from_candle(output_conv1)?,
                    output_conv2a: PackedConv2d::from_candle(output_conv2a)?,
                    output_conv2b: PackedConv2d::from_candle(output_conv2b)?,
                },
                HeadTail::PixelShuffle {
                    l1_residual_fuse,
                    ps_mlp,
                    factor,
                } => CpuTail::PixelShuffle {
                    l1_residual_fuse: PackedConv2d::from_candle(l1_residual_fuse)?,
                    ps_mlp: PackedConv2d::from_candle(ps_mlp)?,
                    factor: *factor,
                },
            },
        })
    }

    /// [`DptHead::forward`] + sigmoid on channels-last maps → (rgb, mask); `norm` is the head's LayerNorm (candle's
    /// fused CPU op on the token rows, which already are channels-last).
    fn forward(
        &self,
        norm: &LayerNorm,
        groups: &[Tensor],
        hh: usize,
        ww: usize,
        image: (usize, usize),
        clock: &mut Clock,
    ) -> Result<(Tensor, Tensor)> {
        let (h_img, w_img) = image;
        let aspect = w_img as f64 / h_img as f64;
        let none = Epilogue::default();
        let mut rn = Vec::with_capacity(4);
        for (i, g) in groups.iter().enumerate() {
            let x = FeatureMap::from_tokens(&norm.forward(g)?, hh, ww)?;
            let mut x = self.projects[i].forward(&x, none)?;
            let (columns, rows) = uv_embedding_tables(x.channels, hh, ww, aspect, 0.1);
            x.add_separable(&columns, &rows)?;
            let x = match &self.resize[i] {
                CpuResize::Up(c) => c.forward(&x)?,
                CpuResize::Identity => x,
                CpuResize::Down(c) => c.forward(&x, none)?,
            };
            clock.lap("norm, projects, resize");
            rn.push(self.layer_rn[i].forward(&x, none)?);
            clock.lap("layer_rn");
        }
        let side = |m: &FeatureMap| Some((m.height, m.width));
        let (s0, s1, s2) = (side(&rn[0]), side(&rn[1]), side(&rn[2]));
        let mut rn = rn.into_iter().map(Some).collect::<Vec<_>>();
        let mut take = |i: usize| {
            rn[i]
                .take()
                .ok_or_else(|| candle_core::Error::Msg(format!("dpt: layer {i} used twice")))
        };
        let out = self.trunk[0].forward(take(3)?, None, s2, clock)?;
        let out = self.trunk[1].forward(out, Some(take(2)?), s1, clock)?;
        let out = self.trunk[2].forward(out, Some(take(1)?), s0, clock)?;
        let mut out = match &self.tail {
            CpuTail::Dpt {
                refine1,
                output_conv1,
                output_conv2a,
                output_conv2b,
            } => {
                let out = refine1.forward(out, Some(take(0)?), None, clock)?;
                let out = output_conv1.forward(&out, none)?;
                clock.lap("output_conv1");
                let mut out = upsample_bilinear(&out, h_img, w_img)?;
                let (columns, rows) = uv_embedding_tables(out.channels, h_img, w_img, aspect, 0.1);
                out.add_separable(&columns, &rows)?;
                clock.lap("full-size upsample + position");
                let hidden = output_conv2a.forward(
                    &out,
                    Epilogue {
                        residual: None,
                        relu: true,
                    },
                )?;
                let out = output_conv2b.forward(&hidden, none)?;
                clock.lap("output_conv2");
                out
            }
            CpuTail::PixelShuffle {
                l1_residual_fuse,
                ps_mlp,
                factor,
            } => {
                let fused = l1_residual_fuse.forward(
                    &take(0)?,
                    Epilogue {
                        residual: Some(&out),
                        relu: false,
                    },
                )?;
                let out = pixel_shuffle_nhwc(&ps_mlp.forward(&fused, none)?, *factor)?;
                clock.lap("pixel-shuffle tail");
                let out = upsample_bilinear(&out, h_img, w_img)?;
                clock.lap("full-size upsample");
                out
            }
        };
        out.sigmoid_in_place();
        let out = out.to_nchw(groups[0].device())?;
        let rgb_mask = (out.narrow(1, 0, 3)?, out.narrow(1, 3, 1)?);
        clock.lap("sigmoid, to NCHW");
        Ok(rgb_mask)
    }
}

/// The neural renderer (`neural_renderer`): patchify + DPT head.
#[derive(Debug, Clone)]
pub struct NeuralRenderer {
    cfg: DptConfig,
    patchify: Linear,
    head: DptHead,
    /// The head packed for the channels-last CPU kernels (f32 CPU weights only).
    cpu_head: Option<CpuHead>,
    /// `patchify` with its input columns reordered `(c, ph, pw)`, for the CPU path's
    /// channel-major patch gather ([`channel_major_patches`]).
    cpu_patchify: Option<Linear>,
}

/// Cuts a channels-last `[B, H, W, C]` f32 map (such as the rasteriser's feature image) into
/// `[B·hh·ww, p·p·C]` patch rows ordered `(ph, pw, c)`, the order of
/// [`NeuralRenderer::patch_tokens`]: each patch row is `p` copies of `p·C` contiguous values.
fn channels_last_patches(data: &[f32], dims: (usize, usize, usize, usize), p: usize) -> Vec<f32> {
    let (b, h, w, c) = dims;
    let (hh, ww) = (h / p, w / p);
    let row = p * p * c;
    let mut out = vec![0f32; b * hh * ww * row];
    if out.is_empty() {
        return out;
    }
    out.par_chunks_mut(ww * row)
        .enumerate()
        .for_each(|(band, dst)| {
            let (bi, y) = (band / hh, band % hh);
            for (x, token) in dst.chunks_exact_mut(row).enumerate() {
                for (ph, run) in token.chunks_exact_mut(p * c).enumerate() {
                    let at = ((bi * h + y * p + ph) * w + x * p) * c;
                    run.copy_from_slice(&data[at..at + p * c]);
                }
            }
        });
    out
}

/// Cuts a contiguous `[B, C, H, W]` f32 map into `[B·hh·ww, C·p·p]` patch rows ordered
/// `(c, ph, pw)`: every `p` values come from one image row, so the gather is a copy of short
/// runs (the `(ph, pw, c)` order of [`NeuralRenderer::patch_tokens`] needs one strided read per
/// value). Patch rows of one `hh` band run in parallel.
fn channel_major_patches(data: &[f32], dims: (usize, usize, usize, usize), p: usize) -> Vec<f32> {
    let (b, c, h, w) = dims;
    let (hh, ww) = (h / p, w / p);
    let row = c * p * p;
    let mut out = vec![0f32; b * hh * ww * row];
    if out.is_empty() {
        return out;
    }
    out.par_chunks_mut(ww * row)
        .enumerate()
        .for_each(|(band, dst)| {
            let (bi, y) = (band / hh, band % hh);
            // one image row at a time (sequential reads), its p-runs dealt to the ww tokens
            for ci in 0..c {
                let plane = &data[(bi * c + ci) * h * w..(bi * c + ci + 1) * h * w];
                for ph in 0..p {
                    let line = &plane[(y * p + ph) * w..(y * p + ph) * w + ww * p];
                    let at = (ci * p + ph) * p;
                    for (token, run) in dst.chunks_exact_mut(row).zip(line.chunks_exact(p)) {
                        token[at..at + p].copy_from_slice(run);
                    }
                }
            }
        });
    out
}

impl NeuralRenderer {
    /// Build from `vb = root.pp("neural_renderer")`.
    pub fn new(cfg: &DptConfig, vb: VarBuilder) -> Result<Self> {
        let p = cfg.patch_size;
        let head = DptHead::new(cfg, vb.pp("dense_predictor"))?;
        let w = head.layer_rn[0].weight();
        let cpu_head = if w.device().is_cpu() && w.dtype() == DType::F32 {
            Some(CpuHead::new(&head)?)
        } else {
            None
        };
        let patchify = linear_no_bias(
            p * p * cfg.in_channels,
            cfg.embed_dim,
            vb.pp("patchify").pp("1"),
        )?;
        let cpu_patchify = match &cpu_head {
            Some(_) => {
                let w = patchify
                    .weight()
                    .reshape((cfg.embed_dim, p, p, cfg.in_channels))?
                    .permute((0, 3, 1, 2))?
                    .reshape((cfg.embed_dim, p * p * cfg.in_channels))?;
                Some(Linear::new(w, None))
            }
            None => None,
        };
        Ok(Self {
            cfg: cfg.clone(),
            patchify,
            head,
            cpu_head,
            cpu_patchify,
        })
    }

    /// The config this renderer was built for.
    pub fn config(&self) -> &DptConfig {
        &self.cfg
    }

    /// The same renderer running its head on stock candle ops only (NCHW convolutions), the
    /// reference the channels-last CPU kernels are checked and benchmarked against.
    pub fn with_candle_ops(mut self) -> Self {
        self.cpu_head = None;
        self.cpu_patchify = None;
        self
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
        self.forward_inner(features, None)
    }

    /// [`Self::forward`], adding the wall-clock time of each stage to `times`.
    pub fn forward_timed(
        &self,
        features: &Tensor,
        times: &mut StageTimes,
    ) -> Result<(Tensor, Tensor)> {
        self.forward_inner(features, Some(times))
    }

    fn forward_inner(
        &self,
        features: &Tensor,
        times: Option<&mut StageTimes>,
    ) -> Result<(Tensor, Tensor)> {
        let mut clock = Clock {
            times,
            last: Instant::now(),
        };
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
        let (hh, ww) = (h / p, w / p);
        let cpu = features.device().is_cpu() && features.dtype() == DType::F32;
        if let (Some(head), Some(patchify), true) = (&self.cpu_head, &self.cpu_patchify, cpu) {
            // A channels-last map viewed as [B, C, H, W] (the rasteriser's features permuted)
            // is gathered in place in the weight's own (ph, pw, c) order; anything else is made
            // contiguous NCHW and gathered channel-major for the column-permuted weight.
            let nhwc = features.permute((0, 2, 3, 1))?;
            let channels_last = nhwc.is_contiguous();
            let source = if channels_last {
                nhwc
            } else {
                features.contiguous()?
            };
            let rows = {
                let (guard, layout) = source.storage_and_layout();
                let candle_core::Storage::Cpu(storage) = &*guard else {
                    candle_core::bail!("neural renderer: CPU tensor without CPU storage");
                };
                let data =
                    super::ops::contiguous_f32(storage, layout, "neural renderer", "features")?;
                if channels_last {
                    channels_last_patches(data, (dims[0], h, w, dims[1]), p)
                } else {
                    channel_major_patches(data, (dims[0], dims[1], h, w), p)
                }
            };
            let rows = Tensor::from_vec(rows, (dims[0], hh * ww, p * p * dims[1]), &Device::Cpu)?;
            clock.lap("patch tokens");
            let linear = if channels_last {
                &self.patchify
            } else {
                patchify
            };
            let tokens = linear.forward(&rows)?;
            let groups = self.cfg.token_groups(&tokens)?;
            clock.lap("patchify linear");
            return head.forward(&self.head.norm, &groups, hh, ww, (h, w), &mut clock);
        }
        let patches = self.patch_tokens(features)?;
        clock.lap("patch tokens");
        let tokens = self.patchify.forward(&patches)?;
        let groups = self.cfg.token_groups(&tokens)?;
        clock.lap("patchify linear");
        let logits = self.head.forward(&groups, hh, ww, (h, w), &mut clock)?;
        let out = candle_nn::ops::sigmoid(&logits.to_dtype(DType::F32)?)?;
        let rgb_mask = (out.narrow(1, 0, 3)?, out.narrow(1, 3, 1)?);
        clock.lap("sigmoid");
        Ok(rgb_mask)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::testing::max_abs_diff;
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
    fn channels_last_cpu_kernels_match_the_candle_op_path() -> Result<()> {
        let fast = renderer()?;
        assert!(fast.cpu_head.is_some());
        let slow = fast.clone().with_candle_ops();
        for dims in [(2, 32, 35, 21), (1, 32, 49, 56), (1, 32, 7, 7)] {
            let feats = Tensor::randn(0f32, 1.0, dims, &Device::Cpu)?;
            let mut times = StageTimes::default();
            let (rgb, mask) = fast.forward_timed(&feats, &mut times)?;
            let (rgb_ref, mask_ref) = slow.forward(&feats)?;
            let d = max_abs_diff(&rgb, &rgb_ref).max(max_abs_diff(&mask, &mask_ref));
            // f32 rounding of a different summation order (Winograd, patch column order)
            assert!(d < 1e-4, "{dims:?}: {d}");
            // the same map stored channels-last (as the rasteriser emits it)
            let hwc = feats
                .permute((0, 2, 3, 1))?
                .contiguous()?
                .permute((0, 3, 1, 2))?;
            assert!(!hwc.is_contiguous());
            let (rgb_hwc, _) = fast.forward(&hwc)?;
            let d = max_abs_diff(&rgb_hwc, &rgb_ref);
            assert!(d < 1e-4, "channels-last input {dims:?}: {d}");
            let names: Vec<_> = times.stages.iter().map(|(n, _)| *n).collect();
            assert!(names.contains(&"layer_rn") && names.contains(&"fusion residual units"));
        }
        Ok(())
    }

    #[test]
    fn pixel_shuffle_moves_channel_blocks_to_pixel_blocks() -> Result<()> {
        // [1, 2·2², 2, 3]: value = channel·100 + y·10 + x
        let (c, u, h, w) = (2usize, 2usize, 2usize, 3usize);
        let data: Vec<f32> = (0..c * u * u * h * w)
            .map(|i| {
                let (ch, y, x) = (i / (h * w), (i / w) % h, i % w);
                (ch * 100 + y * 10 + x) as f32
            })
            .collect();
        let t = Tensor::from_vec(data.clone(), (1, c * u * u, h, w), &Device::Cpu)?;
        let out = pixel_shuffle(&t, u)?;
        assert_eq!(out.dims(), &[1, c, h * u, w * u]);
        // out[c=1, y=1·2+1, x=2·2+0] = in[1·4 + 1·2 + 0, 1, 2]
        let v = out.get(0)?.get(1)?.get(3)?.get(4)?.to_scalar::<f32>()?;
        assert_eq!(v, (6 * 100 + 10 + 2) as f32);
        // the channels-last version agrees everywhere
        let nhwc = FeatureMap::from_nchw(&t)?;
        let back = pixel_shuffle_nhwc(&nhwc, u)?.to_nchw(&Device::Cpu)?;
        assert_eq!(max_abs_diff(&back, &out), 0.0);
        Ok(())
    }

    #[test]
    fn pixel_shuffle_head_cpu_kernels_match_the_candle_op_path() -> Result<()> {
        let cfg = DptConfig {
            pixel_shuffle: Some(2),
            ..DptConfig::tiny()
        };
        let vb = crate::model::checkpoint::seeded_var_builder(4, DType::F32, &Device::Cpu);
        let fast = NeuralRenderer::new(&cfg, vb.pp("neural_renderer"))?;
        assert!(fast.cpu_head.is_some());
        let slow = fast.clone().with_candle_ops();
        for dims in [(1, 32, 35, 21), (2, 32, 14, 28)] {
            let feats = Tensor::randn(0f32, 1.0, dims, &Device::Cpu)?;
            let (rgb, mask) = fast.forward(&feats)?;
            let (rgb_ref, mask_ref) = slow.forward(&feats)?;
            assert_eq!(rgb.dims(), &[dims.0, 3, dims.2, dims.3]);
            assert_eq!(mask.dims(), &[dims.0, 1, dims.2, dims.3]);
            let d = max_abs_diff(&rgb, &rgb_ref).max(max_abs_diff(&mask, &mask_ref));
            assert!(d < 1e-4, "{dims:?}: {d}");
        }
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
    fn channel_major_patches_are_ordered_channel_row_column() {
        // value = c * 10000 + y * 100 + x over a [2, 3, 14, 21] map
        let (b, c, h, w) = (2usize, 3usize, 14usize, 21usize);
        let data: Vec<f32> = (0..b * c * h * w)
            .map(|i| {
                let (bi, ci, y, x) = (i / (c * h * w), (i / (h * w)) % c, (i / w) % h, i % w);
                (bi * 100000 + ci * 10000 + y * 100 + x) as f32
            })
            .collect();
        let rows = channel_major_patches(&data, (b, c, h, w), 7);
        assert_eq!(rows.len(), b * 2 * 3 * c * 49);
        // image 1, patch (1, 2) = token 5; entry (c=2, ph=3, pw=4)
        let token = &rows[(6 + 5) * c * 49..(6 + 6) * c * 49];
        assert_eq!(
            token[2 * 49 + 3 * 7 + 4],
            (100000 + 20000 + 10 * 100 + 18) as f32
        );
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
