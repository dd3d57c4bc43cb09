//! Network configuration: `LhmppConfig` and its presets (`tiny`, `s`, `m`, `l`, `lhmpp-700m`).
//!
//! Field names mirror the official LHM++ config (`configs/train/LHMPP-any-view.yaml`);
//! `parameter_count` is computed from the config alone and checked against built models in tests.

use serde::{Deserialize, Serialize};

use super::dpt::DptConfig;
use super::point::PointBackboneConfig;
use super::shape_head::ShapeHeadConfig;

/// Errors from choosing or validating a configuration.
#[derive(Debug, thiserror::Error)]
pub enum ModelConfigError {
    /// The preset name is not one of [`LhmppConfig::PRESETS`].
    #[error(
        "unknown model preset `{0}` (known: tiny, s, m, l, lhmpp-700m, lhmpp-700m-pixelshuffle)"
    )]
    UnknownPreset(String),
    /// Two config fields disagree.
    #[error("invalid model config `{preset}`: {reason}")]
    Invalid {
        /// Preset name of the offending config.
        preset: String,
        /// What is wrong.
        reason: String,
    },
}

/// DINOv2 ViT image encoder (`encoder.model.*`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EncoderConfig {
    /// Token width (`encoder_feat_dim`, 1024 for ViT-L).
    pub embed_dim: usize,
    /// Number of ViT blocks.
    pub depth: usize,
    /// Attention heads.
    pub num_heads: usize,
    /// Patch size in pixels (14).
    pub patch_size: usize,
    /// Register tokens (4).
    pub num_register_tokens: usize,
    /// Side of the stored position-embedding grid (37 for the official 518-px training size).
    pub pos_embed_grid: usize,
    /// MLP hidden ratio.
    pub mlp_ratio: f64,
    /// LayerNorm epsilon (1e-6).
    pub layer_norm_eps: f64,
}

/// VGGT-style frame attention blocks (`transformer.image_backbone.*`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ImageBackboneConfig {
    /// Frame blocks: one per encoder PIT level (3 for the official model).
    pub depth: usize,
    /// Attention heads (width is the encoder's `embed_dim`).
    pub num_heads: usize,
    /// MLP hidden ratio.
    pub mlp_ratio: f64,
    /// 2D RoPE frequency base (100).
    pub rope_base: f64,
    /// LayerNorm on q and k per head.
    pub qk_norm: bool,
    /// LayerScale initial value (0.01).
    pub init_values: f64,
}

/// Multi-modal joint-attention PIT blocks (`transformer.pi_transformer_{enc,dec}.*`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TransformerConfig {
    /// Joint width (`transformer_dim`, 1024; must equal the encoder width).
    pub transformer_dim: usize,
    /// Joint attention heads (`transformer_heads`, 16).
    pub transformer_heads: usize,
    /// ToMe merge ratio of image tokens (0.5).
    pub merge_ratio: f64,
    /// Hidden width of `motion_embed_mlp` (official: `pcl_dim // 4`, 256).
    pub motion_embed_hidden: usize,
}

/// Gaussian head (`renderer.mlp_net`, `renderer.gs_net`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GsHeadConfig {
    /// Point feature width entering the head (`gs_query_dim`, 128 = last decoder channels).
    pub gs_query_dim: usize,
    /// MLP width (`gs_mlp_network_config.n_neurons`, 512).
    pub n_neurons: usize,
    /// Hidden layers of the MLP (2, SiLU).
    pub n_hidden_layers: usize,
    /// Predict RGB with a sigmoid instead of SH (`gs_use_rgb`).
    pub use_rgb: bool,
    /// Upper clamp of the scales in metres (0.05).
    pub clip_scaling: f64,
    /// Offset range: `(sigmoid − 0.5) · xyz_offset_max_step` (1.0).
    pub xyz_offset_max_step: f64,
    /// Width of `renderer.background_embedding` (`[3, width]`). The official renderer builds it
    /// 128 wide whatever `gs_query_dim` is (`gsplat_renderer.py`); `None` (this project's own
    /// presets) means `gs_query_dim`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub background_dim: Option<usize>,
}

impl GsHeadConfig {
    /// The official width of `renderer.background_embedding`, whatever `gs_query_dim` is.
    pub const OFFICIAL_BACKGROUND_DIM: usize = 128;

