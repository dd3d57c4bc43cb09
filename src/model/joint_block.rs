//! SD3 joint-attention PIT block (`transformer.pi_transformer_{enc,dec}.{i}`), as the official
//! `SD3PMMJointTransformerBlock`.
//!
//! ```text
//! x = ff_proj(points)            c = ff_context_proj(image)
//! nx, gate/shift/scale = AdaLN-Zero(x, temb)
//! nc, ... = AdaLN-Zero(c, temb)   or AdaLN-Continuous(c, temb) when context_pre_only
//! q,k,v = to_q/k/v(nx); cq,ck,cv = add_q/k/v_proj(nc); RMSNorm per head on q,k,cq,ck
//! one softmax over [points; image]; x_attn → to_out.0, c_attn → to_add_out
//! x += g_msa·x_attn; x += g_mlp·ff(LN(x)(1+sc)+sh)
//! c += cg_msa·c_attn; f = ff_context(LN(c)(1+csc)+csh); c += cg_mlp·f + f   (double add: official bug, kept)
//! points = inv_ff_proj(x)
//! ```
//! `temb` is the mean over views of `motion_embed_mlp(cls)`.

use candle_core::{DType, Module, Result, Tensor};
use candle_nn::{Init, RmsNorm, VarBuilder};

use crate::kernels::linear::{linear, Activation, Linear};

use super::attention::{attention, merge_heads, split_heads};
use super::config::PitBlockSpec;
use crate::kernels::layer_norm::LayerNorm;

/// LayerNorm epsilon inside AdaLN (no affine).
const ADALN_EPS: f64 = 1e-6;
/// LayerNorm epsilon before the feed-forward (no affine).
const FF_NORM_EPS: f64 = 1e-5;
/// RMSNorm epsilon on q/k.
const QK_RMS_EPS: f64 = 1e-5;
/// Std of the AdaLN modulation weights created from scratch (small gates).
pub const ADALN_INIT_STD: f64 = 0.02;

/// diffusers `FeedForward`: `net.0.proj` → GELU (tanh) → `net.2`.
#[derive(Debug, Clone)]
pub struct FeedForward {
    proj: Linear,
    out: Linear,
}

impl FeedForward {
    /// `Linear(dim → inner)`, GELU-tanh, `Linear(inner → out)`.
    pub fn new(dim: usize, inner: usize, out: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            proj: linear(dim, inner, vb.pp("net").pp(0).pp("proj"))?,
            out: linear(inner, out, vb.pp("net").pp(2))?,
        })
    }

    /// Applies the two layers.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        self.out
            .forward(&self.proj.forward_act(x, Activation::GeluTanh)?)
    }

    /// `residual + gate ⊙ forward(x)`, fused into the second product.
    pub fn forward_residual(&self, x: &Tensor, residual: &Tensor, gate: &Tensor) -> Result<Tensor> {
        self.out.forward_residual(
            &self.proj.forward_act(x, Activation::GeluTanh)?,
            residual,
            Some(gate),
        )
    }
}

/// `Linear(silu(temb))` producing `chunks` modulation vectors.
#[derive(Debug, Clone)]
struct Modulation {
    linear: Linear,
    chunks: usize,
}

impl Modulation {
    fn new(dim: usize, chunks: usize, vb: VarBuilder) -> Result<Self> {
        let vb = vb.pp("linear");
        let w = vb.get_with_hints(
            (chunks * dim, dim),
            "weight",
            Init::Randn {
                mean: 0.0,
                stdev: ADALN_INIT_STD,
            },
        )?;
        let b = vb.get_with_hints(chunks * dim, "bias", Init::Const(0.0))?;
        Ok(Self {
            linear: Linear::new(w, Some(b)),
            chunks,
        })
    }

    /// `temb [1, D]` → `chunks` tensors `[1, D]`.
    fn forward(&self, temb: &Tensor) -> Result<Vec<Tensor>> {
        self.linear
            .forward(&candle_nn::ops::silu(temb)?)?
            .chunk(self.chunks, 1)
    }
}

