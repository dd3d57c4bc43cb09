//! The betas head of the GS-supervised releases (`shape_head.*`, official `ShapeHead` of
//! `core/models/vggt/heads/shape_head.py`, built when the config has a `shape_head` block:
//! LHMPP-700M-PixelShuffle and LHMPP-700M-SMPLX-FREE, `predict_shape_dim: 10`).
//!
//! Input: the pose token (index `shape_token_idx`, 0) of every view's image tokens after the PIT
//! (`results["img_feats"]` of the official dense PIT: the joint blocks keep the special tokens,
//! so this is the last frame block's output), averaged over the views: `[1, C]`. Then, as VGGT's
//! camera head but without activations: `token_norm`; `num_iterations` times: the conditioning
//! `embed_shape(pred)` (`embed_shape(empty_shape_tokens)` the first time) gives
//! `shift, scale, gate = shapeLN_modulation(·)` (SiLU, Linear C → 3C), the tokens become
//! `gate · (LN(x)·(1 + scale) + shift) + x` (LN without affine, eps 1e-6), run through
//! `trunk_depth` VGGT blocks (no qk norm, no RoPE: one token), and
//! `pred += shape_branch(trunk_norm(·))` (Linear C → C/2, GELU, Linear → 10). The last `pred` is
//! the betas.

use candle_core::{DType, Device, Module, Result, Tensor, D};
use candle_nn::{Init, VarBuilder};
use serde::{Deserialize, Serialize};

use super::config::ImageBackboneConfig;
use super::frame_block::{FrameBlock, RopeTables};
use crate::kernels::layer_norm::{layer_norm, LayerNorm};
use crate::kernels::linear::{linear, Linear};

/// `shape_head` of the official config (plus `predict_shape_dim`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShapeHeadConfig {
    /// Token width (`dim_in`, the image tokens' width: 1024).
    pub dim_in: usize,
    /// Predicted betas (`predict_shape_dim`, 10).
    pub target_dim: usize,
    /// VGGT blocks of the trunk (`trunk_depth`, 2 in the releases; class default 4).
    pub trunk_depth: usize,
    /// Heads of the trunk blocks (16).
    pub num_heads: usize,
    /// MLP ratio of the trunk blocks (4).
    pub mlp_ratio: f64,
    /// LayerScale init of the trunk blocks (0.01).
    pub init_values: f64,
    /// Refinement steps (`num_iterations`, 4).
    pub num_iterations: usize,
    /// Index of the token read in each view's sequence (the pose token, 0).
    pub shape_token_idx: usize,
}

impl ShapeHeadConfig {
    /// The `shape_head` block of `configs/train/LHMPP-pixelshuffle.yaml` and
    /// `configs/train/LHMPP-anyview-SMPLX-FREE.yaml`.
    pub fn lhmpp_700m() -> Self {
        Self {
            dim_in: 1024,
            target_dim: 10,
            trunk_depth: 2,
            num_heads: 16,
            mlp_ratio: 4.0,
            init_values: 0.01,
            num_iterations: 4,
            shape_token_idx: 0,
        }
    }

    /// Parameters of the head.
    pub fn parameter_count(&self) -> usize {
        let (c, t) = (self.dim_in, self.target_dim);
        let lin = |i: usize, o: usize| i * o + o;
        let hidden = (c as f64 * self.mlp_ratio) as usize;
        let block = 4 * c + lin(c, 3 * c) + lin(c, c) + 2 * c + lin(c, hidden) + lin(hidden, c);
        self.trunk_depth * block
            + 4 * c
            + t
            + lin(t, c)
            + lin(c, 3 * c)
            + lin(c, c / 2)
            + lin(c / 2, t)
    }
}

/// The betas head; `vb = root.pp("shape_head")`.
#[derive(Debug, Clone)]
pub struct ShapeHead {
    cfg: ShapeHeadConfig,
    trunk: Vec<FrameBlock>,
    token_norm: LayerNorm,
    trunk_norm: LayerNorm,
    adaln_norm: LayerNorm,
    empty_shape_tokens: Tensor,
    embed_shape: Linear,
    modulation: Linear,
    branch_fc1: Linear,
    branch_fc2: Linear,
    head_dim: usize,
}