    /// Width of `renderer.background_embedding`.
    pub fn background_width(&self) -> usize {
        self.background_dim.unwrap_or(self.gs_query_dim)
    }
}

/// The whole LHM++ network.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LhmppConfig {
    /// Preset name (`tiny`, `s`, `m`, `l`, `lhmpp-700m`).
    pub preset: String,
    /// Input image height in pixels (multiple of the patch size).
    pub image_height: usize,
    /// Input image width in pixels (multiple of the patch size).
    pub image_width: usize,
    /// DINOv2 encoder.
    pub encoder: EncoderConfig,
    /// Frame blocks.
    pub image_backbone: ImageBackboneConfig,
    /// Joint PIT blocks.
    pub transformer: TransformerConfig,
    /// PTv3 point backbone.
    pub point_backbone: PointBackboneConfig,
    /// Gaussian head.
    pub gs_head: GsHeadConfig,
    /// DPT neural renderer.
    pub neural_renderer: DptConfig,
    /// The betas head of the GS-supervised releases (`shape_head.*`); `None`: none (betas come
    /// from the shape topic only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shape_head: Option<ShapeHeadConfig>,
}

/// Parameter counts per part of the network.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct ParameterCounts {
    /// `encoder.model.*`.
    pub encoder: usize,
    /// `transformer.image_backbone.*`.
    pub image_backbone: usize,
    /// `transformer.point_backbone.*`.
    pub point_backbone: usize,
    /// `transformer.pi_transformer_{enc,dec}.*` and `transformer.outnorm`.
    pub pit: usize,
    /// `motion_embed_mlp.*`.
    pub motion_embed: usize,
    /// `renderer.*` (GS head and background embedding).
    pub gs_head: usize,
    /// `neural_renderer.*`.
    pub neural_renderer: usize,
    /// `shape_head.*`.
    pub shape_head: usize,
}

impl ParameterCounts {
    /// Sum over all parts.
    pub fn total(&self) -> usize {
        self.encoder
            + self.image_backbone
            + self.point_backbone
            + self.pit
            + self.motion_embed
            + self.gs_head
            + self.neural_renderer
            + self.shape_head
    }
}

/// One PIT block's shape, in checkpoint order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PitBlockSpec {
    /// Point channels at this level (`pv_dim`).
    pub point_dim: usize,
    /// Last decoder block: no image update (AdaLN-Continuous context).
    pub context_pre_only: bool,
}

impl LhmppConfig {
    /// Preset names accepted by [`LhmppConfig::preset`].
    pub const PRESETS: [&'static str; 7] = [
        "tiny",
        "s",
        "m",
        "l",
        "lhmpp-700m",
        "lhmpp-700m-pixelshuffle",
        "lhmpp-700m-smplx-free",
    ];

    /// Looks a preset up by name.
    pub fn preset(name: &str) -> Result<Self, ModelConfigError> {
        match name {
            "tiny" => Ok(Self::tiny()),
            "s" => Ok(Self::s()),
            "m" => Ok(Self::m()),
            "l" => Ok(Self::l()),
            "lhmpp-700m" | "lhmpp_700m" | "700m" => Ok(Self::lhmpp_700m()),
            "lhmpp-700m-pixelshuffle" | "lhmpp_700m_pixelshuffle" => {
                Ok(Self::lhmpp_700m_pixelshuffle())
            }
            "lhmpp-700m-smplx-free" | "lhmpp_700m_smplx_free" => Ok(Self::lhmpp_700m_smplx_free()),
            other => Err(ModelConfigError::UnknownPreset(other.to_string())),
        }
    }

    /// Exactly the official LHMPP-700M shapes (840×504 input, 3+3 PIT blocks).
    pub fn lhmpp_700m() -> Self {
        Self {
            preset: "lhmpp-700m".into(),
            image_height: 840,
            image_width: 504,
            encoder: EncoderConfig {
                embed_dim: 1024,
                depth: 24,
                num_heads: 16,
                patch_size: 14,
                num_register_tokens: 4,
                pos_embed_grid: 37,
                mlp_ratio: 4.0,
                layer_norm_eps: 1e-6,
            },
            image_backbone: ImageBackboneConfig {
                depth: 3,
                num_heads: 16,
                mlp_ratio: 4.0,
                rope_base: 100.0,
                qk_norm: true,
                init_values: 0.01,
            },
            transformer: TransformerConfig {
                transformer_dim: 1024,
                transformer_heads: 16,
                merge_ratio: 0.5,
                motion_embed_hidden: 256,
            },
            point_backbone: PointBackboneConfig::lhmpp_700m(),
            gs_head: GsHeadConfig {
                gs_query_dim: 128,
                n_neurons: 512,
                n_hidden_layers: 2,
                use_rgb: true,
                clip_scaling: 0.05,
                xyz_offset_max_step: 1.0,
                background_dim: Some(GsHeadConfig::OFFICIAL_BACKGROUND_DIM),
            },
            neural_renderer: DptConfig::lhmpp_700m(),
            shape_head: None,
        }
    }