/// `norm(x)·(1 + scale) + shift` for `x [N, D]`, `scale, shift [1, D]`.
/// One pass: a LayerNorm whose affine weight is `1 + scale` and bias `shift`.
fn modulate(x: &Tensor, shift: &Tensor, scale: &Tensor, eps: f64) -> Result<Tensor> {
    let weight = (scale + 1.0)?.flatten_all()?;
    LayerNorm::new(weight, shift.flatten_all()?, eps).forward(x)
}

/// Joint attention (`attn.*`).
#[derive(Debug, Clone)]
struct JointAttention {
    to_q: Linear,
    to_k: Linear,
    to_v: Linear,
    add_q_proj: Linear,
    add_k_proj: Linear,
    add_v_proj: Linear,
    norm_q: RmsNorm,
    norm_k: RmsNorm,
    norm_added_q: RmsNorm,
    norm_added_k: RmsNorm,
    to_out: Linear,
    to_add_out: Option<Linear>,
    heads: usize,
}

impl JointAttention {
    fn new(dim: usize, heads: usize, pre_only: bool, vb: VarBuilder) -> Result<Self> {
        let hd = dim / heads;
        let lin = |name: &str| linear(dim, dim, vb.pp(name));
        let rms = |name: &str| candle_nn::rms_norm(hd, QK_RMS_EPS, vb.pp(name));
        Ok(Self {
            to_q: lin("to_q")?,
            to_k: lin("to_k")?,
            to_v: lin("to_v")?,
            add_q_proj: lin("add_q_proj")?,
            add_k_proj: lin("add_k_proj")?,
            add_v_proj: lin("add_v_proj")?,
            norm_q: rms("norm_q")?,
            norm_k: rms("norm_k")?,
            norm_added_q: rms("norm_added_q")?,
            norm_added_k: rms("norm_added_k")?,
            to_out: linear(dim, dim, vb.pp("to_out").pp(0))?,
            to_add_out: if pre_only {
                None
            } else {
                Some(lin("to_add_out")?)
            },
            heads,
        })
    }

    /// `x [N, D]`, `c [M, D]` → (`x_res + x_gate ⊙ x_attn` `[N, D]`,
    /// `c_res + c_gate ⊙ c_attn` `[M, D]` if not pre-only); the gated residual adds are fused
    /// into the output projections.
    fn forward(
        &self,
        x: &Tensor,
        c: &Tensor,
        (x_res, x_gate): (&Tensor, &Tensor),
        (c_res, c_gate): (&Tensor, &Tensor),
    ) -> Result<(Tensor, Option<Tensor>)> {
        let n = x.dim(0)?;
        let heads = |t: Tensor| split_heads(&t.unsqueeze(0)?, self.heads);
        let q = self.norm_q.forward(&heads(self.to_q.forward(x)?)?)?;
        let k = self.norm_k.forward(&heads(self.to_k.forward(x)?)?)?;
        let v = heads(self.to_v.forward(x)?)?;
        let cq = self
            .norm_added_q
            .forward(&heads(self.add_q_proj.forward(c)?)?)?;
        let ck = self
            .norm_added_k
            .forward(&heads(self.add_k_proj.forward(c)?)?)?;
        let cv = heads(self.add_v_proj.forward(c)?)?;
        let q = Tensor::cat(&[q, cq], 2)?;
        let k = Tensor::cat(&[k, ck], 2)?;
        let v = Tensor::cat(&[v, cv], 2)?;
        let out = merge_heads(&attention(&q, &k, &v, None)?)?.squeeze(0)?;
        let m = out.dim(0)? - n;
        let x_out = self
            .to_out
            .forward_residual(&out.narrow(0, 0, n)?, x_res, Some(x_gate))?;
        let c_out = match &self.to_add_out {
            Some(l) => Some(l.forward_residual(&out.narrow(0, n, m)?, c_res, Some(c_gate))?),
            None => None,
        };
        Ok((x_out, c_out))
    }
}

