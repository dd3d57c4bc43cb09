//! VGGT-style frame attention (`transformer.image_backbone.*`).
//!
//! Each view's tokens `[pose(1), registers(4), patches(h·w)]` attend within the view. A block is
//! LN → qkv → per-head LayerNorm on q and k → 2D RoPE (base 100; the head dim is split into a
//! y half and an x half, rotate-half convention; patch positions are `(y+1, x+1)`, the 5
//! special tokens sit at 0) → attention → proj → LayerScale, then LN → MLP → LayerScale.
//! It also returns the token-merging metric K: the mean over heads of the post-norm,
//! post-RoPE keys.

use candle_core::{DType, Device, Module, Result, Tensor};
use candle_nn::{Init, VarBuilder};

use crate::kernels::layer_norm::{layer_norm, LayerNorm};
use crate::kernels::linear::{linear, Linear};

use super::attention::{attention, merge_heads};
use super::config::{EncoderConfig, ImageBackboneConfig};
use super::encoder::{LayerScale, Mlp};

/// LayerNorm epsilon of the frame blocks (torch default).
const FRAME_LN_EPS: f64 = 1e-5;

/// Number of special tokens per view: 1 pose token + 4 register tokens.
pub const SPECIAL_TOKENS: usize = 5;

/// Cos/sin tables of the 2D RoPE for one patch grid: `[N, D/2]` per axis.
#[derive(Debug, Clone)]
pub struct RopeTables {
    cos_y: Tensor,
    sin_y: Tensor,
    cos_x: Tensor,
    sin_x: Tensor,
}

impl RopeTables {
    /// Tables for `special` tokens at position 0 followed by an `h×w` grid at `(y+1, x+1)`.
    pub fn new(
        head_dim: usize,
        h: usize,
        w: usize,
        special: usize,
        base: f64,
        dtype: DType,
        dev: &Device,
    ) -> Result<Self> {
        let axis_dim = head_dim / 2;
        let half = axis_dim / 2;
        let inv_freq: Vec<f64> = (0..half)
            .map(|i| 1.0 / base.powf((2 * i) as f64 / axis_dim as f64))
            .collect();
        let mut pos = vec![(0usize, 0usize); special];
        pos.extend((0..h).flat_map(|y| (0..w).map(move |x| (y + 1, x + 1))));
        let n = pos.len();
        let table = |axis: usize, f: fn(f64) -> f64| -> Result<Tensor> {
            let mut v = Vec::with_capacity(n * axis_dim);
            for p in &pos {
                let p = if axis == 0 { p.0 } else { p.1 } as f64;
                for _ in 0..2 {
                    v.extend(inv_freq.iter().map(|fr| f(p * fr) as f32));
                }
            }
            Tensor::from_vec(v, (n, axis_dim), dev)?.to_dtype(dtype)
        };
        Ok(Self {
            cos_y: table(0, f64::cos)?,
            sin_y: table(0, f64::sin)?,
            cos_x: table(1, f64::cos)?,
            sin_x: table(1, f64::sin)?,
        })
    }

    /// Rotates `x [B, H, N, D]`: first half of D by y, second half by x.
    pub fn apply(&self, x: &Tensor) -> Result<Tensor> {
        let d = x.dim(3)?;
        let y = rope_1d(&x.narrow(3, 0, d / 2)?, &self.cos_y, &self.sin_y)?;
        let xx = rope_1d(&x.narrow(3, d / 2, d / 2)?, &self.cos_x, &self.sin_x)?;
        Tensor::cat(&[y, xx], 3)
    }
}

/// `t·cos + rotate_half(t)·sin` with `rotate_half([a, b]) = [−b, a]`.
fn rope_1d(t: &Tensor, cos: &Tensor, sin: &Tensor) -> Result<Tensor> {
    let d = t.dim(3)?;
    let a = t.narrow(3, 0, d / 2)?;
    let b = t.narrow(3, d / 2, d / 2)?;
    let rotated = Tensor::cat(&[b.neg()?, a], 3)?;
    t.broadcast_mul(cos)? + rotated.broadcast_mul(sin)?
}

/// Attention with qk LayerNorm and 2D RoPE (`attn.*`).
#[derive(Debug, Clone)]
struct FrameAttention {
    qkv: Linear,
    q_norm: Option<LayerNorm>,
    k_norm: Option<LayerNorm>,
    proj: Linear,
    heads: usize,
}

impl FrameAttention {
    fn new(dim: usize, cfg: &ImageBackboneConfig, vb: VarBuilder) -> Result<Self> {
        let hd = dim / cfg.num_heads;
        let norm = |name: &str| -> Result<Option<LayerNorm>> {
            if cfg.qk_norm {
                Ok(Some(layer_norm(hd, FRAME_LN_EPS, vb.pp(name))?))
            } else {
                Ok(None)
            }
        };
        Ok(Self {
            qkv: linear(dim, 3 * dim, vb.pp("qkv"))?,
            q_norm: norm("q_norm")?,
            k_norm: norm("k_norm")?,
            proj: linear(dim, dim, vb.pp("proj"))?,
            heads: cfg.num_heads,
        })
    }

