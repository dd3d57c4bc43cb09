//! Gaussian head (`renderer.mlp_net`, `renderer.gs_net.out_layers`, `renderer.background_embedding`).
//!
//! `mlp_net`: Linear(q→n), SiLU, [Linear(n→n), SiLU]×(hidden−1), Linear(n→q); then five linear
//! heads with the official activations: colour `sigmoid` (RGB), scale `exp` clamped to
//! `[0, clip_scaling]`, offset `(sigmoid − 0.5)·xyz_offset_max_step`, opacity `sigmoid`,
//! rotation L2-normalised quaternion (w, x, y, z). (The inference-time per-body-part rules,
//! [`UPPER_BODY_MAX_SCALE`] and [`HAND_OPACITY`], need body-part masks:
//! [`GaussianOutput::with_part_masks`].)

use candle_core::{DType, Module, Result, Tensor, D};
use candle_nn::{Init, VarBuilder};

use crate::kernels::linear::{linear, Linear};

use super::config::GsHeadConfig;

/// Upper-body Gaussians have their scales clamped to this at inference (metres; official
/// `GSMLPDecoder`).
pub const UPPER_BODY_MAX_SCALE: f32 = 0.02;
/// Opacity the official decoder forces on hand Gaussians.
pub const HAND_OPACITY: f32 = 0.95;

/// Training init of the scaling bias (exp(−6) ≈ 2.5 mm).
pub const SCALING_BIAS_INIT: f64 = -6.0;
/// Training init of the opacity bias: logit(0.1).
pub const OPACITY_BIAS_INIT: f64 = -2.197_224_577_336_219_4;

/// Gaussian attributes for N points, as candle tensors (f32).
#[derive(Debug, Clone)]
pub struct GaussianOutput {
    /// Offsets from the anchors `[N, 3]`.
    pub offsets: Tensor,
    /// Canonical positions = anchors + offsets `[N, 3]`.
    pub positions: Tensor,
    /// Scales in metres `[N, 3]`.
    pub scales: Tensor,
    /// Unit quaternions (w, x, y, z) `[N, 4]`.
    pub rotations: Tensor,
    /// Opacities in [0, 1] `[N, 1]`.
    pub opacities: Tensor,
    /// RGB in [0, 1] `[N, 3]`.
    pub colors: Tensor,
    /// Point features for the neural renderer `[N, q]`.
    pub features: Tensor,
}

/// The part masks of the official `mesh_meta` in a tensor map (u8 or any numeric dtype,
/// non-zero = in the part): (hands = `is_rhand` | `is_lhand`, `is_upper_body`), `None` when
/// none of the three is there. `is_constrain_body` is passed by the official code but changes
/// no output.
pub fn part_masks(
    tensors: &std::collections::HashMap<String, Tensor>,
) -> Result<Option<(Tensor, Tensor)>> {
    let names = ["is_rhand", "is_lhand", "is_upper_body"];
    let found: Vec<Option<&Tensor>> = names.iter().map(|n| tensors.get(*n)).collect();
    let flag = |t: &Tensor| t.to_dtype(DType::F32)?.ne(0f32);
    match found.as_slice() {
        [Some(r), Some(l), Some(u)] => {
            let hands = flag(r)?.maximum(&flag(l)?)?;
            Ok(Some((hands, flag(u)?)))
        }
        [None, None, None] => Ok(None),
        _ => candle_core::bail!("part masks need all of {names:?}"),
    }
}

impl GaussianOutput {
    /// The official inference rules of `GSMLPDecoder` on body-part masks (`u8 [N]`, non-zero =
    /// in the part): hand Gaussians get opacity [`HAND_OPACITY`], upper-body scales are clamped
    /// to [`UPPER_BODY_MAX_SCALE`]. (`reconstruct::part_rules` applies the same rules on the
    /// prior's masks.)
    pub fn with_part_masks(self, hands: &Tensor, upper_body: &Tensor) -> Result<Self> {
        let n = self.opacities.dim(0)?;
        let mask = |m: &Tensor, width: usize| -> Result<Tensor> {
            m.to_dtype(DType::U8)?
                .ne(0u8)?
                .reshape((n, 1))?
                .broadcast_as((n, width))
        };
        let hand_opacity = Tensor::full(HAND_OPACITY, (n, 1), self.opacities.device())?;
        let opacities = mask(hands, 1)?.where_cond(&hand_opacity, &self.opacities)?;
        let clamped = self.scales.clamp(0f32, UPPER_BODY_MAX_SCALE)?;
        let scales = mask(upper_body, 3)?.where_cond(&clamped, &self.scales)?;
        Ok(Self {
            opacities,
            scales,
            ..self
        })
    }
}