    /// The released GS-supervised LHMPP-700M-PixelShuffle (`configs/train/LHMPP-pixelshuffle.yaml`):
    /// the LHMPP-700M network with ToMe off (merge_ratio 0.0) and the `mlp_pixelshuffle`
    /// neural renderer (pixel_shuffle_factor 2), with the `shape_head` predicting the SMPL-X
    /// betas from the image tokens.
    pub fn lhmpp_700m_pixelshuffle() -> Self {
        let mut cfg = Self {
            preset: "lhmpp-700m-pixelshuffle".into(),
            neural_renderer: DptConfig::lhmpp_700m_pixelshuffle(),
            shape_head: Some(ShapeHeadConfig::lhmpp_700m()),
            ..Self::lhmpp_700m()
        };
        cfg.transformer.merge_ratio = 0.0;
        cfg
    }

    /// The released GS-supervised LHMPP-700M-SMPLX-FREE (`configs/train/LHMPP-anyview-SMPLX-FREE.yaml`,
    /// fork KuroTaiga/LHM_pp): the LHMPP-700M network exactly (merge_ratio 0.5, the
    /// `patch_4dptonly` DPT head) plus the `shape_head` predicting the betas, trained with its
    /// Gaussian RGB supervised.
    pub fn lhmpp_700m_smplx_free() -> Self {
        Self {
            preset: "lhmpp-700m-smplx-free".into(),
            shape_head: Some(ShapeHeadConfig::lhmpp_700m()),
            ..Self::lhmpp_700m()
        }
    }

    /// M: the official sizes (3+3 PIT blocks, about 700M parameters without the unused
    /// neural-renderer transformer blocks).
    pub fn m() -> Self {
        Self {
            preset: "m".into(),
            ..Self::lhmpp_700m()
        }
    }

    /// S: 2+2 PIT blocks (one point level less), about 500M parameters.
    pub fn s() -> Self {
        let mut cfg = Self {
            preset: "s".into(),
            ..Self::lhmpp_700m()
        };
        cfg.point_backbone = PointBackboneConfig::small();
        cfg.image_backbone.depth = 2;
        cfg
    }

    /// L: 4+4 PIT blocks (one point level more), about 900M parameters.
    pub fn l() -> Self {
        let mut cfg = Self {
            preset: "l".into(),
            ..Self::lhmpp_700m()
        };
        cfg.point_backbone = PointBackboneConfig::large();
        cfg.image_backbone.depth = 4;
        cfg
    }

    /// A tiny network for tests: 112×112 images, ViT width 64 with 2 blocks, 3+3 PIT blocks.
    pub fn tiny() -> Self {
        let pb = PointBackboneConfig::tiny();
        Self {
            preset: "tiny".into(),
            image_height: 112,
            image_width: 112,
            encoder: EncoderConfig {
                embed_dim: 64,
                depth: 2,
                num_heads: 2,
                patch_size: 14,
                num_register_tokens: 4,
                pos_embed_grid: 8,
                mlp_ratio: 4.0,
                layer_norm_eps: 1e-6,
            },
            image_backbone: ImageBackboneConfig {
                depth: pb.enc_channels.len() - 1,
                num_heads: 2,
                mlp_ratio: 4.0,
                rope_base: 100.0,
                qk_norm: true,
                init_values: 0.01,
            },
            transformer: TransformerConfig {
                transformer_dim: 64,
                transformer_heads: 2,
                merge_ratio: 0.5,
                motion_embed_hidden: 32,
            },
            gs_head: GsHeadConfig {
                gs_query_dim: pb.dec_channels[0],
                n_neurons: 64,
                n_hidden_layers: 2,
                use_rgb: true,
                clip_scaling: 0.05,
                xyz_offset_max_step: 1.0,
                background_dim: None,
            },
            point_backbone: pb,
            neural_renderer: DptConfig::tiny(),
            shape_head: None,
        }
    }

