//! Hub folders: the layout of the released LHM++ checkpoints (`3DAIGC/LHMPP-700M`), a folder
//! holding `config.json` (the HuggingFace `PyTorchModelHubMixin` config, i.e. the YAML
//! `model:` section of `configs/train/LHMPP-any-view.yaml`) and `model.safetensors` (or a
//! sharded `model.safetensors.index.json` with its shards).
//!
//! `config.json` is parsed into [`OfficialModelConfig`] (only the fields the network needs;
//! the others are ignored) and turned into an [`LhmppConfig`] starting from the `lhmpp-700m`
//! preset: every field the file sets is checked against what our network supports
//! (unsupported values are errors naming the field and the file) and every value that differs
//! from the preset is reported by its official name. The weights are then validated against the
//! derived config (all mismatches at once) and memory-mapped.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use candle_core::{DType, Device};
use candle_nn::VarBuilder;
use serde::Deserialize;

use super::checkpoint::{
    check_files, load_var_builder, load_var_builder_from_files, CheckpointError, CheckpointSummary,
};
use super::config::{GsHeadConfig, LhmppConfig};
use super::point::SerializationOrder;
use super::rgb_kind::RgbKind;
use super::shape_head::ShapeHeadConfig;

/// Config file of a hub folder.
pub const CONFIG_FILE: &str = "config.json";
/// Single-file weights of a hub folder.
pub const WEIGHTS_FILE: &str = "model.safetensors";
/// Index of sharded weights of a hub folder.
pub const INDEX_FILE: &str = "model.safetensors.index.json";

/// Errors from opening a hub folder.
#[derive(Debug, thiserror::Error)]
pub enum HubError {
    /// A required file is absent.
    #[error("hub folder {folder}: missing {what}")]
    Missing {
        /// The folder.
        folder: PathBuf,
        /// What is missing (file names).
        what: String,
    },
    /// The checkpoint path does not exist.
    #[error(
        "checkpoint {0} does not exist (expected a safetensors file, or a hub folder with \
             config.json and model.safetensors: see the README section \"Official LHM++ weights\")"
    )]
    NotFound(PathBuf),
    /// Reading a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A JSON file is malformed or lacks a field; `key` is the path of the offending field.
    #[error("{path}: key `{key}`: {reason}")]
    Json {
        /// The file.
        path: PathBuf,
        /// Path of the offending key (`transformer_decoder.point_backbone.stride`).
        key: String,
        /// What is wrong.
        reason: String,
    },
    /// The config asks for something our network does not implement.
    #[error("{path}: unsupported by this network:\n  {}", fields.join("\n  "))]
    Unsupported {
        /// The config file.
        path: PathBuf,
        /// One line per unsupported field, naming it and its value.
        fields: Vec<String>,
    },
    /// The derived config is invalid, or the weights do not match it.
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
}

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

/// An opened hub folder: parsed config, derived network config and the weight files.
#[derive(Debug, Clone)]
pub struct HubFolder {
    /// The folder.
    pub dir: PathBuf,
    /// `config.json` as parsed.
    pub official: OfficialModelConfig,
    /// Our network config derived from it.
    pub config: LhmppConfig,
    /// Fields that differ from the `lhmpp-700m` preset: `name: file value (preset value)`.
    pub differences: Vec<String>,
    /// Weight files (one, or the shards in index order).
    pub weights: Vec<PathBuf>,
}

impl HubFolder {
    /// Opens `dir`: parses `config.json`, derives the network config and finds the weights.
    /// A folder without `config.json` but with `step_N/` checkpoints (the LHM release layout)
    /// opens the highest step.
    pub fn open(dir: &Path) -> Result<Self, HubError> {
        let resolved = latest_step(dir);
        let dir = resolved.as_deref().unwrap_or(dir);
        let config_path = dir.join(CONFIG_FILE);
        if !config_path.is_file() {
            return Err(HubError::Missing {
                folder: dir.to_path_buf(),
                what: CONFIG_FILE.into(),
            });
        }
        let official = parse_config(&config_path)?;
        let (config, differences) = derive_config(&official, &config_path, dir)?;
        let weights = find_weights(dir)?;
        Ok(Self {
            dir: dir.to_path_buf(),
            official,
            config,
            differences,
            weights,
        })
    }

