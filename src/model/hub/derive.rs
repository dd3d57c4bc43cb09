//! Derivation of our [`LhmppConfig`] from an official [`OfficialModelConfig`], subtree by
//! subtree (encoder, point backbone, image backbone, transformer, Gaussian head, neural
//! renderer, body): every field the file sets is checked against what our network supports and
//! every value that differs from the `lhmpp-700m` preset is reported by its official name.

use std::path::Path;

use super::official::{
    OfficialImageBackbone, OfficialModelConfig, DEFAULT_PIXEL_SHUFFLE_FACTOR, DPT_RENDERER_TYPE,
    PIXEL_SHUFFLE_RENDERER_TYPE, SHARED_DPT_RENDERER_TYPE,
};
use super::HubError;
use crate::model::checkpoint::CheckpointError;
use crate::model::config::{GsHeadConfig, LhmppConfig};
use crate::model::point::SerializationOrder;
use crate::model::shape_head::ShapeHeadConfig;

/// What a derivation found: the fields that differ from the `lhmpp-700m` preset and the
/// values our network does not support, in the order they were checked.
#[derive(Default)]
struct Derivation {
    diffs: Vec<String>,
    unsupported: Vec<String>,
}

impl Derivation {
    /// Records `field = value` as unsupported (`want`: what is) unless `ok`.
    fn require(&mut self, ok: bool, field: &str, value: &dyn std::fmt::Debug, want: &str) {
        if !ok {
            self.unsupported
                .push(format!("{field} = {value:?} (supported: {want})"));
        }
    }