    /// Checks that the parts fit together (widths, depths, image size).
    pub fn validate(&self) -> Result<(), ModelConfigError> {
        let bad = |reason: String| ModelConfigError::Invalid {
            preset: self.preset.clone(),
            reason,
        };
        let e = &self.encoder;
        let pb = &self.point_backbone;
        if self.image_height % e.patch_size != 0 || self.image_width % e.patch_size != 0 {
            return Err(bad(format!(
                "image {}x{} is not a multiple of patch size {}",
                self.image_height, self.image_width, e.patch_size
            )));
        }
        if self.transformer.transformer_dim != e.embed_dim {
            return Err(bad(format!(
                "transformer_dim {} must equal encoder embed_dim {} (image tokens flow through both)",
                self.transformer.transformer_dim, e.embed_dim
            )));
        }
        if pb.enc_channels.len() < 2 || pb.dec_channels.len() + 1 != pb.enc_channels.len() {
            return Err(bad(format!(
                "point backbone needs L >= 2 encoder levels and L-1 decoder levels, got {} and {}",
                pb.enc_channels.len(),
                pb.dec_channels.len()
            )));
        }
        if self.image_backbone.depth != pb.enc_channels.len() - 1 {
            return Err(bad(format!(
                "image_backbone.depth {} must equal the encoder PIT levels {}",
                self.image_backbone.depth,
                pb.enc_channels.len() - 1
            )));
        }
        if self.gs_head.gs_query_dim != pb.dec_channels[0] {
            return Err(bad(format!(
                "gs_query_dim {} must equal the last decoder channels {}",
                self.gs_head.gs_query_dim, pb.dec_channels[0]
            )));
        }
        let head_dim = e.embed_dim / self.image_backbone.num_heads.max(1);
        if e.embed_dim % self.image_backbone.num_heads != 0 || head_dim % 4 != 0 {
            return Err(bad(format!("frame-block head dim {head_dim} must divide the width and be a multiple of 4 (2D RoPE)")));
        }
        if e.embed_dim % e.num_heads != 0
            || self.transformer.transformer_dim % self.transformer.transformer_heads != 0
        {
            return Err(bad("head counts must divide the widths".into()));
        }
        if let Some(sh) = &self.shape_head {
            if sh.dim_in != e.embed_dim || sh.num_heads == 0 || sh.dim_in % sh.num_heads != 0 {
                return Err(bad(format!(
                    "shape_head dim_in {} must equal the image tokens' width {} and be divisible \
                     by its {} heads",
                    sh.dim_in, e.embed_dim, sh.num_heads
                )));
            }
        }
        if !(0.0..1.0).contains(&self.transformer.merge_ratio) {
            return Err(bad(format!(
                "merge_ratio {} not in [0, 1)",
                self.transformer.merge_ratio
            )));
        }
        Ok(())
    }

    /// Patch grid (rows, cols) of one input image.
    pub fn patch_grid(&self) -> (usize, usize) {
        (
            self.image_height / self.encoder.patch_size,
            self.image_width / self.encoder.patch_size,
        )
    }

    /// Encoder PIT blocks (`pi_transformer_enc.{i}`), in order.
    pub fn pit_encoder_blocks(&self) -> Vec<PitBlockSpec> {
        self.point_backbone.enc_channels[1..]
            .iter()
            .map(|&c| PitBlockSpec {
                point_dim: c,
                context_pre_only: false,
            })
            .collect()
    }

    /// Decoder PIT blocks (`pi_transformer_dec.{j}`), in order: deepest level first; the
    /// last one is `context_pre_only`.
    pub fn pit_decoder_blocks(&self) -> Vec<PitBlockSpec> {
        let n = self.point_backbone.dec_channels.len();
        (0..n)
            .map(|j| PitBlockSpec {
                point_dim: self.point_backbone.dec_channels[n - 1 - j],
                context_pre_only: j + 1 == n,
            })
            .collect()
    }

