//! DINOv2 ViT image encoder with register tokens (`encoder.model.*`).
//!
//! Inputs are RGB in [0, 1] without ImageNet normalisation (as the official code). The stored
//! `G×G` position-embedding grid is resampled with antialiased bicubic interpolation to the
//! input's patch grid (cached per size). Returns the final-norm patch tokens and CLS token;
//! the register tokens are dropped.

use std::collections::HashMap;
use std::sync::Mutex;

use candle_core::{Module, Result, Tensor};
use candle_nn::{Conv2d, Conv2dConfig, Init, VarBuilder};

use crate::kernels::layer_norm::{layer_norm, LayerNorm};
use crate::kernels::linear::{linear, Linear};

use super::attention::{attention, merge_heads};
use super::bicubic::resize_bicubic_aa;
use super::config::EncoderConfig;

/// LayerScale initial value used when weights are created from scratch.
pub const ENCODER_LAYER_SCALE_INIT: f64 = 0.1;

/// Std of the random token/position tables created from scratch.
const TOKEN_INIT_STD: f64 = 0.02;

/// `ls1` / `ls2`: per-channel scaling of a residual branch.
#[derive(Debug, Clone)]
pub struct LayerScale {
    gamma: Tensor,
}

impl LayerScale {
    /// Loads `gamma [dim]`.
    pub fn new(dim: usize, init: f64, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            gamma: vb.get_with_hints(dim, "gamma", Init::Const(init))?,
        })
    }

    /// The per-channel scale `gamma [dim]`.
    pub fn gamma(&self) -> &Tensor {
        &self.gamma
    }
}

/// Two-layer MLP with exact GELU (`mlp.fc1`, `mlp.fc2`).
#[derive(Debug, Clone)]
pub struct Mlp {
    fc1: Linear,
    fc2: Linear,
}

impl Mlp {
    /// Loads `fc1 [hidden, dim]` and `fc2 [dim, hidden]`.
    pub fn new(dim: usize, hidden: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            fc1: linear(dim, hidden, vb.pp("fc1"))?,
            fc2: linear(hidden, dim, vb.pp("fc2"))?,
        })
    }

    /// `residual + gate ⊙ fc2(gelu_erf(fc1(x)))`, fused into the second product.
    pub fn forward_residual(
        &self,
        x: &Tensor,
        residual: &Tensor,
        gate: Option<&Tensor>,
    ) -> Result<Tensor> {
        self.fc2
            .forward_residual(&self.fc1.forward_gelu(x)?, residual, gate)
    }
}

/// Plain multi-head self-attention (`attn.qkv`, `attn.proj`).
#[derive(Debug, Clone)]
struct SelfAttention {
    qkv: Linear,
    proj: Linear,
    heads: usize,
}

impl SelfAttention {
    fn new(dim: usize, heads: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            qkv: linear(dim, 3 * dim, vb.pp("qkv"))?,
            proj: linear(dim, dim, vb.pp("proj"))?,
            heads,
        })
    }

    /// `residual + gate ⊙ attention(x)`.
    fn forward_residual(&self, x: &Tensor, residual: &Tensor, gate: &Tensor) -> Result<Tensor> {
        let (b, n, c) = x.dims3()?;
        let qkv = self
            .qkv
            .forward(x)?
            .reshape((b, n, 3, self.heads, c / self.heads))?;
        let qkv = qkv.permute((2, 0, 3, 1, 4))?;
        let (q, k, v) = (qkv.get(0)?, qkv.get(1)?, qkv.get(2)?);
        let out = attention(&q.contiguous()?, &k.contiguous()?, &v.contiguous()?, None)?;
        self.proj
            .forward_residual(&merge_heads(&out)?, residual, Some(gate))
    }
}

/// One pre-norm ViT block with LayerScale (`encoder.model.blocks.{i}`).
#[derive(Debug, Clone)]
pub struct EncoderBlock {
    norm1: LayerNorm,
    attn: SelfAttention,
    ls1: LayerScale,
    norm2: LayerNorm,
    mlp: Mlp,
    ls2: LayerScale,
}

