//! The official `config.json` as read: [`OfficialModelConfig`] and its subtrees (only the
//! fields the network needs; the others are ignored).

use std::path::Path;

use serde::Deserialize;

use super::HubError;

/// `transformer_decoder.point_backbone` of the official config.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct OfficialPointBackbone {
    /// Backbone type (`pv3`).
    #[serde(rename = "type")]
    pub kind: String,
    /// Input features (6 = xyz + normal).
    pub in_channels: usize,
    /// Serialization orders (`z`, `z-trans`, `hilbert`, `hilbert-trans`).
    pub order: Vec<String>,
    /// Pooling strides.
    pub stride: Vec<usize>,
    /// Blocks per encoder level.
    pub enc_depths: Vec<usize>,
    /// Channels per encoder level.
    pub enc_channels: Vec<usize>,
    /// Heads per encoder level.
    pub enc_num_head: Vec<usize>,
    /// Patch size per encoder level.
    pub enc_patch_size: Vec<usize>,
    /// Blocks per decoder level.
    pub dec_depths: Vec<usize>,
    /// Channels per decoder level.
    pub dec_channels: Vec<usize>,
    /// Heads per decoder level.
    pub dec_num_head: Vec<usize>,
    /// Patch size per decoder level.
    pub dec_patch_size: Vec<usize>,
    /// MLP ratio.
    pub mlp_ratio: f64,
    /// Relative position encoding (must be off).
    #[serde(default)]
    pub enable_rpe: bool,
    /// Random order shuffling (training only; must be off).
    #[serde(default)]
    pub shuffle_orders: bool,
}

/// `transformer_decoder.image_backbone` of the official config.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct OfficialImageBackbone {
    /// Backbone type (`vggt`).
    #[serde(rename = "type")]
    pub kind: String,
    /// Frame blocks.
    pub depth: usize,
    /// Attention order (`[frame]`).
    #[serde(default)]
    pub aa_order: Vec<String>,
    /// Frame-block width (`VGGTAggregator(embed_dim=1024)` when absent, as in the released
    /// config.json); must equal the encoder width, whose tokens the blocks read.
    #[serde(default)]
    pub embed_dim: Option<usize>,
    /// Frame-block heads (`VGGTAggregator(num_heads=16)` when absent).
    #[serde(default)]
    pub num_heads: Option<usize>,
    /// Frame-block MLP ratio (`VGGTAggregator(mlp_ratio=4.0)` when absent).
    #[serde(default)]
    pub mlp_ratio: Option<f64>,
}

impl OfficialImageBackbone {
    /// `VGGTAggregator`'s default `embed_dim`.
    pub const DEFAULT_EMBED_DIM: usize = 1024;
    /// `VGGTAggregator`'s default `num_heads`.
    pub const DEFAULT_NUM_HEADS: usize = 16;
    /// `VGGTAggregator`'s default `mlp_ratio`.
    pub const DEFAULT_MLP_RATIO: f64 = 4.0;
}

/// `transformer_decoder` of the official config.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct OfficialTransformerDecoder {
    /// Decoder type (`patch_efficient_pvt_mm_encoder_decoder_dense`).
    #[serde(rename = "type")]
    pub kind: String,
    /// PTv3 point backbone.
    pub point_backbone: OfficialPointBackbone,
    /// VGGT frame blocks.
    pub image_backbone: OfficialImageBackbone,
    /// ToMe merge ratio.
    pub merge_ratio: f64,
}

/// `gs_mlp_network_config` of the official config.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct OfficialGsMlp {
    /// MLP width.
    pub n_neurons: usize,
    /// Hidden layers.
    pub n_hidden_layers: usize,
    /// Activation (`silu`).
    pub activation: String,
}

/// `neural_renderer` of the official config.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct OfficialNeuralRenderer {
    /// Renderer type (`patch_4dptonly`).
    #[serde(rename = "type")]
    pub kind: String,
    /// Feature-map channels.
    pub enc_channels: usize,
    /// Token width after patchify.
    pub img_dim: usize,
    /// Patch side.
    pub enc_patch_size: usize,
    /// Unused SD3 blocks built by the official class (their weights are ignored).
    #[serde(default)]
    pub depth: usize,
    /// Pixel-shuffle factor of `mlp_pixelshuffle` (`PatchMLPPixelShuffleDPT4DecoderOnly`,
    /// default 2).
    #[serde(default)]
    pub pixel_shuffle_factor: Option<usize>,
}

