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
//! [`crate::kernels`] (the token rows already are NHWC): 3×3 convolutions by Winograd F(4×4, 3×3)
//! or im2col + gemm with the bias, ReLUs and residual adds in their epilogues, the stride-sized
//! transposed convolutions as one gemm + scatter, each fusion block's 1×1 `out_conv` before its
//! (commuting) bilinear resize, and the sigmoid before a single NCHW copy at the end. Other
//! devices and dtypes, and [`NeuralRenderer::with_candle_ops`], run the stock candle ops.
//!
//! This module holds the configuration, the patchify front and [`NeuralRenderer`]; the head on
//! stock candle ops is in `candle_head`, the same head packed for the CPU kernels in `cpu_head`.

mod candle_head;
mod cpu_head;
#[cfg(test)]
mod tests;

use std::time::{Duration, Instant};

use candle_core::{DType, Device, Module, Result, Tensor, D};
use candle_nn::VarBuilder;
use rayon::prelude::*;

use crate::kernels::linear::{linear_no_bias, Linear};
use candle_head::DptHead;
use cpu_head::CpuHead;

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
pub struct DptStageTimes {
    /// `(stage, time)` pairs.
    pub stages: Vec<(&'static str, Duration)>,
}

impl DptStageTimes {
    fn add(&mut self, name: &'static str, d: Duration) {
        match self.stages.iter_mut().find(|(n, _)| *n == name) {
            Some((_, t)) => *t += d,
            None => self.stages.push((name, d)),
        }
    }
}

/// Laps the stages of one forward into an optional [`DptStageTimes`].
struct Clock<'a> {
    times: Option<&'a mut DptStageTimes>,
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
    ///
    /// A bf16 checkpoint on the CPU loads this head in f32 (its weights widened once, a few MB)
    /// so that it runs on the channels-last f32 kernels: their Winograd 3×3 convolutions do a
    /// quarter of the multiplications that bf16 products would do (700M head at 588², 2
    /// threads: 0.86× PyTorch bf16's time, `scripts/bench-cpu-peer --only dpt --dtype bf16`).
    pub fn new(cfg: &DptConfig, vb: VarBuilder) -> Result<Self> {
        let vb = if vb.device().is_cpu() && vb.dtype() == DType::BF16 {
            vb.set_dtype(DType::F32)
        } else {
            vb
        };
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
        times: &mut DptStageTimes,
    ) -> Result<(Tensor, Tensor)> {
        self.forward_inner(features, Some(times))
    }

    fn forward_inner(
        &self,
        features: &Tensor,
        times: Option<&mut DptStageTimes>,
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
        let widened;
        let features = if self.cpu_head.is_some() && features.dtype() == DType::BF16 {
            // Widened in its own memory order: a channels-last view stays channels-last.
            let nhwc = features.permute((0, 2, 3, 1))?;
            widened = if nhwc.is_contiguous() {
                crate::kernels::bf16::widened_to_f32(&nhwc)?.permute((0, 3, 1, 2))?
            } else {
                crate::kernels::bf16::widened_to_f32(features)?
            };
            &widened
        } else {
            features
        };
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
                    crate::kernels::contiguous_f32(storage, layout, "neural renderer", "features")?;
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