/// [`GaussianOutput`] copied to plain row-major arrays.
#[derive(Debug, Clone, PartialEq)]
pub struct GaussianArrays {
    /// `[N·3]`.
    pub offsets: Vec<f32>,
    /// `[N·3]`.
    pub positions: Vec<f32>,
    /// `[N·3]`.
    pub scales: Vec<f32>,
    /// `[N·4]` (w, x, y, z).
    pub rotations: Vec<f32>,
    /// `[N]`.
    pub opacities: Vec<f32>,
    /// `[N·3]`.
    pub colors: Vec<f32>,
    /// `[N·q]`.
    pub features: Vec<f32>,
    /// Feature width `q`.
    pub feature_dim: usize,
}

fn flat(t: &Tensor) -> Result<Vec<f32>> {
    t.to_dtype(DType::F32)?.flatten_all()?.to_vec1::<f32>()
}

impl GaussianOutput {
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.positions.dim(0).unwrap_or(0)
    }

    /// Whether there are no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Copies every tensor to the CPU as f32 arrays.
    pub fn to_cpu_arrays(&self) -> Result<GaussianArrays> {
        Ok(GaussianArrays {
            offsets: flat(&self.offsets)?,
            positions: flat(&self.positions)?,
            scales: flat(&self.scales)?,
            rotations: flat(&self.rotations)?,
            opacities: flat(&self.opacities)?,
            colors: flat(&self.colors)?,
            features: flat(&self.features)?,
            feature_dim: self.features.dim(1)?,
        })
    }
}

/// The Gaussian head; `vb = root.pp("renderer")`.
#[derive(Debug, Clone)]
pub struct GsHead {
    cfg: GsHeadConfig,
    mlp: Vec<Linear>,
    shs: Linear,
    scaling: Linear,
    xyz: Linear,
    opacity: Linear,
    rotation: Linear,
    background_embedding: Tensor,
}

fn head(q: usize, out: usize, vb: VarBuilder, bias: Init) -> Result<Linear> {
    let w = vb.get_with_hints((out, q), "weight", candle_nn::init::DEFAULT_KAIMING_NORMAL)?;
    let b = vb.get_with_hints(out, "bias", bias)?;
    Ok(Linear::new(w, Some(b)))
}

impl GsHead {
    /// Builds `mlp_net.layers.{0,2,..}`, `gs_net.out_layers.*` and `background_embedding`.
    pub fn new(cfg: &GsHeadConfig, vb: VarBuilder) -> Result<Self> {
        let (q, n) = (cfg.gs_query_dim, cfg.n_neurons);
        let layers = vb.pp("mlp_net").pp("layers");
        let mut mlp = vec![linear(q, n, layers.pp(0))?];
        for i in 1..cfg.n_hidden_layers {
            mlp.push(linear(n, n, layers.pp(2 * i))?);
        }
        mlp.push(linear(n, q, layers.pp(2 * cfg.n_hidden_layers))?);
        let out = vb.pp("gs_net").pp("out_layers");
        let zero = Init::Const(0.0);
        let color = if cfg.use_rgb { 3 } else { 48 };
        Ok(Self {
            cfg: cfg.clone(),
            mlp,
            shs: head(q, color, out.pp("shs"), zero)?,
            scaling: head(q, 3, out.pp("scaling"), Init::Const(SCALING_BIAS_INIT))?,
            xyz: head(q, 3, out.pp("xyz"), zero)?,
            opacity: head(q, 1, out.pp("opacity"), Init::Const(OPACITY_BIAS_INIT))?,
            // The w = 1 bias is set by the checkpoint initialiser (no per-element Init exists).
            rotation: head(q, 4, out.pp("rotation"), zero)?,
            background_embedding: vb.get_with_hints(
                (3, cfg.background_width()),
                "background_embedding",
                Init::Randn {
                    mean: 0.0,
                    stdev: 0.02,
                },
            )?,
        })
    }

    /// Background feature for a grey level in {0 (black), 0.5 (grey), 1 (white)}:
    /// `[background_width]` (the official 128, which equals `gs_query_dim` in every released
    /// configuration).
    pub fn background_feature(&self, level: f32) -> Result<Tensor> {
        let idx = ((level / 0.5).round() as usize).min(2);
        self.background_embedding.get(idx)
    }

