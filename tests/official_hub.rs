//! Hub folders of the released checkpoints: config.json parsing, derivation of our config,
//! weight discovery (single file or shards) and the errors a user sees.

mod official_support;

use std::path::Path;

use candle_core::{DType, Device};
use lhmpp::model::hub::{self, HubError, HubFolder};
use lhmpp::model::LhmppConfig;

/// The `model:` section of the official `configs/train/LHMPP-any-view.yaml` as config.json.
const OFFICIAL_CONFIG: &str = include_str!("fixtures/official/config.json");

fn config_value() -> serde_json::Value {
    serde_json::from_str(OFFICIAL_CONFIG).unwrap()
}

fn write_config(dir: &Path, value: &serde_json::Value) {
    std::fs::write(dir.join("config.json"), value.to_string()).unwrap();
}

/// A safetensors file holding `tensors` (f32 zeros of the given shapes).
fn write_weights(path: &Path, tensors: &[(&str, Vec<usize>)]) {
    let data: Vec<(String, Vec<u8>, Vec<usize>)> = tensors
        .iter()
        .map(|(n, dims)| {
            let count: usize = dims.iter().product();
            (n.to_string(), vec![0u8; 4 * count], dims.clone())
        })
        .collect();
    official_support::write_tensors(path, safetensors::Dtype::F32, &data);
}

#[test]
fn official_config_json_derives_exactly_the_lhmpp_700m_preset() {
    let dir = tempfile::tempdir().unwrap();
    write_config(dir.path(), &config_value());
    write_weights(&dir.path().join("model.safetensors"), &[]);
    let hub = HubFolder::open(dir.path()).unwrap();
    assert_eq!(hub.config, LhmppConfig::lhmpp_700m());
    assert!(hub.differences.is_empty(), "{:?}", hub.differences);
    assert_eq!(hub.official.dense_sample_pts, Some(160_000));
    assert_eq!(hub.weights, vec![dir.path().join("model.safetensors")]);
}

#[test]
fn config_wrapped_in_a_config_key_is_accepted() {
    let dir = tempfile::tempdir().unwrap();
    write_config(dir.path(), &serde_json::json!({ "config": config_value() }));
    write_weights(&dir.path().join("model.safetensors"), &[]);
    assert_eq!(
        HubFolder::open(dir.path()).unwrap().config,
        LhmppConfig::lhmpp_700m()
    );
}

#[test]
fn fields_differing_from_the_preset_are_named_and_applied() {
    let dir = tempfile::tempdir().unwrap();
    let mut v = config_value();
    v["transformer_decoder"]["merge_ratio"] = serde_json::json!(0.0);
    v["gs_clip_scaling"] = serde_json::json!(0.03);
    write_config(dir.path(), &v);
    write_weights(&dir.path().join("model.safetensors"), &[]);
    let hub = HubFolder::open(dir.path()).unwrap();
    assert_eq!(hub.config.transformer.merge_ratio, 0.0);
    assert_eq!(hub.config.gs_head.clip_scaling, 0.03);
    let names: Vec<&str> = hub
        .differences
        .iter()
        .map(|d| d.split(':').next().unwrap())
        .collect();
    assert_eq!(
        names,
        ["transformer_decoder.merge_ratio", "gs_clip_scaling"],
        "{:?}",
        hub.differences
    );
    assert!(
        hub.config.preset.starts_with("hub:"),
        "{}",
        hub.config.preset
    );
}

#[test]
fn unsupported_variants_name_every_field_and_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let mut v = config_value();
    v["neural_renderer"]["type"] = serde_json::json!("patch_convonly");
    v["transformer_decoder"]["image_backbone"]["aa_order"] = serde_json::json!(["frame", "global"]);
    write_config(dir.path(), &v);
    write_weights(&dir.path().join("model.safetensors"), &[]);
    let err = HubFolder::open(dir.path()).unwrap_err();
    let msg = err.to_string();
    assert!(matches!(err, HubError::Unsupported { .. }), "{msg}");
    assert!(msg.contains("config.json"), "{msg}");
    assert!(msg.contains("neural_renderer.type"), "{msg}");
    assert!(msg.contains("patch_convonly"), "{msg}");
    assert!(
        msg.contains("transformer_decoder.image_backbone.aa_order"),
        "{msg}"
    );
}