    /// Parameter counts per part, from the config alone.
    pub fn parameter_count(&self) -> ParameterCounts {
        ParameterCounts {
            encoder: self.encoder_params(),
            image_backbone: self.image_backbone_params(),
            point_backbone: point_backbone_params(&self.point_backbone),
            pit: self.pit_params(),
            motion_embed: linear(self.encoder.embed_dim, self.transformer.motion_embed_hidden)
                + linear(
                    self.transformer.motion_embed_hidden,
                    self.transformer.transformer_dim,
                ),
            gs_head: self.gs_head_params(),
            neural_renderer: dpt_params(&self.neural_renderer),
            shape_head: self
                .shape_head
                .as_ref()
                .map_or(0, ShapeHeadConfig::parameter_count),
        }
    }

    fn encoder_params(&self) -> usize {
        let e = &self.encoder;
        let c = e.embed_dim;
        let hidden = (c as f64 * e.mlp_ratio) as usize;
        let block = 2 * c
            + linear(c, 3 * c)
            + linear(c, c)
            + c
            + 2 * c
            + linear(c, hidden)
            + linear(hidden, c)
            + c;
        c + (1 + e.pos_embed_grid * e.pos_embed_grid) * c
            + e.num_register_tokens * c
            + 3 * e.patch_size * e.patch_size * c
            + c
            + e.depth * block
            + 2 * c
    }

    fn image_backbone_params(&self) -> usize {
        let ib = &self.image_backbone;
        let c = self.encoder.embed_dim;
        let hd = c / ib.num_heads;
        let hidden = (c as f64 * ib.mlp_ratio) as usize;
        let qk = if ib.qk_norm { 4 * hd } else { 0 };
        let block = 2 * c
            + linear(c, 3 * c)
            + qk
            + linear(c, c)
            + c
            + 2 * c
            + linear(c, hidden)
            + linear(hidden, c)
            + c;
        2 * c + 2 * self.encoder.num_register_tokens * c + ib.depth * block
    }

    fn pit_params(&self) -> usize {
        let d = self.transformer.transformer_dim;
        let ctx = self.encoder.embed_dim;
        let hd = d / self.transformer.transformer_heads;
        let block = |spec: PitBlockSpec| {
            let pv = spec.point_dim;
            let ff = |i: usize, inner: usize, o: usize| linear(i, inner) + linear(inner, o);
            let mut n = linear(d, 6 * d);
            n += linear(d, if spec.context_pre_only { 2 * d } else { 6 * d });
            n += 7 * linear(d, d) + 4 * hd;
            n += ff(d, 4 * d, d);
            if !spec.context_pre_only {
                n += linear(d, d) + ff(d, 4 * d, d);
            }
            n += ff(pv, 4 * pv, d) + ff(ctx, 4 * pv, d) + ff(d, 4 * d, pv);
            n
        };
        let blocks: usize = self
            .pit_encoder_blocks()
            .into_iter()
            .chain(self.pit_decoder_blocks())
            .map(block)
            .sum();
        blocks + 2 * self.gs_head.gs_query_dim
    }

    fn gs_head_params(&self) -> usize {
        let g = &self.gs_head;
        let (q, n) = (g.gs_query_dim, g.n_neurons);
        let mlp = linear(q, n) + g.n_hidden_layers.saturating_sub(1) * linear(n, n) + linear(n, q);
        let color = if g.use_rgb { 3 } else { 48 };
        mlp + linear(q, color + 3 + 3 + 1 + 4) + 3 * g.background_width()
    }
}

/// Parameters of a biased `Linear(i → o)`.
fn linear(i: usize, o: usize) -> usize {
    i * o + o
}

/// Parameters of the PTv3 point backbone (stem, encoder, decoder), official layout.
pub fn point_backbone_params(pb: &PointBackboneConfig) -> usize {
    let block = |c: usize| {
        let h = (c as f64 * pb.mlp_ratio) as usize;
        (27 * c * c + c)
            + linear(c, c)
            + 2 * c
            + 2 * c
            + linear(c, 3 * c)
            + linear(c, c)
            + 2 * c
            + linear(c, h)
            + linear(h, c)
    };
    let c0 = pb.enc_channels[0];
    let mut n = linear(pb.in_channels, c0) + 2 * c0;
    for (l, (&c, &depth)) in pb.enc_channels.iter().zip(&pb.enc_depths).enumerate() {
        if l > 0 {
            n += linear(pb.enc_channels[l - 1], c) + 2 * c;
        }
        n += depth * block(c);
    }
    let nd = pb.dec_channels.len();
    for (l, (&c, &depth)) in pb.dec_channels.iter().zip(&pb.dec_depths).enumerate() {
        let deeper = if l + 1 == nd {
            pb.enc_channels[nd]
        } else {
            pb.dec_channels[l + 1]
        };
        let skip = pb.enc_channels[l];
        n += linear(deeper, c) + 2 * c + linear(skip, c) + 2 * c + depth * block(c);
    }
    n
}