    /// Validates the weights against the derived config from their headers only and
    /// summarises them (tensor and parameter counts, ignored extras, stored dtypes).
    pub fn check(&self) -> Result<CheckpointSummary, HubError> {
        Ok(check_files(&self.weights, &self.dir, &self.config)?)
    }

    /// Validates the weights against the derived config (all mismatches at once) and returns a
    /// `VarBuilder` over them in `dtype` on `device`.
    pub fn var_builder(
        &self,
        dtype: DType,
        device: &Device,
    ) -> Result<VarBuilder<'static>, HubError> {
        Ok(load_var_builder_from_files(
            &self.weights,
            &self.dir,
            &self.config,
            dtype,
            device,
        )?)
    }
}

/// A loaded checkpoint: its network config, its tensors and a description for logs.
pub struct LoadedCheckpoint {
    /// The network config (the preset's, or derived from a hub folder's `config.json`).
    pub config: LhmppConfig,
    /// The validated tensors.
    pub var_builder: VarBuilder<'static>,
    /// Where the weights came from.
    pub description: String,
    /// The official `neural_renderer.type` of a hub folder (`None` for a single file).
    pub neural_renderer_type: Option<String>,
    /// Whether the hub folder's network carries the betas `shape_head` of the GS-supervised
    /// releases (LHMPP-700M-PixelShuffle, -SMPLX-FREE); false for a single file.
    pub shape_head: bool,
}

impl LoadedCheckpoint {
    /// What the Gaussians' RGB of this checkpoint is: by `neural_renderer.type` and `shape_head`
    /// for a hub folder ([`RgbKind::of_hub`]), by preset for a single file.
    pub fn rgb_kind(&self) -> RgbKind {
        match &self.neural_renderer_type {
            Some(kind) => RgbKind::of_hub(kind, self.shape_head),
            None => RgbKind::of_preset(&self.config.preset),
        }
    }
}

/// Loads `path` the way the node does: a hub folder (config from its `config.json`) or a
/// single safetensors file validated against `preset`.
pub fn load_checkpoint(
    path: &Path,
    preset: &LhmppConfig,
    dtype: DType,
    device: &Device,
) -> Result<LoadedCheckpoint, HubError> {
    if !path.exists() {
        return Err(HubError::NotFound(path.to_path_buf()));
    }
    if path.is_dir() {
        let hub = HubFolder::open(path)?;
        if hub.official.has_shape_head() {
            tracing::info!(
                "{}: the checkpoint's shape_head predicts the SMPL-X betas from the image tokens",
                path.join(CONFIG_FILE).display()
            );
        }
        for d in &hub.differences {
            tracing::warn!(
                "{}: differs from the lhmpp-700m preset: {d}",
                path.join(CONFIG_FILE).display()
            );
        }
        if hub.config.preset != preset.preset {
            tracing::info!(
                "{}: using the config of the hub folder (`{}`) instead of preset `{}`",
                path.display(),
                hub.config.preset,
                preset.preset
            );
        }
        let var_builder = hub.var_builder(dtype, device)?;
        return Ok(LoadedCheckpoint {
            description: format!(
                "{} (hub folder, {} weight file(s))",
                path.display(),
                hub.weights.len()
            ),
            neural_renderer_type: Some(hub.official.neural_renderer.kind.clone()),
            shape_head: hub.official.has_shape_head(),
            config: hub.config,
            var_builder,
        });
    }
    let var_builder = load_var_builder(path, preset, dtype, device)?;
    Ok(LoadedCheckpoint {
        config: preset.clone(),
        var_builder,
        description: path.display().to_string(),
        neural_renderer_type: None,
        shape_head: false,
    })
}