#[test]
fn bad_json_names_the_key_and_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let mut v = config_value();
    v["transformer_decoder"]["point_backbone"]["stride"] = serde_json::json!("two");
    write_config(dir.path(), &v);
    let err = HubFolder::open(dir.path()).unwrap_err().to_string();
    assert!(err.contains("config.json"), "{err}");
    assert!(
        err.contains("transformer_decoder.point_backbone.stride"),
        "{err}"
    );

    let mut v = config_value();
    v.as_object_mut().unwrap().remove("gs_query_dim");
    write_config(dir.path(), &v);
    let err = HubFolder::open(dir.path()).unwrap_err().to_string();
    assert!(err.contains("gs_query_dim"), "{err}");

    std::fs::write(dir.path().join("config.json"), "{ not json").unwrap();
    let err = HubFolder::open(dir.path()).unwrap_err().to_string();
    assert!(err.contains("config.json"), "{err}");
}

#[test]
fn folder_without_config_or_weights_says_which_file_is_missing() {
    let dir = tempfile::tempdir().unwrap();
    let err = HubFolder::open(dir.path()).unwrap_err().to_string();
    assert!(err.contains("missing config.json"), "{err}");
    write_config(dir.path(), &config_value());
    let err = HubFolder::open(dir.path()).unwrap_err().to_string();
    assert!(
        err.contains("model.safetensors") && err.contains("model.safetensors.index.json"),
        "{err}"
    );
}

#[test]
fn sharded_weights_are_found_through_the_index_and_missing_shards_named() {
    let dir = tempfile::tempdir().unwrap();
    write_config(dir.path(), &config_value());
    let index = serde_json::json!({
        "metadata": {"total_size": 0},
        "weight_map": {
            "encoder.model.cls_token": "model-00001-of-00002.safetensors",
            "renderer.background_embedding": "model-00002-of-00002.safetensors"
        }
    });
    std::fs::write(
        dir.path().join("model.safetensors.index.json"),
        index.to_string(),
    )
    .unwrap();
    write_weights(
        &dir.path().join("model-00001-of-00002.safetensors"),
        &[("encoder.model.cls_token", vec![1, 1, 1024])],
    );
    let err = HubFolder::open(dir.path()).unwrap_err().to_string();
    assert!(err.contains("model-00002-of-00002.safetensors"), "{err}");
    write_weights(
        &dir.path().join("model-00002-of-00002.safetensors"),
        &[("renderer.background_embedding", vec![3, 128])],
    );
    let hub = HubFolder::open(dir.path()).unwrap();
    assert_eq!(hub.weights.len(), 2);
    // Both shards are read: only the tensors in neither are reported missing.
    let err = hub
        .var_builder(DType::F32, &Device::Cpu)
        .err()
        .unwrap()
        .to_string();
    assert!(
        !err.contains("missing tensor `encoder.model.cls_token`"),
        "{err}"
    );
    assert!(
        !err.contains("missing tensor `renderer.background_embedding`"),
        "{err}"
    );
    assert!(
        err.contains("missing tensor `encoder.model.pos_embed`"),
        "{err}"
    );
}

#[test]
fn mismatched_tensors_are_all_reported_at_once_and_official_extras_ignored() {
    let dir = tempfile::tempdir().unwrap();
    write_config(dir.path(), &config_value());
    write_weights(
        &dir.path().join("model.safetensors"),
        &[
            ("encoder.model.cls_token", vec![1, 1, 768]),
            ("renderer.background_embedding", vec![3, 64]),
            ("renderer.smplx_model.skinning_weight", vec![10, 55]),
            (
                "neural_renderer.transformer_block.0.norm1.linear.weight",
                vec![6, 4],
            ),
            ("encoder.model.mask_token", vec![1, 1024]),
        ],
    );
    let err = hub::load_checkpoint(
        dir.path(),
        &LhmppConfig::lhmpp_700m(),
        DType::F32,
        &Device::Cpu,
    )
    .err()
    .unwrap()
    .to_string();
    let expected = lhmpp::model::checkpoint::expected_tensors(&LhmppConfig::lhmpp_700m()).unwrap();
    assert!(
        err.contains(&dir.path().display().to_string()),
        "{}",
        &err[..200]
    );
    assert!(err.contains("wrong shape for `encoder.model.cls_token`"));
    assert!(err.contains("wrong shape for `renderer.background_embedding`"));
    assert!(err.contains("unexpected tensor `encoder.model.mask_token`"));
    assert!(!err.contains("smplx_model"));
    assert!(!err.contains("transformer_block"));
    let missing = err.matches("missing tensor").count();
    assert_eq!(missing, expected.len() - 2);
}