impl ShapeHead {
    /// Builds `trunk_blocks.*`, the norms, `empty_shape_tokens`, `embed_shape`,
    /// `shapeLN_modulation.1` and `shape_branch.fc{1,2}`.
    pub fn new(cfg: &ShapeHeadConfig, vb: VarBuilder) -> Result<Self> {
        let (c, t) = (cfg.dim_in, cfg.target_dim);
        let block_cfg = ImageBackboneConfig {
            depth: cfg.trunk_depth,
            num_heads: cfg.num_heads,
            mlp_ratio: cfg.mlp_ratio,
            rope_base: 100.0,
            qk_norm: false,
            init_values: cfg.init_values,
        };
        let trunk = (0..cfg.trunk_depth)
            .map(|i| FrameBlock::new(c, &block_cfg, vb.pp("trunk_blocks").pp(i)))
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            cfg: cfg.clone(),
            trunk,
            token_norm: layer_norm(c, 1e-5, vb.pp("token_norm"))?,
            trunk_norm: layer_norm(c, 1e-5, vb.pp("trunk_norm"))?,
            adaln_norm: LayerNorm::plain(1e-6),
            empty_shape_tokens: vb.get_with_hints(
                (1, 1, t),
                "empty_shape_tokens",
                Init::Const(0.0),
            )?,
            embed_shape: linear(t, c, vb.pp("embed_shape"))?,
            modulation: linear(c, 3 * c, vb.pp("shapeLN_modulation").pp(1))?,
            branch_fc1: linear(c, c / 2, vb.pp("shape_branch").pp("fc1"))?,
            branch_fc2: linear(c / 2, t, vb.pp("shape_branch").pp("fc2"))?,
            head_dim: c / cfg.num_heads.max(1),
        })
    }

    /// The config this head was built for.
    pub fn config(&self) -> &ShapeHeadConfig {
        &self.cfg
    }

    /// `tokens [B, C]` (aggregated shape tokens) → the prediction after every refinement step,
    /// each `[B, target_dim]` (the last is the betas).
    pub fn forward(&self, tokens: &Tensor) -> Result<Vec<Tensor>> {
        let x = match tokens.rank() {
            2 => tokens.unsqueeze(1)?,
            _ => tokens.clone(),
        };
        let x = self.token_norm.forward(&x)?;
        let (b, s, c) = x.dims3()?;
        // One token at position 0: the trunk blocks' RoPE is the identity (VGGT builds them
        // without RoPE).
        let rope = RopeTables::new(self.head_dim, 0, 0, s, 100.0, x.dtype(), x.device())?;
        let normed = self.adaln_norm.forward(&x)?;
        let mut pred: Option<Tensor> = None;
        let mut out = Vec::with_capacity(self.cfg.num_iterations);
        for _ in 0..self.cfg.num_iterations {
            let input = match &pred {
                None => self.embed_shape.forward(&self.empty_shape_tokens.expand((
                    b,
                    s,
                    self.cfg.target_dim,
                ))?)?,
                Some(p) => self.embed_shape.forward(p)?,
            };
            let m = self.modulation.forward(&candle_nn::ops::silu(&input)?)?;
            let (shift, scale, gate) = (
                m.narrow(D::Minus1, 0, c)?,
                m.narrow(D::Minus1, c, c)?,
                m.narrow(D::Minus1, 2 * c, c)?,
            );
            let modulated = ((normed.broadcast_mul(&(scale + 1.0)?)? + shift)? * gate)?;
            let mut h = (modulated + &x)?;
            for block in &self.trunk {
                h = block.forward(&h, &rope)?.0;
            }
            let delta = self.branch_fc2.forward(
                &self
                    .branch_fc1
                    .forward_gelu(&self.trunk_norm.forward(&h)?)?,
            )?;
            let next = match pred {
                None => delta,
                Some(p) => (p + delta)?,
            };
            out.push(next.mean(1)?);
            pred = Some(next);
        }
        Ok(out)
    }

    /// The betas `[1, target_dim]` from the image tokens after the PIT, `[V, P, C]`: the
    /// `shape_token_idx` token of every view, averaged over the views, refined
    /// (`forward_from_sequence` of the official head).
    pub fn predict(&self, tokens: &Tensor) -> Result<Tensor> {
        let slot = tokens
            .narrow(1, self.cfg.shape_token_idx, 1)?
            .squeeze(1)?
            .to_dtype(DType::F32)?
            .mean_keepdim(0)?
            .to_dtype(tokens.dtype())?;
        let steps = self.forward(&slot)?;
        steps
            .last()
            .cloned()
            .ok_or_else(|| candle_core::Error::Msg("shape head: num_iterations is 0".into()))?
            .to_dtype(DType::F32)
    }

    /// The device of the head's weights.
    pub fn device(&self) -> &Device {
        self.empty_shape_tokens.device()
    }
}