    /// Records `name` when `new` differs from the preset value in `slot`, then stores it.
    fn set<T: PartialEq + std::fmt::Debug>(&mut self, name: &str, slot: &mut T, new: T) {
        if *slot != new {
            self.diffs
                .push(format!("{name}: {new:?} (lhmpp-700m preset: {slot:?})"));
            *slot = new;
        }
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
    let mut dv = Derivation::default();
    encoder_widths(&mut dv, &mut cfg, o, encoder);
    point_backbone(&mut dv, &mut cfg, o, config_path);
    image_backbone(&mut dv, &mut cfg, o);
    transformer(&mut dv, &mut cfg, o);
    gs_head(&mut dv, &mut cfg, o);
    neural_renderer(&mut dv, &mut cfg, o);
    body(&mut dv, &mut cfg, o);
    let Derivation {
        diffs: d,
        unsupported,
    } = dv;
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

/// `encoder_model_name`, `encoder_feat_dim`: the DINOv2 widths.
fn encoder_widths(
    dv: &mut Derivation,
    cfg: &mut LhmppConfig,
    o: &OfficialModelConfig,
    encoder: Option<(usize, usize, usize)>,
) {
    match encoder.or_else(|| dinov2_variant(&o.encoder_model_name)) {
        Some((dim, depth, heads)) => {
            if o.encoder_model_name != "dinov2_vitl14_reg" {
                dv.diffs.push(format!(
                    "encoder_model_name: {:?} (lhmpp-700m preset: \"dinov2_vitl14_reg\")",
                    o.encoder_model_name
                ));
            }
            cfg.encoder.embed_dim = dim;
            cfg.encoder.depth = depth;
            cfg.encoder.num_heads = heads;
        }
        None => dv.require(
            false,
            "encoder_model_name",
            &o.encoder_model_name,
            "dinov2_vit{s,b,l}14_reg",
        ),
    }
    if let Some(dim) = o.encoder_feat_dim {
        dv.require(
            dim == cfg.encoder.embed_dim,
            "encoder_feat_dim",
            &dim,
            "the width of encoder_model_name",
        );
    }
}

/// `transformer_decoder.type`, `transformer_type` and `transformer_decoder.point_backbone`.
fn point_backbone(
    dv: &mut Derivation,
    cfg: &mut LhmppConfig,
    o: &OfficialModelConfig,
    config_path: &Path,
) {
    let td = &o.transformer_decoder;
    dv.require(
        td.kind == "patch_efficient_pvt_mm_encoder_decoder_dense",
        "transformer_decoder.type",
        &td.kind,
        "patch_efficient_pvt_mm_encoder_decoder_dense",
    );
    if let Some(t) = &o.transformer_type {
        dv.require(t == "mm", "transformer_type", t, "mm");
    }
    let pb = &td.point_backbone;
    dv.require(
        pb.kind == "pv3",
        "transformer_decoder.point_backbone.type",
        &pb.kind,
        "pv3",
    );
    dv.require(
        !pb.enable_rpe,
        "transformer_decoder.point_backbone.enable_rpe",
        &pb.enable_rpe,
        "false",
    );
    let orders: Vec<Option<SerializationOrder>> = pb.order.iter().map(|s| order_of(s)).collect();
    dv.require(
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
    dv.set(&name("in_channels"), &mut p.in_channels, pb.in_channels);
    dv.set(
        &name("order"),
        &mut p.order,
        orders.into_iter().flatten().collect(),
    );
    dv.set(&name("stride"), &mut p.stride, pb.stride.clone());
    dv.set(
        &name("enc_depths"),
        &mut p.enc_depths,
        pb.enc_depths.clone(),
    );
    dv.set(
        &name("enc_channels"),
        &mut p.enc_channels,
        pb.enc_channels.clone(),
    );
    dv.set(
        &name("enc_num_head"),
        &mut p.enc_num_head,
        pb.enc_num_head.clone(),
    );
    dv.set(
        &name("enc_patch_size"),
        &mut p.enc_patch_size,
        pb.enc_patch_size.clone(),
    );
    dv.set(
        &name("dec_depths"),
        &mut p.dec_depths,
        pb.dec_depths.clone(),
    );
    dv.set(
        &name("dec_channels"),
        &mut p.dec_channels,
        pb.dec_channels.clone(),
    );
    dv.set(
        &name("dec_num_head"),
        &mut p.dec_num_head,
        pb.dec_num_head.clone(),
    );
    dv.set(
        &name("dec_patch_size"),
        &mut p.dec_patch_size,
        pb.dec_patch_size.clone(),
    );
    dv.set(&name("mlp_ratio"), &mut p.mlp_ratio, pb.mlp_ratio);
}

/// `transformer_decoder.image_backbone`: the VGGT frame blocks.
fn image_backbone(dv: &mut Derivation, cfg: &mut LhmppConfig, o: &OfficialModelConfig) {
    let td = &o.transformer_decoder;
    let ib = &td.image_backbone;
    dv.require(
        ib.kind == "vggt",
        "transformer_decoder.image_backbone.type",
        &ib.kind,
        "vggt",
    );
    dv.require(
        ib.aa_order.is_empty() || ib.aa_order == ["frame"],
        "transformer_decoder.image_backbone.aa_order",
        &ib.aa_order,
        "[frame]",
    );
    dv.set(
        "transformer_decoder.image_backbone.depth",
        &mut cfg.image_backbone.depth,
        ib.depth,
    );
    // The frame blocks are `VGGTAggregator(**image_backbone)`: width and heads come from that
    // dict (defaults 1024 and 16), not from the encoder or the joint attention.
    let frame_dim = ib
        .embed_dim
        .unwrap_or(OfficialImageBackbone::DEFAULT_EMBED_DIM);
    dv.require(
        frame_dim == cfg.encoder.embed_dim,
        "transformer_decoder.image_backbone.embed_dim",
        &frame_dim,
        "the width of encoder_model_name (the frame blocks read its tokens; absent = 1024)",
    );
    dv.set(
        "transformer_decoder.image_backbone.num_heads",
        &mut cfg.image_backbone.num_heads,
        ib.num_heads
            .unwrap_or(OfficialImageBackbone::DEFAULT_NUM_HEADS),
    );
    dv.set(
        "transformer_decoder.image_backbone.mlp_ratio",
        &mut cfg.image_backbone.mlp_ratio,
        ib.mlp_ratio
            .unwrap_or(OfficialImageBackbone::DEFAULT_MLP_RATIO),
    );
}

/// `transformer_decoder.merge_ratio`, `transformer_heads`, `transformer_dim`, `pcl_dim`.
fn transformer(dv: &mut Derivation, cfg: &mut LhmppConfig, o: &OfficialModelConfig) {
    let td = &o.transformer_decoder;
    dv.set(
        "transformer_decoder.merge_ratio",
        &mut cfg.transformer.merge_ratio,
        td.merge_ratio,
    );
    dv.set(
        "transformer_heads",
        &mut cfg.transformer.transformer_heads,
        o.transformer_heads,
    );
    dv.set(
        "transformer_dim",
        &mut cfg.transformer.transformer_dim,
        o.transformer_dim,
    );
    // `motion_embed_mlp = Linear(encoder_feat_dim, pcl_dim // 4), SiLU, Linear(pcl_dim // 4,
    // pcl_dim)`; its output is the AdaLN conditioning of the joint blocks (width transformer_dim).
    let pcl_dim = o.pcl_dim.unwrap_or(o.transformer_dim);
    dv.require(
        pcl_dim == o.transformer_dim,
        "pcl_dim",
        &pcl_dim,
        "transformer_dim (motion_embed_mlp's output conditions the joint blocks)",
    );
    dv.set(
        "pcl_dim // 4 (motion_embed_mlp hidden)",
        &mut cfg.transformer.motion_embed_hidden,
        pcl_dim / 4,
    );
}

/// `gs_*`: the Gaussian head.
fn gs_head(dv: &mut Derivation, cfg: &mut LhmppConfig, o: &OfficialModelConfig) {
    dv.set(
        "gs_query_dim",
        &mut cfg.gs_head.gs_query_dim,
        o.gs_query_dim,
    );
    dv.set("gs_use_rgb", &mut cfg.gs_head.use_rgb, o.gs_use_rgb);
    // `renderer.background_embedding = nn.Parameter(torch.zeros(3, 128))`, whatever gs_query_dim.
    cfg.gs_head.background_dim = Some(GsHeadConfig::OFFICIAL_BACKGROUND_DIM);
    let mlp = &o.gs_mlp_network_config;
    dv.require(
        mlp.activation == "silu",
        "gs_mlp_network_config.activation",
        &mlp.activation,
        "silu",
    );
    dv.set(
        "gs_mlp_network_config.n_neurons",
        &mut cfg.gs_head.n_neurons,
        mlp.n_neurons,
    );
    dv.set(
        "gs_mlp_network_config.n_hidden_layers",
        &mut cfg.gs_head.n_hidden_layers,
        mlp.n_hidden_layers,
    );
    dv.set(
        "gs_xyz_offset_max_step",
        &mut cfg.gs_head.xyz_offset_max_step,
        o.gs_xyz_offset_max_step,
    );
    match o.gs_clip_scaling.inference_value() {
        Some(v) => dv.set("gs_clip_scaling", &mut cfg.gs_head.clip_scaling, v),
        None => dv.require(
            false,
            "gs_clip_scaling",
            &o.gs_clip_scaling,
            "a number or [a, b, c, steps]",
        ),
    }
}

/// `neural_renderer`: the DPT head.
fn neural_renderer(dv: &mut Derivation, cfg: &mut LhmppConfig, o: &OfficialModelConfig) {
    let nr = &o.neural_renderer;
    dv.require(
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
        dv.require(
            nr.depth == 1,
            "neural_renderer.depth",
            &nr.depth,
            "1 with patch_dptonly",
        );
        dv.set(
            "neural_renderer.type patch_dptonly (the whole tokens feed the four DPT inputs)",
            &mut cfg.neural_renderer.shared_tokens,
            true,
        );
    }
    if nr.kind == PIXEL_SHUFFLE_RENDERER_TYPE {
        let u = nr
            .pixel_shuffle_factor
            .unwrap_or(DEFAULT_PIXEL_SHUFFLE_FACTOR);
        dv.require(u >= 1, "neural_renderer.pixel_shuffle_factor", &u, ">= 1");
        dv.set(
            "neural_renderer.type mlp_pixelshuffle, pixel_shuffle_factor",
            &mut cfg.neural_renderer.pixel_shuffle,
            Some(u),
        );
    }
    dv.set(
        "neural_renderer.enc_channels",
        &mut cfg.neural_renderer.in_channels,
        nr.enc_channels,
    );
    dv.set(
        "neural_renderer.img_dim",
        &mut cfg.neural_renderer.embed_dim,
        nr.img_dim,
    );
    dv.set(
        "neural_renderer.enc_patch_size",
        &mut cfg.neural_renderer.patch_size,
        nr.enc_patch_size,
    );
}

/// `smplx_type` and the `shape_head` block.
fn body(dv: &mut Derivation, cfg: &mut LhmppConfig, o: &OfficialModelConfig) {
    if let Some(t) = &o.smplx_type {
        dv.require(
            t == "smplx_diffused_voxel" || t == "smplx_voxel",
            "smplx_type",
            t,
            "smplx_diffused_voxel",
        );
    }
    if o.has_shape_head() {
        match shape_head_config(o, cfg.encoder.embed_dim) {
            Ok(sh) => cfg.shape_head = Some(sh),
            Err(reason) => dv.unsupported.push(reason),
        }
    }
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