    /// `features [N, q]`, `anchors [N, 3]` → Gaussians.
    pub fn forward(&self, features: &Tensor, anchors: &Tensor) -> Result<GaussianOutput> {
        // On the CPU the head's activations stay f32 between its layers (bf16 weights still
        // run the bf16 kernel, which rounds each layer's input): the attributes are not rounded
        // to bf16 on their way, which the rotations' normalisation would amplify.
        let mut x = match features.device() {
            candle_core::Device::Cpu => features.to_dtype(DType::F32)?,
            _ => features.clone(),
        };
        let last = self.mlp.len() - 1;
        for (i, l) in self.mlp.iter().enumerate() {
            x = l.forward(&x)?;
            if i < last {
                x = candle_nn::ops::silu(&x)?;
            }
        }
        let to_f32 = |t: Tensor| t.to_dtype(DType::F32);
        let colors = to_f32(candle_nn::ops::sigmoid(&self.shs.forward(&x)?)?)?;
        let scales = to_f32(self.scaling.forward(&x)?)?
            .exp()?
            .clamp(0.0, self.cfg.clip_scaling)?;
        let offsets = ((to_f32(candle_nn::ops::sigmoid(&self.xyz.forward(&x)?)?)? - 0.5)?
            * self.cfg.xyz_offset_max_step)?;
        let opacities = to_f32(candle_nn::ops::sigmoid(&self.opacity.forward(&x)?)?)?;
        let r = to_f32(self.rotation.forward(&x)?)?;
        let norm = r
            .sqr()?
            .sum_keepdim(D::Minus1)?
            .sqrt()?
            .clamp(1e-12, f64::MAX)?;
        let rotations = r.broadcast_div(&norm)?;
        let positions = (anchors.to_dtype(DType::F32)? + &offsets)?;
        Ok(GaussianOutput {
            offsets,
            positions,
            scales,
            rotations,
            opacities,
            colors,
            features: to_f32(features.clone())?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::config::LhmppConfig;
    use candle_core::Device;

    #[test]
    fn activations_respect_the_official_ranges() {
        let cfg = LhmppConfig::tiny().gs_head;
        let vb = crate::model::checkpoint::seeded_var_builder(2, DType::F32, &Device::Cpu);
        let h = GsHead::new(&cfg, vb.pp("renderer")).unwrap();
        let feats = (Tensor::randn(0f32, 1.0, (200, cfg.gs_query_dim), &Device::Cpu).unwrap()
            * 10.0)
            .unwrap();
        let anchors = Tensor::randn(0f32, 1.0, (200, 3), &Device::Cpu).unwrap();
        let g = h.forward(&feats, &anchors).unwrap();
        let a = g.to_cpu_arrays().unwrap();
        assert!(a.scales.iter().all(|&s| (0.0..=0.05).contains(&s)));
        assert!(a.offsets.iter().all(|&o| (-0.5..=0.5).contains(&o)));
        assert!(a
            .colors
            .iter()
            .chain(&a.opacities)
            .all(|&c| (0.0..=1.0).contains(&c)));
        for q in a.rotations.chunks(4) {
            let n: f32 = q.iter().map(|v| v * v).sum();
            assert!((n - 1.0).abs() < 1e-4);
        }
        let anchors = anchors.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        for ((p, a0), o) in a.positions.iter().zip(&anchors).zip(&a.offsets) {
            assert!((p - a0 - o).abs() < 1e-6);
        }
        assert_eq!(a.features.len(), 200 * cfg.gs_query_dim);
    }

    #[test]
    fn part_masks_fix_hand_opacity_and_clamp_upper_body_scales() {
        let cfg = LhmppConfig::tiny().gs_head;
        let vb = crate::model::checkpoint::seeded_var_builder(3, DType::F32, &Device::Cpu);
        let h = GsHead::new(&cfg, vb.pp("renderer")).unwrap();
        let dev = Device::Cpu;
        let feats = Tensor::randn(0f32, 1.0, (6, cfg.gs_query_dim), &dev).unwrap();
        let g = h
            .forward(&feats, &Tensor::zeros((6, 3), DType::F32, &dev).unwrap())
            .unwrap();
        let before = g.to_cpu_arrays().unwrap();
        let hands = Tensor::new(&[1u8, 0, 0, 1, 0, 0], &dev).unwrap();
        let upper = Tensor::new(&[0u8, 1, 0, 1, 0, 0], &dev).unwrap();
        let after = g
            .with_part_masks(&hands, &upper)
            .unwrap()
            .to_cpu_arrays()
            .unwrap();
        for i in 0..6 {
            let hand = i == 0 || i == 3;
            let up = i == 1 || i == 3;
            let want = if hand {
                HAND_OPACITY
            } else {
                before.opacities[i]
            };
            assert_eq!(after.opacities[i], want);
            for k in 0..3 {
                let s = before.scales[3 * i + k];
                let want = if up { s.min(UPPER_BODY_MAX_SCALE) } else { s };
                assert_eq!(after.scales[3 * i + k], want);
            }
        }
        assert_eq!(after.colors, before.colors);
    }
}