/// One PIT block.
#[derive(Debug, Clone)]
pub struct JointBlock {
    spec: PitBlockSpec,
    ff_proj: FeedForward,
    ff_context_proj: FeedForward,
    norm1: Modulation,
    norm1_context: Modulation,
    attn: JointAttention,
    ff: FeedForward,
    ff_context: Option<FeedForward>,
    inv_ff_proj: FeedForward,
}

impl JointBlock {
    /// Builds a block of width `dim` for `spec.point_dim` point channels and `context_dim`
    /// image channels.
    pub fn new(
        spec: PitBlockSpec,
        dim: usize,
        heads: usize,
        context_dim: usize,
        vb: VarBuilder,
    ) -> Result<Self> {
        let pv = spec.point_dim;
        let pre = spec.context_pre_only;
        Ok(Self {
            spec,
            ff_proj: FeedForward::new(pv, 4 * pv, dim, vb.pp("ff_proj"))?,
            ff_context_proj: FeedForward::new(context_dim, 4 * pv, dim, vb.pp("ff_context_proj"))?,
            norm1: Modulation::new(dim, 6, vb.pp("norm1"))?,
            norm1_context: Modulation::new(dim, if pre { 2 } else { 6 }, vb.pp("norm1_context"))?,
            attn: JointAttention::new(dim, heads, pre, vb.pp("attn"))?,
            ff: FeedForward::new(dim, 4 * dim, dim, vb.pp("ff"))?,
            ff_context: if pre {
                None
            } else {
                Some(FeedForward::new(dim, 4 * dim, dim, vb.pp("ff_context"))?)
            },
            inv_ff_proj: FeedForward::new(dim, 4 * dim, pv, vb.pp("inv_ff_proj"))?,
        })
    }

    /// Whether the image tokens are left unchanged (last decoder block).
    pub fn context_pre_only(&self) -> bool {
        self.spec.context_pre_only
    }

    /// `points [N, pv]`, `image [M, C]`, `temb [1, D]` → (new point features `[N, pv]`,
    /// updated image tokens `[M, D]`, or `None` when context-pre-only).
    pub fn forward(
        &self,
        points: &Tensor,
        image: &Tensor,
        temb: &Tensor,
    ) -> Result<(Tensor, Option<Tensor>)> {
        // The residual streams `x` and `c` are f32 whatever the model's dtype: a bf16 model
        // rounds them once, at the block's outputs, not after each residual add.
        let dtype = points.dtype();
        let f32 = |t: Tensor| t.to_dtype(DType::F32);
        let x = f32(self.ff_proj.forward(points)?)?;
        let c = f32(self.ff_context_proj.forward(image)?)?;
        let m = self.norm1.forward(temb)?;
        let (shift_msa, scale_msa, gate_msa, shift_mlp, scale_mlp, gate_mlp) =
            (&m[0], &m[1], &m[2], &m[3], &m[4], &m[5]);
        let nx = modulate(&x, shift_msa, scale_msa, ADALN_EPS)?.to_dtype(dtype)?;
        let mc = self.norm1_context.forward(temb)?;
        let nc = if self.spec.context_pre_only {
            // AdaLN-Continuous: chunk order (scale, shift).
            modulate(&c, &mc[1], &mc[0], ADALN_EPS)?
        } else {
            modulate(&c, &mc[0], &mc[1], ADALN_EPS)?
        }
        .to_dtype(dtype)?;
        // Pre-only blocks have no context gate; the gate is then unused.
        let c_gate_msa = mc.get(2).unwrap_or(gate_msa);
        let (x, c_new) = self
            .attn
            .forward(&nx, &nc, (&x, gate_msa), (&c, c_gate_msa))?;
        let x = self.ff.forward_residual(
            &modulate(&x, shift_mlp, scale_mlp, FF_NORM_EPS)?.to_dtype(dtype)?,
            &x,
            gate_mlp,
        )?;
        let c = match (c_new, &self.ff_context) {
            (Some(c), Some(ff_context)) => {
                let (c_shift_mlp, c_scale_mlp, c_gate_mlp) = (&mc[3], &mc[4], &mc[5]);
                // Official double add of the context feed-forward (kept for weight parity):
                // c + g ⊙ f + f = c + (g + 1) ⊙ f.
                Some(
                    ff_context
                        .forward_residual(
                            &modulate(&c, c_shift_mlp, c_scale_mlp, FF_NORM_EPS)?
                                .to_dtype(dtype)?,
                            &c,
                            &(c_gate_mlp + 1.0)?,
                        )?
                        .to_dtype(dtype)?,
                )
            }
            _ => None,
        };
        // Rounded into the model's dtype before the projection back (its product rounds its
        // input anyway): its wide hidden activations then stay in that dtype too.
        Ok((self.inv_ff_proj.forward(&x.to_dtype(dtype)?)?, c))
    }
}