impl EncoderBlock {
    /// Builds one block of `cfg`'s width from `vb = ….blocks.{i}`.
    pub fn new(cfg: &EncoderConfig, vb: VarBuilder) -> Result<Self> {
        let c = cfg.embed_dim;
        let hidden = (c as f64 * cfg.mlp_ratio) as usize;
        Ok(Self {
            norm1: layer_norm(c, cfg.layer_norm_eps, vb.pp("norm1"))?,
            attn: SelfAttention::new(c, cfg.num_heads, vb.pp("attn"))?,
            ls1: LayerScale::new(c, ENCODER_LAYER_SCALE_INIT, vb.pp("ls1"))?,
            norm2: layer_norm(c, cfg.layer_norm_eps, vb.pp("norm2"))?,
            mlp: Mlp::new(c, hidden, vb.pp("mlp"))?,
            ls2: LayerScale::new(c, ENCODER_LAYER_SCALE_INIT, vb.pp("ls2"))?,
        })
    }

    /// `x [B, N, C]` → `x + ls1·attn(norm1 x)`, then `+ ls2·mlp(norm2 x)`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let x = self
            .attn
            .forward_residual(&self.norm1.forward(x)?, x, self.ls1.gamma())?;
        self.mlp
            .forward_residual(&self.norm2.forward(&x)?, &x, Some(self.ls2.gamma()))
    }
}

/// Encoder output for a batch of images.
#[derive(Debug, Clone)]
pub struct EncoderOutput {
    /// Final-norm patch tokens `[B, h·w, C]` (row-major patch grid).
    pub patch_tokens: Tensor,
    /// Final-norm CLS token `[B, C]`.
    pub cls: Tensor,
}

/// DINOv2 ViT with register tokens; `vb = root.pp("encoder").pp("model")`.
#[derive(Debug)]
pub struct DinoEncoder {
    cfg: EncoderConfig,
    cls_token: Tensor,
    pos_embed: Tensor,
    register_tokens: Tensor,
    patch_embed: Conv2d,
    /// The patch embedding as a linear layer over flattened `3·p·p` patches, for bf16 weights
    /// on the CPU (candle has no bf16 CPU convolution; the packed bf16 product runs it).
    patch_linear: Option<Linear>,
    blocks: Vec<EncoderBlock>,
    norm: LayerNorm,
    pos_cache: Mutex<HashMap<(usize, usize), Tensor>>,
}

impl DinoEncoder {
    /// Builds the encoder from `encoder.model.*`.
    pub fn new(cfg: &EncoderConfig, vb: VarBuilder) -> Result<Self> {
        let c = cfg.embed_dim;
        let randn = Init::Randn {
            mean: 0.0,
            stdev: TOKEN_INIT_STD,
        };
        let conv_cfg = Conv2dConfig {
            stride: cfg.patch_size,
            ..Default::default()
        };
        let blocks = (0..cfg.depth)
            .map(|i| EncoderBlock::new(cfg, vb.pp("blocks").pp(i)))
            .collect::<Result<Vec<_>>>()?;
        let patch_embed = candle_nn::conv2d(
            3,
            c,
            cfg.patch_size,
            conv_cfg,
            vb.pp("patch_embed").pp("proj"),
        )?;
        let w = patch_embed.weight();
        let patch_linear = if w.device().is_cpu() && w.dtype() == candle_core::DType::BF16 {
            let flat = w.reshape((c, 3 * cfg.patch_size * cfg.patch_size))?;
            Some(Linear::new(flat, patch_embed.bias().cloned()))
        } else {
            None
        };
        Ok(Self {
            cfg: cfg.clone(),
            cls_token: vb.get_with_hints((1, 1, c), "cls_token", randn)?,
            pos_embed: vb.get_with_hints(
                (1, 1 + cfg.pos_embed_grid * cfg.pos_embed_grid, c),
                "pos_embed",
                randn,
            )?,
            register_tokens: vb.get_with_hints(
                (1, cfg.num_register_tokens, c),
                "register_tokens",
                randn,
            )?,
            patch_embed,
            patch_linear,
            blocks,
            norm: layer_norm(c, cfg.layer_norm_eps, vb.pp("norm"))?,
            pos_cache: Mutex::new(HashMap::new()),
        })
    }

    /// Patch-position embedding `[1, h·w, C]` for a `h×w` patch grid (cached per size).
    pub fn patch_pos_embed(&self, h: usize, w: usize) -> Result<Tensor> {
        if let Some(t) = self
            .pos_cache
            .lock()
            .map_err(|_| candle_core::Error::Msg("pos cache poisoned".into()))?
            .get(&(h, w))
        {
            return Ok(t.clone());
        }
        let g = self.cfg.pos_embed_grid;
        let c = self.cfg.embed_dim;
        let table = self.pos_embed.narrow(1, 1, g * g)?;
        let out = if (h, w) == (g, g) {
            table
        } else {
            let src = table
                .to_dtype(candle_core::DType::F32)?
                .flatten_all()?
                .to_vec1::<f32>()?;
            let dst = resize_bicubic_aa(&src, g, g, c, h, w);
            Tensor::from_vec(dst, (1, h * w, c), self.pos_embed.device())?
                .to_dtype(self.pos_embed.dtype())?
        };
        if let Ok(mut cache) = self.pos_cache.lock() {
            cache.insert((h, w), out.clone());
        }
        Ok(out)
    }