#[test]
fn a_checkpoint_path_that_does_not_exist_points_to_the_expected_layout() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("LHMPP-700M");
    let err = hub::load_checkpoint(
        &missing,
        &LhmppConfig::lhmpp_700m(),
        DType::F32,
        &Device::Cpu,
    )
    .err()
    .unwrap()
    .to_string();
    assert!(
        err.contains("LHMPP-700M") && err.contains("does not exist"),
        "{err}"
    );
    assert!(
        err.contains("config.json") && err.contains("model.safetensors"),
        "{err}"
    );
}

#[test]
fn a_release_folder_with_step_checkpoints_opens_the_latest_step() {
    let dir = tempfile::tempdir().unwrap();
    for step in ["step_000900", "step_001200", "step_notes"] {
        let d = dir.path().join(step);
        std::fs::create_dir_all(&d).unwrap();
        if step != "step_notes" {
            write_config(&d, &config_value());
            write_weights(&d.join("model.safetensors"), &[]);
        }
    }
    let hub = HubFolder::open(dir.path()).unwrap();
    assert_eq!(hub.dir, dir.path().join("step_001200"));
    assert_eq!(
        hub.weights,
        vec![dir.path().join("step_001200/model.safetensors")]
    );
}

#[test]
fn a_smaller_dinov2_is_named_as_a_difference_and_its_width_must_match_the_joint_width() {
    let dir = tempfile::tempdir().unwrap();
    let mut v = config_value();
    v["encoder_model_name"] = serde_json::json!("dinov2_vitb14_reg");
    v["encoder_feat_dim"] = serde_json::json!(768);
    write_config(dir.path(), &v);
    write_weights(&dir.path().join("model.safetensors"), &[]);
    // The frame blocks stay VGGTAggregator's default 1024 wide: refused, naming the field.
    let err = HubFolder::open(dir.path()).unwrap_err().to_string();
    assert!(
        err.contains("transformer_decoder.image_backbone.embed_dim = 1024"),
        "{err}"
    );
    v["transformer_decoder"]["image_backbone"]["embed_dim"] = serde_json::json!(768);
    v["transformer_decoder"]["image_backbone"]["num_heads"] = serde_json::json!(12);
    // transformer_dim (and pcl_dim) stay 1024: the derived config is invalid, and says why.
    write_config(dir.path(), &v);
    let err = HubFolder::open(dir.path()).unwrap_err().to_string();
    assert!(
        err.contains("transformer_dim 1024") && err.contains("768"),
        "{err}"
    );
    v["transformer_dim"] = serde_json::json!(768);
    v["pcl_dim"] = serde_json::json!(768);
    v["transformer_heads"] = serde_json::json!(12);
    v["neural_renderer"]["img_dim"] = serde_json::json!(768);
    write_config(dir.path(), &v);
    let hub = HubFolder::open(dir.path()).unwrap();
    assert_eq!(hub.config.encoder.embed_dim, 768);
    assert_eq!(hub.config.encoder.depth, 12);
    assert!(
        hub.differences[0].starts_with("encoder_model_name: \"dinov2_vitb14_reg\""),
        "{:?}",
        hub.differences
    );
}

/// The released config.json at small widths, the way the official code is configured for them
/// (../shared/reference/official-forward.md: ViT-S/14 reg, d 384, PTv3 channels
/// [32, 64, 128, 256] with one block per stage): `pcl_dim` (= `transformer_dim` in the YAML)
/// and the `image_backbone` dict's `embed_dim` / `num_heads` follow the encoder.
fn small_official_config() -> serde_json::Value {
    use serde_json::json;
    let mut v = config_value();
    official_support::vit_s_widths(&mut v);
    let pb = &mut v["transformer_decoder"]["point_backbone"];
    pb["enc_depths"] = json!([1, 1, 1, 1]);
    pb["enc_channels"] = json!([32, 64, 128, 256]);
    pb["enc_num_head"] = json!([2, 4, 8, 8]);
    pb["enc_patch_size"] = json!([1024, 1024, 512, 256]);
    pb["dec_depths"] = json!([1, 1, 1]);
    pb["dec_channels"] = json!([64, 128, 256]);
    pb["dec_num_head"] = json!([4, 8, 8]);
    pb["dec_patch_size"] = json!([1024, 1024, 512]);
    v["gs_query_dim"] = json!(64);
    v["gs_mlp_network_config"]["n_neurons"] = json!(128);
    v["neural_renderer"]["enc_channels"] = json!(64);
    v
}

