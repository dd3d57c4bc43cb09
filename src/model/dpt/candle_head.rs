//! The DPT head on stock candle ops (NCHW convolutions): any device and dtype, and the
//! reference the channels-last CPU head ([`super::cpu_head`]) is checked against.

use candle_core::{Module, Result, Tensor};
use candle_nn::{
    conv2d, conv2d_no_bias, conv_transpose2d, Conv2d, Conv2dConfig, ConvTranspose2d,
    ConvTranspose2dConfig, VarBuilder,
};

use super::{pixel_shuffle, uv_position_embedding, Clock, DptConfig};
use crate::kernels::layer_norm::{layer_norm, LayerNorm};

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

/// DPT `ResidualConvUnit`: `conv2(relu(conv1(relu(x)))) + relu(x)` — the official ReLU is in
/// place, so the skip adds the rectified input.
#[derive(Debug, Clone)]
pub(super) struct ResidualConvUnit {
    pub(super) conv1: Conv2d,
    pub(super) conv2: Conv2d,
}

impl ResidualConvUnit {
    pub(super) fn new(features: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            conv1: conv3x3(features, features, vb.pp("conv1"))?,
            conv2: conv3x3(features, features, vb.pp("conv2"))?,
        })
    }

    pub(super) fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let x = x.relu()?;
        let out = self.conv2.forward(&self.conv1.forward(&x)?.relu()?)?;
        out + x
    }
}

/// DPT `FeatureFusionBlock` (`scratch.refinenet{i}`).
#[derive(Debug, Clone)]
pub(super) struct FusionBlock {
    pub(super) res1: Option<ResidualConvUnit>,
    pub(super) res2: ResidualConvUnit,
    pub(super) out_conv: Conv2d,
}

impl FusionBlock {
    pub(super) fn new(features: usize, has_residual: bool, vb: VarBuilder) -> Result<Self> {
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
    pub(super) fn forward(
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
pub(super) enum Resize {
    Up(ConvTranspose2d),
    Identity,
    Down(Conv2d),
}

impl Resize {
    pub(super) fn forward(&self, x: &Tensor) -> Result<Tensor> {
        match self {
            Resize::Up(c) => c.forward(x),
            Resize::Identity => Ok(x.clone()),
            Resize::Down(c) => c.forward(x),
        }
    }
}

/// What follows the shared `refinenet4 → refinenet3 → refinenet2` trunk of the head.
#[derive(Debug, Clone)]
pub(super) enum HeadTail {
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

/// The VGGT-style `DPTHead` (`neural_renderer.dense_predictor`), output_dim 4, or its
/// `MLPPixelShuffleDPTHead` variant (same front and first three fusion blocks).
#[derive(Debug, Clone)]
pub(super) struct DptHead {
    pub(super) norm: LayerNorm,
    pub(super) projects: Vec<Conv2d>,
    pub(super) resize: Vec<Resize>,
    pub(super) layer_rn: Vec<Conv2d>,
    /// `refinenet4`, `refinenet3`, `refinenet2`, in the order they run.
    pub(super) trunk: Vec<FusionBlock>,
    pub(super) tail: HeadTail,
}

impl DptHead {
    pub(super) fn new(cfg: &DptConfig, vb: VarBuilder) -> Result<Self> {
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
    pub(super) fn forward(
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