/// `motion_embed_mlp`: `Linear(C → hidden)`, SiLU, `Linear(hidden → D)`.
#[derive(Debug, Clone)]
pub struct MotionEmbed {
    l0: Linear,
    l2: Linear,
}

impl MotionEmbed {
    /// Builds `motion_embed_mlp.{0,2}`.
    pub fn new(in_dim: usize, hidden: usize, out_dim: usize, vb: VarBuilder) -> Result<Self> {
        Ok(Self {
            l0: linear(in_dim, hidden, vb.pp(0))?,
            l2: linear(hidden, out_dim, vb.pp(2))?,
        })
    }

    /// Conditioning `temb [1, D]` = mean over views of the MLP of each view's CLS `[V, C]`.
    pub fn temb(&self, cls: &Tensor) -> Result<Tensor> {
        let e = self
            .l2
            .forward(&candle_nn::ops::silu(&self.l0.forward(cls)?)?)?;
        e.mean_keepdim(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};

    fn block(pre_only: bool) -> JointBlock {
        let vb = crate::model::checkpoint::seeded_var_builder(9, DType::F32, &Device::Cpu);
        JointBlock::new(
            PitBlockSpec {
                point_dim: 16,
                context_pre_only: pre_only,
            },
            32,
            2,
            32,
            vb.pp("blk"),
        )
        .unwrap()
    }

    #[test]
    fn block_maps_points_back_to_their_width_and_updates_the_image() {
        let b = block(false);
        let p = Tensor::randn(0f32, 1.0, (10, 16), &Device::Cpu).unwrap();
        let c = Tensor::randn(0f32, 1.0, (7, 32), &Device::Cpu).unwrap();
        let t = Tensor::randn(0f32, 1.0, (1, 32), &Device::Cpu).unwrap();
        let (np, nc) = b.forward(&p, &c, &t).unwrap();
        assert_eq!(np.dims(), &[10, 16]);
        assert_eq!(nc.unwrap().dims(), &[7, 32]);
    }

    #[test]
    fn context_pre_only_block_returns_no_image_update() {
        let b = block(true);
        let p = Tensor::randn(0f32, 1.0, (4, 16), &Device::Cpu).unwrap();
        let c = Tensor::randn(0f32, 1.0, (3, 32), &Device::Cpu).unwrap();
        let t = Tensor::randn(0f32, 1.0, (1, 32), &Device::Cpu).unwrap();
        let (np, nc) = b.forward(&p, &c, &t).unwrap();
        assert_eq!(np.dims(), &[4, 16]);
        assert!(nc.is_none());
    }

    #[test]
    fn points_see_the_image_through_joint_attention() {
        let b = block(false);
        let p = Tensor::randn(0f32, 1.0, (6, 16), &Device::Cpu).unwrap();
        let t = Tensor::randn(0f32, 1.0, (1, 32), &Device::Cpu).unwrap();
        let c1 = Tensor::randn(0f32, 1.0, (5, 32), &Device::Cpu).unwrap();
        let c2 = Tensor::randn(0f32, 1.0, (5, 32), &Device::Cpu).unwrap();
        let (a, _) = b.forward(&p, &c1, &t).unwrap();
        let (b2, _) = b.forward(&p, &c2, &t).unwrap();
        let diff = crate::testing::max_abs_diff(&a, &b2);
        assert!(diff > 1e-6);
    }
}