    /// Returns the projected output and the keys metric `[B, N, D]`.
    /// `(residual + gate ⊙ attention(x), keys metric)`.
    fn forward_residual(
        &self,
        x: &Tensor,
        rope: &RopeTables,
        residual: &Tensor,
        gate: &Tensor,
    ) -> Result<(Tensor, Tensor)> {
        let (b, n, c) = x.dims3()?;
        let qkv = self
            .qkv
            .forward(x)?
            .reshape((b, n, 3, self.heads, c / self.heads))?
            .permute((2, 0, 3, 1, 4))?;
        let (mut q, mut k, v) = (qkv.get(0)?, qkv.get(1)?, qkv.get(2)?.contiguous()?);
        if let Some(norm) = &self.q_norm {
            q = norm.forward(&q)?;
        }
        if let Some(norm) = &self.k_norm {
            k = norm.forward(&k)?;
        }
        let q = rope.apply(&q)?.contiguous()?;
        let k = rope.apply(&k)?.contiguous()?;
        let metric = k.mean(1)?;
        let out = attention(&q, &k, &v, None)?;
        let x = self
            .proj
            .forward_residual(&merge_heads(&out)?, residual, Some(gate))?;
        Ok((x, metric))
    }
}

/// One frame block (`frame_blocks.{i}`).
#[derive(Debug, Clone)]
pub struct FrameBlock {
    norm1: LayerNorm,
    attn: FrameAttention,
    ls1: LayerScale,
    norm2: LayerNorm,
    mlp: Mlp,
    ls2: LayerScale,
}

impl FrameBlock {
    /// Builds one block of width `dim`.
    pub fn new(dim: usize, cfg: &ImageBackboneConfig, vb: VarBuilder) -> Result<Self> {
        let hidden = (dim as f64 * cfg.mlp_ratio) as usize;
        Ok(Self {
            norm1: layer_norm(dim, FRAME_LN_EPS, vb.pp("norm1"))?,
            attn: FrameAttention::new(dim, cfg, vb.pp("attn"))?,
            ls1: LayerScale::new(dim, cfg.init_values, vb.pp("ls1"))?,
            norm2: layer_norm(dim, FRAME_LN_EPS, vb.pp("norm2"))?,
            mlp: Mlp::new(dim, hidden, vb.pp("mlp"))?,
            ls2: LayerScale::new(dim, cfg.init_values, vb.pp("ls2"))?,
        })
    }

    /// `x [V, 5+h·w, C]` → (updated tokens, keys metric `[V, 5+h·w, D]`).
    ///
    /// The residual stream inside the block is f32 whatever `x`'s dtype: a bf16 model rounds
    /// it once, at the block's output.
    pub fn forward(&self, x: &Tensor, rope: &RopeTables) -> Result<(Tensor, Tensor)> {
        let dtype = x.dtype();
        let stream = x.to_dtype(DType::F32)?;
        let normed = self.norm1.forward(&stream)?.to_dtype(dtype)?;
        let (stream, metric) =
            self.attn
                .forward_residual(&normed, rope, &stream, self.ls1.gamma())?;
        let normed = self.norm2.forward(&stream)?.to_dtype(dtype)?;
        let x = self
            .mlp
            .forward_residual(&normed, &stream, Some(self.ls2.gamma()))?
            .to_dtype(dtype)?;
        Ok((x, metric))
    }
}

/// Special tokens and frame blocks (`transformer.image_backbone`).
#[derive(Debug, Clone)]
pub struct ImageBackbone {
    pose_token: Tensor,
    register_token: Tensor,
    blocks: Vec<FrameBlock>,
    head_dim: usize,
    rope_base: f64,
}