/// Parameters of the DPT neural renderer used at inference (patchify + DPT head).
pub fn dpt_params(d: &DptConfig) -> usize {
    let dim_in = d.head_dim();
    let f = d.features;
    let oc = d.out_channels;
    let conv = |i: usize, o: usize, k: usize| i * o * k * k + o;
    let mut n = d.embed_dim * d.patch_size * d.patch_size * d.in_channels;
    n += 2 * dim_in;
    n += oc.iter().map(|&o| conv(dim_in, o, 1)).sum::<usize>();
    n += conv(oc[0], oc[0], 4) + conv(oc[1], oc[1], 2) + conv(oc[3], oc[3], 3);
    n += oc.iter().map(|&o| o * f * 9).sum::<usize>();
    // refinenet4 (one residual unit), refinenet3 and refinenet2
    n += 2 * (conv(f, f, 1) + 4 * conv(f, f, 3)) + conv(f, f, 1) + 2 * conv(f, f, 3);
    n += match d.pixel_shuffle {
        None => {
            conv(f, f, 1)
                + 4 * conv(f, f, 3)
                + conv(f, f / 2, 3)
                + conv(f / 2, 32, 3)
                + conv(32, 4, 1)
        }
        Some(u) => conv(f, f, 1) + conv(f, 4 * u * u, 1),
    };
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_preset_validates() {
        for name in LhmppConfig::PRESETS {
            LhmppConfig::preset(name).unwrap().validate().unwrap();
        }
    }

    #[test]
    fn official_parts_match_the_reference_state_dict() {
        // Sums over /work/shared/reference/lhmpp_700M_state_dict_keys.txt, per prefix.
        let p = LhmppConfig::lhmpp_700m().parameter_count();
        assert_eq!(p.encoder, 304_371_712);
        assert_eq!(p.image_backbone, 37_805_824);
        assert_eq!(p.point_backbone, 111_660_736);
        assert_eq!(p.pit, 270_368_256);
        assert_eq!(p.motion_embed, 525_568);
        assert_eq!(p.gs_head, 396_558);
        assert_eq!(p.neural_renderer, 13_516_004);
    }

    #[test]
    fn pixelshuffle_renderer_counts_its_own_tail() {
        // 700M DPT head minus refinenet1 (128·128 + 4·(9·128·128 + 128) + 128) and the output
        // convolutions, plus l1_residual_fuse (128·128 + 128) and refinenet1_ps_mlp (16·128 + 16).
        let dpt = LhmppConfig::lhmpp_700m().parameter_count().neural_renderer;
        let ps = LhmppConfig::lhmpp_700m_pixelshuffle()
            .parameter_count()
            .neural_renderer;
        let refine1 = 128 * 128 + 128 + 4 * (9 * 128 * 128 + 128);
        let outputs = (9 * 128 * 64 + 64) + (9 * 64 * 32 + 32) + (32 * 4 + 4);
        assert_eq!(
            ps,
            dpt - refine1 - outputs + (128 * 128 + 128) + (128 * 16 + 16)
        );
    }

    #[test]
    fn presets_grow_from_s_to_l() {
        let s = LhmppConfig::s().parameter_count().total();
        let m = LhmppConfig::m().parameter_count().total();
        let l = LhmppConfig::l().parameter_count().total();
        assert!(s < m && m < l, "{s} {m} {l}");
        assert_eq!(
            LhmppConfig::s().pit_encoder_blocks().len()
                + LhmppConfig::s().pit_decoder_blocks().len(),
            4
        );
        assert_eq!(
            LhmppConfig::l().pit_encoder_blocks().len()
                + LhmppConfig::l().pit_decoder_blocks().len(),
            8
        );
    }

    #[test]
    fn unknown_preset_is_named_in_the_error() {
        let err = LhmppConfig::preset("xl").unwrap_err().to_string();
        assert!(err.contains("xl"), "{err}");
    }
}