#[test]
fn an_official_config_at_small_widths_derives_the_official_shapes_and_loads() {
    let dir = tempfile::tempdir().unwrap();
    write_config(dir.path(), &small_official_config());
    let weights = dir.path().join("model.safetensors");
    write_weights(&weights, &[]);
    let hub = HubFolder::open(dir.path()).unwrap();
    let cfg = &hub.config;
    assert_eq!(cfg.encoder.embed_dim, 384);
    assert_eq!(cfg.image_backbone.num_heads, 6);
    assert_eq!(cfg.transformer.motion_embed_hidden, 96);
    assert_eq!(cfg.gs_head.background_width(), 128);
    let expected = lhmpp::model::checkpoint::expected_tensors(cfg).unwrap();
    // The three widths the official modules derive on their own (modeling_humana4o_lrm.py:
    // `mid_dim = pcl_dim // 4`; gsplat_renderer.py: `torch.zeros(3, 128)`; vggt_transformer.py:
    // `VGGTAggregator(embed_dim, num_heads)` with qk LayerNorms over the head dim 384 / 6).
    let official: [(&str, &[usize]); 9] = [
        ("motion_embed_mlp.0.weight", &[96, 384]),
        ("motion_embed_mlp.0.bias", &[96]),
        ("motion_embed_mlp.2.weight", &[384, 96]),
        ("motion_embed_mlp.2.bias", &[384]),
        ("renderer.background_embedding", &[3, 128]),
        (
            "transformer.image_backbone.frame_blocks.0.attn.q_norm.weight",
            &[64],
        ),
        (
            "transformer.image_backbone.frame_blocks.2.attn.k_norm.bias",
            &[64],
        ),
        (
            "transformer.image_backbone.frame_blocks.1.attn.qkv.weight",
            &[1152, 384],
        ),
        ("transformer.image_backbone.pose_token", &[1, 2, 1, 384]),
    ];
    for (name, dims) in official {
        assert_eq!(expected.get(name).map(Vec::as_slice), Some(dims), "{name}");
    }
    // A random checkpoint with exactly those tensors loads without a mismatch.
    lhmpp::model::checkpoint::init_checkpoint(cfg, 5, &weights).unwrap();
    let loaded = hub::load_checkpoint(
        dir.path(),
        &LhmppConfig::lhmpp_700m(),
        DType::F32,
        &Device::Cpu,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(&loaded.config, cfg);
    lhmpp::model::Lhmpp::new(&loaded.config, loaded.var_builder).unwrap();
}

#[test]
fn the_frame_blocks_take_their_width_and_heads_from_the_image_backbone_dict() {
    let dir = tempfile::tempdir().unwrap();
    let mut v = small_official_config();
    let ib = v["transformer_decoder"]["image_backbone"]
        .as_object_mut()
        .unwrap();
    ib.remove("num_heads");
    write_config(dir.path(), &v);
    write_weights(&dir.path().join("model.safetensors"), &[]);
    // Absent num_heads is VGGTAggregator's default 16 (head dim 384 / 16 = 24).
    let hub = HubFolder::open(dir.path()).unwrap();
    assert_eq!(hub.config.image_backbone.num_heads, 16);
    let expected = lhmpp::model::checkpoint::expected_tensors(&hub.config).unwrap();
    assert_eq!(
        expected["transformer.image_backbone.frame_blocks.0.attn.q_norm.weight"],
        vec![24]
    );
    // Absent embed_dim is 1024, which a 384-wide encoder cannot feed: the file is refused,
    // naming the field.
    v["transformer_decoder"]["image_backbone"]
        .as_object_mut()
        .unwrap()
        .remove("embed_dim");
    write_config(dir.path(), &v);
    let err = HubFolder::open(dir.path()).unwrap_err().to_string();
    assert!(
        err.contains("transformer_decoder.image_backbone.embed_dim") && err.contains("1024"),
        "{err}"
    );
    // pcl_dim must be the joint width.
    let mut v = small_official_config();
    v["pcl_dim"] = serde_json::json!(1024);
    write_config(dir.path(), &v);
    let err = HubFolder::open(dir.path()).unwrap_err().to_string();
    assert!(err.contains("pcl_dim = 1024"), "{err}");
}
