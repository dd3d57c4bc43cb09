//! The DPT head packed once for the channels-last f32 CPU kernels of [`crate::kernels`]
//! (Winograd / im2col + gemm convolutions with fused epilogues), used when the head's weights
//! and input are f32 on the CPU; it computes what [`super::candle_head`] computes.

use candle_core::{Module, Result, Tensor};
use candle_nn::Conv2d;
use rayon::prelude::*;

use super::candle_head::{DptHead, FusionBlock, HeadTail, ResidualConvUnit, Resize};
use super::{uv_embedding_tables, Clock};
use crate::kernels::conv2d::{Epilogue, PackedConv2d};
use crate::kernels::conv_transpose::PackedConvTranspose2d;
use crate::kernels::feature_map::FeatureMap;
use crate::kernels::layer_norm::LayerNorm;
use crate::kernels::upsample::upsample_bilinear;

/// [`pixel_shuffle`] on a channels-last map.
pub(super) fn pixel_shuffle_nhwc(x: &FeatureMap, u: usize) -> Result<FeatureMap> {
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

/// `conv2(relu(conv1(relu(x)))) + relu(x)` packed for the channels-last CPU kernels.
#[derive(Debug, Clone)]
pub(super) struct CpuResidualUnit {
    conv1: PackedConv2d,
    conv2: PackedConv2d,
}

impl CpuResidualUnit {
    pub(super) fn new(unit: &ResidualConvUnit) -> Result<Self> {
        Ok(Self {
            conv1: PackedConv2d::from_candle(&unit.conv1)?,
            conv2: PackedConv2d::from_candle(&unit.conv2)?,
        })
    }

    /// The unit on `x` (consumed: its ReLU is the skip), plus `extra` if given; the bias, ReLUs
    /// and both additions ride in the convolutions' epilogues.
    pub(super) fn forward(
        &self,
        mut x: FeatureMap,
        extra: Option<&FeatureMap>,
    ) -> Result<FeatureMap> {
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
pub(super) struct CpuFusion {
    res1: Option<CpuResidualUnit>,
    res2: CpuResidualUnit,
    out_conv: PackedConv2d,
}

impl CpuFusion {
    pub(super) fn new(block: &FusionBlock) -> Result<Self> {
        Ok(Self {
            res1: block.res1.as_ref().map(CpuResidualUnit::new).transpose()?,
            res2: CpuResidualUnit::new(&block.res2)?,
            out_conv: PackedConv2d::from_candle(&block.out_conv)?,
        })
    }

    /// As [`FusionBlock::forward`]. The 1×1 `out_conv` and the bilinear resize commute (the
    /// interpolation weights sum to one), so the convolution runs on the smaller of the two maps.
    pub(super) fn forward(
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
pub(super) enum CpuResize {
    Up(PackedConvTranspose2d),
    Identity,
    Down(PackedConv2d),
}

/// [`HeadTail`] packed for the CPU kernels.
#[derive(Debug, Clone)]
pub(super) enum CpuTail {
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
pub(super) struct CpuHead {
    projects: Vec<PackedConv2d>,
    resize: Vec<CpuResize>,
    layer_rn: Vec<PackedConv2d>,
    trunk: Vec<CpuFusion>,
    tail: CpuTail,
}

impl CpuHead {
    pub(super) fn new(head: &DptHead) -> Result<Self> {
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
    pub(super) fn forward(
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