/// `neural_renderer.type` of the DPT head (LHMPP-700M, LHMPPS-700M, LHMPP-700M-SMPLX-FREE).
pub const DPT_RENDERER_TYPE: &str = "patch_4dptonly";
/// `neural_renderer.type` of the one-group DPT head (LHMPPS-700M, depth 1).
pub const SHARED_DPT_RENDERER_TYPE: &str = "patch_dptonly";
/// `neural_renderer.type` of the pixel-shuffle head (LHMPP-700M-PixelShuffle).
pub const PIXEL_SHUFFLE_RENDERER_TYPE: &str = "mlp_pixelshuffle";
/// `PatchMLPPixelShuffleDPT4DecoderOnly`'s default `pixel_shuffle_factor`.
pub const DEFAULT_PIXEL_SHUFFLE_FACTOR: usize = 2;

/// `gs_clip_scaling`: a constant, or the `[start, mid, end, steps]` schedule whose final
/// value (index 2) is used at inference.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(untagged)]
pub enum ClipScaling {
    /// A constant clamp.
    Constant(f64),
    /// A schedule.
    Schedule(Vec<f64>),
}

impl ClipScaling {
    /// The clamp applied at inference.
    pub fn inference_value(&self) -> Option<f64> {
        match self {
            Self::Constant(v) => Some(*v),
            Self::Schedule(v) => v.get(2).or(v.last()).copied(),
        }
    }
}

/// The fields of the official `config.json` this crate reads (others are ignored).
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct OfficialModelConfig {
    /// Model class name (`LHMA4O`).
    #[serde(default)]
    pub model_name: Option<String>,
    /// DINOv2 variant (`dinov2_vitl14_reg`).
    pub encoder_model_name: String,
    /// Encoder width (1024).
    #[serde(default)]
    pub encoder_feat_dim: Option<usize>,
    /// Point/image fusion transformer.
    pub transformer_decoder: OfficialTransformerDecoder,
    /// Fusion type (`mm`).
    #[serde(default)]
    pub transformer_type: Option<String>,
    /// Joint attention heads.
    pub transformer_heads: usize,
    /// Joint width.
    pub transformer_dim: usize,
    /// Point-latent width (`transformer_dim: ${model.pcl_dim}` in the YAML): the output of
    /// `motion_embed_mlp`, whose hidden width is `pcl_dim // 4`. Absent: `transformer_dim`.
    #[serde(default)]
    pub pcl_dim: Option<usize>,
    /// Skinning type (`smplx_diffused_voxel`).
    #[serde(default)]
    pub smplx_type: Option<String>,
    /// Query points (160000).
    #[serde(default)]
    pub dense_sample_pts: Option<usize>,
    /// Canonical pose type (1 = hips ±π/9).
    #[serde(default)]
    pub cano_pose_type: Option<u32>,
    /// Point feature width entering the GS head.
    pub gs_query_dim: usize,
    /// RGB colours (not SH).
    pub gs_use_rgb: bool,
    /// GS head MLP.
    pub gs_mlp_network_config: OfficialGsMlp,
    /// Offset range.
    pub gs_xyz_offset_max_step: f64,
    /// Scale clamp.
    pub gs_clip_scaling: ClipScaling,
    /// Neural renderer.
    pub neural_renderer: OfficialNeuralRenderer,
    /// SMPL-X shape components (10).
    #[serde(default)]
    pub shape_param_dim: Option<usize>,
    /// Betas predicted by `shape_head` (10 in LHMPP-700M-PixelShuffle / -SMPLX-FREE).
    #[serde(default)]
    pub predict_shape_dim: Option<usize>,
    /// Whether the predicted betas shape the rendered body.
    #[serde(default)]
    pub use_pred_shape_for_render: Option<bool>,
    /// The `ShapeHead` settings (`dim_in`, `trunk_depth`, `num_iterations`, `num_heads`,
    /// `mlp_ratio`, `init_values`); present in the GS-supervised releases.
    #[serde(default)]
    pub shape_head: Option<serde_json::Value>,
}

impl OfficialModelConfig {
    /// Whether the checkpoint carries a `shape_head` (betas predicted from the image tokens).
    pub fn has_shape_head(&self) -> bool {
        self.shape_head
            .as_ref()
            .is_some_and(|v| v.as_object().is_some_and(|o| !o.is_empty()))
    }
}

pub(super) fn read_json(path: &Path) -> Result<serde_json::Value, HubError> {
    let text = std::fs::read_to_string(path).map_err(|source| HubError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    serde_json::from_str(&text).map_err(|e| HubError::Json {
        path: path.to_path_buf(),
        key: "(root)".into(),
        reason: e.to_string(),
    })
}

/// Parses an official `config.json` (flat, or wrapped in `{"config": {...}}`).
pub fn parse_config(path: &Path) -> Result<OfficialModelConfig, HubError> {
    let mut value = read_json(path)?;
    if let Some(inner) = value.get("config").filter(|v| v.is_object()) {
        if value.get("transformer_decoder").is_none() {
            value = inner.clone();
        }
    }
    serde_path_to_error::deserialize(value).map_err(|e| {
        let key = e.path().to_string();
        HubError::Json {
            path: path.to_path_buf(),
            key,
            reason: e.into_inner().to_string(),
        }
    })
}