    /// Encodes images `[B, 3, H, W]` in [0, 1] (H, W multiples of the patch size).
    pub fn forward(&self, images: &Tensor) -> Result<EncoderOutput> {
        let (b, _, hh, ww) = images.dims4()?;
        let p = self.cfg.patch_size;
        if hh % p != 0 || ww % p != 0 {
            candle_core::bail!("encoder input {hh}x{ww} is not a multiple of patch size {p}");
        }
        let (h, w) = (hh / p, ww / p);
        let c = self.cfg.embed_dim;
        let images = images.to_dtype(self.cls_token.dtype())?;
        let x = match &self.patch_linear {
            Some(l) if images.device().is_cpu() => {
                // `[B, 3, h·p, w·p]` → patches `[B, h·w, 3·p·p]` in the weight's (c, y, x) order.
                let patches = images
                    .reshape((b, 3, h, p, w, p))?
                    .permute((0, 2, 4, 1, 3, 5))?
                    .contiguous()?
                    .reshape((b, h * w, 3 * p * p))?;
                l.forward(&patches)?
            }
            _ => self
                .patch_embed
                .forward(&images)?
                .flatten_from(2)?
                .transpose(1, 2)?,
        };
        let x = x.broadcast_add(&self.patch_pos_embed(h, w)?)?;
        let cls = (&self.cls_token + self.pos_embed.narrow(1, 0, 1)?)?.broadcast_as((b, 1, c))?;
        let regs = self
            .register_tokens
            .broadcast_as((b, self.cfg.num_register_tokens, c))?;
        let mut x = Tensor::cat(&[&cls, &regs, &x], 1)?.contiguous()?;
        for block in &self.blocks {
            x = block.forward(&x)?;
        }
        let x = self.norm.forward(&x)?;
        let skip = 1 + self.cfg.num_register_tokens;
        Ok(EncoderOutput {
            cls: x.narrow(1, 0, 1)?.squeeze(1)?,
            patch_tokens: x.narrow(1, skip, h * w)?.contiguous()?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::config::LhmppConfig;
    use candle_core::{DType, Device};

    fn encoder() -> DinoEncoder {
        let cfg = LhmppConfig::tiny();
        let vb = crate::model::checkpoint::seeded_var_builder(3, DType::F32, &Device::Cpu);
        DinoEncoder::new(&cfg.encoder, vb.pp("encoder").pp("model")).unwrap()
    }

    #[test]
    fn encoder_returns_patch_tokens_and_cls_for_any_patch_multiple() {
        let enc = encoder();
        let img = Tensor::rand(0f32, 1.0, (2, 3, 112, 84), &Device::Cpu).unwrap();
        let out = enc.forward(&img).unwrap();
        assert_eq!(out.patch_tokens.dims(), &[2, 8 * 6, 64]);
        assert_eq!(out.cls.dims(), &[2, 64]);
        let finite = out
            .patch_tokens
            .abs()
            .unwrap()
            .max_all()
            .unwrap()
            .to_scalar::<f32>()
            .unwrap();
        assert!(finite.is_finite());
    }

    #[test]
    fn images_in_a_batch_are_encoded_independently() {
        let enc = encoder();
        let img = Tensor::rand(0f32, 1.0, (2, 3, 56, 56), &Device::Cpu).unwrap();
        let both = enc.forward(&img).unwrap();
        let second = enc.forward(&img.narrow(0, 1, 1).unwrap()).unwrap();
        let diff = crate::testing::max_abs_diff(
            &both.patch_tokens.narrow(0, 1, 1).unwrap(),
            &second.patch_tokens,
        );
        assert!(diff < 1e-5);
    }

    #[test]
    fn non_patch_multiple_input_is_rejected() {
        let enc = encoder();
        let img = Tensor::zeros((1, 3, 50, 56), DType::F32, &Device::Cpu).unwrap();
        assert!(enc.forward(&img).unwrap_err().to_string().contains("50x56"));
    }
}