fn read_json(path: &Path) -> Result<serde_json::Value, HubError> {
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

/// Records `name` when `new` differs from the preset value in `slot`, then stores it.
fn set<T: PartialEq + std::fmt::Debug>(diffs: &mut Vec<String>, name: &str, slot: &mut T, new: T) {
    if *slot != new {
        diffs.push(format!("{name}: {new:?} (lhmpp-700m preset: {slot:?})"));
        *slot = new;
    }
}

/// DINOv2 variants: (embed dim, depth, heads).
fn dinov2_variant(name: &str) -> Option<(usize, usize, usize)> {
    match name {
        "dinov2_vits14_reg" => Some((384, 12, 6)),
        "dinov2_vitb14_reg" => Some((768, 12, 12)),
        "dinov2_vitl14_reg" => Some((1024, 24, 16)),
        _ => None,
    }
}

fn order_of(name: &str) -> Option<SerializationOrder> {
    match name {
        "z" => Some(SerializationOrder::Z),
        "z-trans" => Some(SerializationOrder::ZTrans),
        "hilbert" => Some(SerializationOrder::Hilbert),
        "hilbert-trans" => Some(SerializationOrder::HilbertTrans),
        _ => None,
    }
}

/// Derives our config from the official one, starting from the `lhmpp-700m` preset (which
/// supplies what `config.json` does not hold: DINOv2 internals, the 840×504 input, the DPT
/// head widths). Returns the config and the fields that differ from the preset.
pub fn derive_config(
    o: &OfficialModelConfig,
    config_path: &Path,
    dir: &Path,
) -> Result<(LhmppConfig, Vec<String>), HubError> {
    derive_config_with_encoder(o, None, config_path, dir)
}

/// [`derive_config`] with the DINOv2 widths `(embed dim, depth, heads)` given instead of read
/// from `encoder_model_name` (`None`: from the name): for official configs built with a DINOv2
/// that is not a released variant, such as the reduced `dinov2_fixture14_reg` of the official
/// forward fixture (`scripts/parity/official/`).
pub fn derive_config_with_encoder(
    o: &OfficialModelConfig,
    encoder: Option<(usize, usize, usize)>,
    config_path: &Path,
    dir: &Path,
) -> Result<(LhmppConfig, Vec<String>), HubError> {
    let mut cfg = LhmppConfig::lhmpp_700m();
    let mut d = Vec::new();
    let mut unsupported = Vec::new();
    let mut require = |ok: bool, field: &str, value: &dyn std::fmt::Debug, want: &str| {
        if !ok {
            unsupported.push(format!("{field} = {value:?} (supported: {want})"));
        }
    };
    match encoder.or_else(|| dinov2_variant(&o.encoder_model_name)) {
        Some((dim, depth, heads)) => {
            if o.encoder_model_name != "dinov2_vitl14_reg" {
                d.push(format!(
                    "encoder_model_name: {:?} (lhmpp-700m preset: \"dinov2_vitl14_reg\")",
                    o.encoder_model_name
                ));
            }
            cfg.encoder.embed_dim = dim;
            cfg.encoder.depth = depth;
            cfg.encoder.num_heads = heads;
        }
        None => require(
            false,
            "encoder_model_name",
            &o.encoder_model_name,
            "dinov2_vit{s,b,l}14_reg",
        ),
    }
    if let Some(dim) = o.encoder_feat_dim {
        require(
            dim == cfg.encoder.embed_dim,
            "encoder_feat_dim",
            &dim,
            "the width of encoder_model_name",
        );
    }
    let td = &o.transformer_decoder;
    require(
        td.kind == "patch_efficient_pvt_mm_encoder_decoder_dense",
        "transformer_decoder.type",
        &td.kind,
        "patch_efficient_pvt_mm_encoder_decoder_dense",
    );
    if let Some(t) = &o.transformer_type {
        require(t == "mm", "transformer_type", t, "mm");
    }
    let pb = &td.point_backbone;
    require(
        pb.kind == "pv3",
        "transformer_decoder.point_backbone.type",
        &pb.kind,
        "pv3",
    );
    require(
        !pb.enable_rpe,
        "transformer_decoder.point_backbone.enable_rpe",
        &pb.enable_rpe,
        "false",
    );
    let orders: Vec<Option<SerializationOrder>> = pb.order.iter().map(|s| order_of(s)).collect();
    require(
        !orders.is_empty() && orders.iter().all(Option::is_some),
        "transformer_decoder.point_backbone.order",
        &pb.order,
        "z, z-trans, hilbert, hilbert-trans",
    );
    if pb.shuffle_orders {
        tracing::warn!(
            "{}: shuffle_orders is a training option; orders are used as listed",
            config_path.display()
        );
    }
    let p = &mut cfg.point_backbone;
    let name = |f: &str| format!("transformer_decoder.point_backbone.{f}");
    set(
        &mut d,
        &name("in_channels"),
        &mut p.in_channels,
        pb.in_channels,
    );
    set(
        &mut d,
        &name("order"),
        &mut p.order,
        orders.into_iter().flatten().collect(),
    );
    set(&mut d, &name("stride"), &mut p.stride, pb.stride.clone());
    set(
        &mut d,
        &name("enc_depths"),
        &mut p.enc_depths,
        pb.enc_depths.clone(),
    );
    set(
        &mut d,
        &name("enc_channels"),
        &mut p.enc_channels,
        pb.enc_channels.clone(),
    );
    set(
        &mut d,
        &name("enc_num_head"),
        &mut p.enc_num_head,
        pb.enc_num_head.clone(),
    );
    set(
        &mut d,
        &name("enc_patch_size"),
        &mut p.enc_patch_size,
        pb.enc_patch_size.clone(),
    );
    set(
        &mut d,
        &name("dec_depths"),
        &mut p.dec_depths,
        pb.dec_depths.clone(),
    );
    set(
        &mut d,
        &name("dec_channels"),
        &mut p.dec_channels,
        pb.dec_channels.clone(),
    );
    set(
        &mut d,
        &name("dec_num_head"),
        &mut p.dec_num_head,
        pb.dec_num_head.clone(),
    );
    set(
        &mut d,
        &name("dec_patch_size"),
        &mut p.dec_patch_size,
        pb.dec_patch_size.clone(),
    );
    set(&mut d, &name("mlp_ratio"), &mut p.mlp_ratio, pb.mlp_ratio);
    let ib = &td.image_backbone;
    require(
        ib.kind == "vggt",
        "transformer_decoder.image_backbone.type",
        &ib.kind,
        "vggt",
    );
    require(
        ib.aa_order.is_empty() || ib.aa_order == ["frame"],
        "transformer_decoder.image_backbone.aa_order",
        &ib.aa_order,
        "[frame]",
    );
    set(
        &mut d,
        "transformer_decoder.image_backbone.depth",
        &mut cfg.image_backbone.depth,
        ib.depth,
    );
    // The frame blocks are `VGGTAggregator(**image_backbone)`: width and heads come from that
    // dict (defaults 1024 and 16), not from the encoder or the joint attention.
    let frame_dim = ib
        .embed_dim
        .unwrap_or(OfficialImageBackbone::DEFAULT_EMBED_DIM);
    require(
        frame_dim == cfg.encoder.embed_dim,
        "transformer_decoder.image_backbone.embed_dim",
        &frame_dim,
        "the width of encoder_model_name (the frame blocks read its tokens; absent = 1024)",
    );
    set(
        &mut d,
        "transformer_decoder.image_backbone.num_heads",
        &mut cfg.image_backbone.num_heads,
        ib.num_heads
            .unwrap_or(OfficialImageBackbone::DEFAULT_NUM_HEADS),
    );
    set(
        &mut d,
        "transformer_decoder.image_backbone.mlp_ratio",
        &mut cfg.image_backbone.mlp_ratio,
        ib.mlp_ratio
            .unwrap_or(OfficialImageBackbone::DEFAULT_MLP_RATIO),
    );
    set(
        &mut d,
        "transformer_decoder.merge_ratio",
        &mut cfg.transformer.merge_ratio,
        td.merge_ratio,
    );
    set(
        &mut d,
        "transformer_heads",
        &mut cfg.transformer.transformer_heads,
        o.transformer_heads,
    );
    set(
        &mut d,
        "transformer_dim",
        &mut cfg.transformer.transformer_dim,
        o.transformer_dim,
    );
    // `motion_embed_mlp = Linear(encoder_feat_dim, pcl_dim // 4), SiLU, Linear(pcl_dim // 4,
    // pcl_dim)`; its output is the AdaLN conditioning of the joint blocks (width transformer_dim).
    let pcl_dim = o.pcl_dim.unwrap_or(o.transformer_dim);
    require(
        pcl_dim == o.transformer_dim,
        "pcl_dim",
        &pcl_dim,
        "transformer_dim (motion_embed_mlp's output conditions the joint blocks)",
    );
    set(
        &mut d,
        "pcl_dim // 4 (motion_embed_mlp hidden)",
        &mut cfg.transformer.motion_embed_hidden,
        pcl_dim / 4,
    );
    set(
        &mut d,
        "gs_query_dim",
        &mut cfg.gs_head.gs_query_dim,
        o.gs_query_dim,
    );
    set(&mut d, "gs_use_rgb", &mut cfg.gs_head.use_rgb, o.gs_use_rgb);
    // `renderer.background_embedding = nn.Parameter(torch.zeros(3, 128))`, whatever gs_query_dim.
    cfg.gs_head.background_dim = Some(GsHeadConfig::OFFICIAL_BACKGROUND_DIM);
    let mlp = &o.gs_mlp_network_config;
    require(
        mlp.activation == "silu",
        "gs_mlp_network_config.activation",
        &mlp.activation,
        "silu",
    );
    set(
        &mut d,
        "gs_mlp_network_config.n_neurons",
        &mut cfg.gs_head.n_neurons,
        mlp.n_neurons,
    );
    set(
        &mut d,
        "gs_mlp_network_config.n_hidden_layers",
        &mut cfg.gs_head.n_hidden_layers,
        mlp.n_hidden_layers,
    );
    set(
        &mut d,
        "gs_xyz_offset_max_step",
        &mut cfg.gs_head.xyz_offset_max_step,
        o.gs_xyz_offset_max_step,
    );
    match o.gs_clip_scaling.inference_value() {
        Some(v) => set(&mut d, "gs_clip_scaling", &mut cfg.gs_head.clip_scaling, v),
        None => require(
            false,
            "gs_clip_scaling",
            &o.gs_clip_scaling,
            "a number or [a, b, c, steps]",
        ),
    }
    let nr = &o.neural_renderer;
    require(
        [
            DPT_RENDERER_TYPE,
            SHARED_DPT_RENDERER_TYPE,
            PIXEL_SHUFFLE_RENDERER_TYPE,
        ]
        .contains(&nr.kind.as_str()),
        "neural_renderer.type",
        &nr.kind,
        "patch_4dptonly, patch_dptonly, mlp_pixelshuffle",
    );
    if nr.kind == SHARED_DPT_RENDERER_TYPE {
        // `PatchDPTDecoderOnly` hands the head one token list and indexes it with
        // `intermediate_mapping[depth]`: only depth 1 ([0, 0, 0, 0]) runs.
        require(
            nr.depth == 1,
            "neural_renderer.depth",
            &nr.depth,
            "1 with patch_dptonly",
        );
        set(
            &mut d,
            "neural_renderer.type patch_dptonly (the whole tokens feed the four DPT inputs)",
            &mut cfg.neural_renderer.shared_tokens,
            true,
        );
    }
    if nr.kind == PIXEL_SHUFFLE_RENDERER_TYPE {
        let u = nr
            .pixel_shuffle_factor
            .unwrap_or(DEFAULT_PIXEL_SHUFFLE_FACTOR);
        require(u >= 1, "neural_renderer.pixel_shuffle_factor", &u, ">= 1");
        set(
            &mut d,
            "neural_renderer.type mlp_pixelshuffle, pixel_shuffle_factor",
            &mut cfg.neural_renderer.pixel_shuffle,
            Some(u),
        );
    }
    set(
        &mut d,
        "neural_renderer.enc_channels",
        &mut cfg.neural_renderer.in_channels,
        nr.enc_channels,
    );
    set(
        &mut d,
        "neural_renderer.img_dim",
        &mut cfg.neural_renderer.embed_dim,
        nr.img_dim,
    );
    set(
        &mut d,
        "neural_renderer.enc_patch_size",
        &mut cfg.neural_renderer.patch_size,
        nr.enc_patch_size,
    );
    if let Some(t) = &o.smplx_type {
        require(
            t == "smplx_diffused_voxel" || t == "smplx_voxel",
            "smplx_type",
            t,
            "smplx_diffused_voxel",
        );
    }
    if o.has_shape_head() {
        match shape_head_config(o, cfg.encoder.embed_dim) {
            Ok(sh) => cfg.shape_head = Some(sh),
            Err(reason) => unsupported.push(reason),
        }
    }
    if !unsupported.is_empty() {
        return Err(HubError::Unsupported {
            path: config_path.to_path_buf(),
            fields: unsupported,
        });
    }
    // A released network exactly (LHMPP-700M, -PixelShuffle, -SMPLX-FREE) keeps its preset
    // name; anything else is named after the folder.
    let released = [
        LhmppConfig::lhmpp_700m(),
        LhmppConfig::lhmpp_700m_pixelshuffle(),
        LhmppConfig::lhmpp_700m_smplx_free(),
    ]
    .into_iter()
    .find(|p| {
        *p == LhmppConfig {
            preset: p.preset.clone(),
            ..cfg.clone()
        }
    });
    cfg.preset = match released {
        Some(p) => p.preset,
        None => {
            let folder = dir
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_else(|| dir.display().to_string());
            format!("hub:{folder}")
        }
    };
    cfg.validate().map_err(CheckpointError::from)?;
    Ok((cfg, d))
}

/// The `ShapeHead` of a config with a `shape_head` block, as `ModelHumanA4OLRM.__init__` builds
/// it: `dim_in` (else the image tokens' width), `target_dim = predict_shape_dim` (else
/// `shape_param_dim`, else 100), `trunk_depth` (4), `num_heads` (16), `mlp_ratio` (4.0),
/// `init_values` (0.01), `num_iterations` (4); the pose token (index 0) is read.
fn shape_head_config(o: &OfficialModelConfig, width: usize) -> Result<ShapeHeadConfig, String> {
    let empty = serde_json::Map::new();
    let sh = o
        .shape_head
        .as_ref()
        .and_then(|v| v.as_object())
        .unwrap_or(&empty);
    let int = |key: &str, default: usize| -> Result<usize, String> {
        match sh.get(key) {
            None | Some(serde_json::Value::Null) => Ok(default),
            Some(v) => v
                .as_u64()
                .map(|n| n as usize)
                .ok_or_else(|| format!("shape_head.{key} = {v} (supported: a whole number)")),
        }
    };
    let float = |key: &str, default: f64| -> Result<f64, String> {
        match sh.get(key) {
            None | Some(serde_json::Value::Null) => Ok(default),
            Some(v) => v
                .as_f64()
                .ok_or_else(|| format!("shape_head.{key} = {v} (supported: a number)")),
        }
    };
    Ok(ShapeHeadConfig {
        dim_in: int("dim_in", width)?,
        target_dim: o.predict_shape_dim.or(o.shape_param_dim).unwrap_or(100),
        trunk_depth: int("trunk_depth", 4)?,
        num_heads: int("num_heads", 16)?,
        mlp_ratio: float("mlp_ratio", 4.0)?,
        init_values: float("init_values", 0.01)?,
        num_iterations: int("num_iterations", 4)?,
        shape_token_idx: 0,
    })
}

/// The weight files of `dir`: `model.safetensors`, or the shards named by the index.
pub fn find_weights(dir: &Path) -> Result<Vec<PathBuf>, HubError> {
    let single = dir.join(WEIGHTS_FILE);
    if single.is_file() {
        return Ok(vec![single]);
    }
    let index = dir.join(INDEX_FILE);
    if !index.is_file() {
        return Err(HubError::Missing {
            folder: dir.to_path_buf(),
            what: format!("weights ({WEIGHTS_FILE} or {INDEX_FILE})"),
        });
    }
    let value = read_json(&index)?;
    let map: BTreeMap<String, String> = value
        .get("weight_map")
        .cloned()
        .ok_or_else(|| HubError::Json {
            path: index.clone(),
            key: "weight_map".into(),
            reason: "missing field `weight_map`".into(),
        })
        .and_then(|v| {
            serde_path_to_error::deserialize(v).map_err(|e| HubError::Json {
                path: index.clone(),
                key: format!("weight_map.{}", e.path()),
                reason: e.into_inner().to_string(),
            })
        })?;
    let shards: BTreeSet<&String> = map.values().collect();
    if shards.is_empty() {
        return Err(HubError::Json {
            path: index,
            key: "weight_map".into(),
            reason: "names no shard".into(),
        });
    }
    let missing: Vec<&str> = shards
        .iter()
        .filter(|s| !dir.join(s.as_str()).is_file())
        .map(|s| s.as_str())
        .collect();
    if !missing.is_empty() {
        return Err(HubError::Missing {
            folder: dir.to_path_buf(),
            what: format!("shard(s) named by {INDEX_FILE}: {}", missing.join(", ")),
        });
    }
    Ok(shards.into_iter().map(|s| dir.join(s)).collect())
}

/// The `step_N` subfolder of `dir` with the highest N holding a `config.json`, when `dir`
/// itself has none.
fn latest_step(dir: &Path) -> Option<PathBuf> {
    if dir.join(CONFIG_FILE).is_file() {
        return None;
    }
    std::fs::read_dir(dir)
        .ok()?
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let step: u64 = name.strip_prefix("step_")?.parse().ok()?;
            let path = e.path();
            path.join(CONFIG_FILE).is_file().then_some((step, path))
        })
        .max_by_key(|(step, _)| *step)
        .map(|(_, path)| path)
}