impl ImageBackbone {
    /// Builds `pose_token [1,2,1,C]`, `register_token [1,2,R,C]` and `frame_blocks.{0..depth}`.
    pub fn new(enc: &EncoderConfig, cfg: &ImageBackboneConfig, vb: VarBuilder) -> Result<Self> {
        let c = enc.embed_dim;
        let init = Init::Randn {
            mean: 0.0,
            stdev: 0.02,
        };
        let blocks = (0..cfg.depth)
            .map(|i| FrameBlock::new(c, cfg, vb.pp("frame_blocks").pp(i)))
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            pose_token: vb.get_with_hints((1, 2, 1, c), "pose_token", init)?,
            register_token: vb.get_with_hints(
                (1, 2, enc.num_register_tokens, c),
                "register_token",
                init,
            )?,
            blocks,
            head_dim: c / cfg.num_heads,
            rope_base: cfg.rope_base,
        })
    }

    /// Number of frame blocks.
    pub fn depth(&self) -> usize {
        self.blocks.len()
    }

    /// Prepends the special tokens: `[V, h·w, C]` → `[V, 5+h·w, C]`; view 0 gets variant 0,
    /// the other views variant 1.
    pub fn with_special_tokens(&self, patches: &Tensor) -> Result<Tensor> {
        let (v, _, c) = patches.dims3()?;
        let special = Tensor::cat(&[&self.pose_token, &self.register_token], 2)?.squeeze(0)?; // [2, 5, C]
        let s = special.dim(1)?;
        let first = special.narrow(0, 0, 1)?;
        let specials = if v == 1 {
            first
        } else {
            Tensor::cat(
                &[first, special.narrow(0, 1, 1)?.broadcast_as((v - 1, s, c))?],
                0,
            )?
        };
        Tensor::cat(&[&specials.to_dtype(patches.dtype())?, patches], 1)
    }

    /// RoPE tables for an `h×w` patch grid.
    pub fn rope(&self, h: usize, w: usize, dtype: DType, dev: &Device) -> Result<RopeTables> {
        RopeTables::new(
            self.head_dim,
            h,
            w,
            SPECIAL_TOKENS,
            self.rope_base,
            dtype,
            dev,
        )
    }

    /// Runs frame block `i`.
    pub fn block(&self, i: usize, x: &Tensor, rope: &RopeTables) -> Result<(Tensor, Tensor)> {
        self.blocks[i].forward(x, rope)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rope_preserves_norms_and_leaves_position_zero_unrotated() {
        let dev = Device::Cpu;
        let rope = RopeTables::new(8, 2, 3, 5, 100.0, DType::F32, &dev).unwrap();
        let x = Tensor::randn(0f32, 1.0, (1, 2, 11, 8), &dev).unwrap();
        let y = rope.apply(&x).unwrap();
        let n = |t: &Tensor| {
            t.sqr()
                .unwrap()
                .sum(3)
                .unwrap()
                .flatten_all()
                .unwrap()
                .to_vec1::<f32>()
                .unwrap()
        };
        for (a, b) in n(&x).iter().zip(n(&y)) {
            assert!((a - b).abs() < 1e-4);
        }
        let special_diff =
            crate::testing::max_abs_diff(&x.narrow(2, 0, 5).unwrap(), &y.narrow(2, 0, 5).unwrap());
        assert_eq!(special_diff, 0.0);
    }

    #[test]
    fn rope_scores_depend_only_on_relative_position() {
        // q·k after RoPE is a function of (pos_q − pos_k): shifting both by one row keeps it.
        let dev = Device::Cpu;
        let rope = RopeTables::new(8, 3, 1, 0, 100.0, DType::F32, &dev).unwrap();
        let q = Tensor::randn(0f32, 1.0, (1, 1, 1, 8), &dev).unwrap();
        let k = Tensor::randn(0f32, 1.0, (1, 1, 1, 8), &dev).unwrap();
        let at = |t: &Tensor, row: usize| {
            let rep = t.broadcast_as((1, 1, 3, 8)).unwrap().contiguous().unwrap();
            rope.apply(&rep).unwrap().narrow(2, row, 1).unwrap()
        };
        let dot = |a: Tensor, b: Tensor| {
            (a * b)
                .unwrap()
                .sum_all()
                .unwrap()
                .to_scalar::<f32>()
                .unwrap()
        };
        let s01 = dot(at(&q, 0), at(&k, 1));
        let s12 = dot(at(&q, 1), at(&k, 2));
        assert!((s01 - s12).abs() < 1e-4, "{s01} {s12}");
    }

    #[test]
    fn first_view_gets_its_own_special_tokens() {
        let vb = crate::model::checkpoint::seeded_var_builder(5, DType::F32, &Device::Cpu);
        let cfg = crate::model::config::LhmppConfig::tiny();
        let ib = ImageBackbone::new(
            &cfg.encoder,
            &cfg.image_backbone,
            vb.pp("transformer").pp("image_backbone"),
        )
        .unwrap();
        let patches = Tensor::zeros((3, 4, 64), DType::F32, &Device::Cpu).unwrap();
        let t = ib.with_special_tokens(&patches).unwrap();
        assert_eq!(t.dims(), &[3, 9, 64]);
        let v = |i: usize| t.get(i).unwrap().narrow(0, 0, 5).unwrap();
        let d01 = (v(0) - v(1))
            .unwrap()
            .abs()
            .unwrap()
            .sum_all()
            .unwrap()
            .to_scalar::<f32>()
            .unwrap();
        let d12 = (v(1) - v(2))
            .unwrap()
            .abs()
            .unwrap()
            .sum_all()
            .unwrap()
            .to_scalar::<f32>()
            .unwrap();
        assert!(d01 > 0.0);
        assert_eq!(d12, 0.0);
        let rope = ib.rope(2, 2, DType::F32, &Device::Cpu).unwrap();
        let (out, metric) = ib.block(0, &t, &rope).unwrap();
        assert_eq!(out.dims(), &[3, 9, 64]);
        assert_eq!(metric.dims(), &[3, 9, 32]);
    }
}
