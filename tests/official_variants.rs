//! The GS-supervised releases LHMPP-700M-PixelShuffle and LHMPP-700M-SMPLX-FREE: their key
//! lists, made by instantiating the official modules (`scripts/parity/official_keys.py`: the
//! official `MLPPixelShuffleDPTHead` and `ShapeHead` swapped into the instantiated LHMPP-700M
//! list), equal our networks' (with the betas `shape_head.*`); their config.json derive the
//! presets; a small random PixelShuffle hub folder loads, predicts betas, renders through its
//! pixel-shuffle head and is display-ready.

mod official_support;

use std::collections::BTreeMap;
use std::path::Path;

use candle_core::{DType, Device, Tensor};
use lhmpp::config::ModelConfig;
use lhmpp::model::checkpoint::{expected_tensors, init_checkpoint, IGNORED_PREFIXES};
use lhmpp::model::hub::{self, HubFolder};
use lhmpp::model::{Lhmpp, LhmppConfig, RgbKind};
use lhmpp::reconstruct::shape::AcceptedShape;
use lhmpp::reconstruct::Reconstructor;

use serde_json::json;

const PIXELSHUFFLE_KEYS: &str =
    include_str!("fixtures/lhmpp_700m_pixelshuffle_state_dict_keys.tsv");
const SMPLX_FREE_KEYS: &str = include_str!("fixtures/lhmpp_700m_smplx_free_state_dict_keys.tsv");
const LHMPPS_KEYS: &str = include_str!("fixtures/lhmpps_700m_state_dict_keys.tsv");
/// The `model:` section of the official `configs/train/LHMPP-any-view.yaml` as config.json.
const OFFICIAL_CONFIG: &str = include_str!("fixtures/official/config.json");

fn parse(tsv: &str) -> BTreeMap<String, Vec<usize>> {
    tsv.lines()
        .filter_map(|l| {
            let (k, s) = l.split_once('\t')?;
            let dims = s
                .trim_matches(|c| c == '[' || c == ']')
                .split(',')
                .filter(|d| !d.trim().is_empty())
                .map(|d| d.trim().parse().unwrap())
                .collect();
            Some((k.to_string(), dims))
        })
        .collect()
}

/// Asserts that `cfg`'s tensors are exactly the official ones, but for those under an ignored
/// prefix that the network does not build (as the loader does); returns how many official
/// tensors each ignored prefix skipped.
fn assert_key_list(cfg: &LhmppConfig, official: &BTreeMap<String, Vec<usize>>) -> Vec<usize> {
    let expected = expected_tensors(cfg).unwrap();
    let mut ignored = vec![0; IGNORED_PREFIXES.len()];
    let mut problems = Vec::new();
    for (k, dims) in official {
        if let Some(i) = IGNORED_PREFIXES.iter().position(|p| k.starts_with(p)) {
            if !expected.contains_key(k) {
                ignored[i] += 1;
                continue;
            }
        }
        match expected.get(k) {
            None => problems.push(format!("missing {k}")),
            Some(d) if d != dims => problems.push(format!("{k}: ours {d:?}, official {dims:?}")),
            _ => {}
        }
    }
    for k in expected.keys() {
        if !official.contains_key(k) {
            problems.push(format!("extra {k}"));
        }
    }
    assert!(problems.is_empty(), "{problems:#?}");
    ignored
}

#[test]
fn pixelshuffle_keys_and_shapes_equal_the_official_modules() {
    let official = parse(PIXELSHUFFLE_KEYS);
    assert_eq!(official.len(), 1486);
    let cfg = LhmppConfig::lhmpp_700m_pixelshuffle();
    let ignored = assert_key_list(&cfg, &official);
    // neural_renderer.transformer_block.* (4 unused SD3 blocks: 170 tensors); the 41
    // shape_head tensors are ours
    assert_eq!(ignored, vec![0, 170, 0]);
    let expected = expected_tensors(&cfg).unwrap();
    let dp = "neural_renderer.dense_predictor.";
    assert_eq!(
        expected[&format!("{dp}refinenet1_ps_mlp.weight")],
        vec![16, 128, 1, 1]
    );
    assert!(expected.contains_key(&format!("{dp}l1_residual_fuse.bias")));
    assert!(!expected
        .keys()
        .any(|k| k.contains("refinenet1.") || k.contains("output_conv")));
}

#[test]
fn smplx_free_keys_and_shapes_equal_the_official_modules() {
    let official = parse(SMPLX_FREE_KEYS);
    let cfg = LhmppConfig::lhmpp_700m_smplx_free();
    assert_eq!(assert_key_list(&cfg, &official), vec![0, 170, 0]);
    // The LHMPP-700M network plus the shape head; the RGB is GS-supervised.
    assert_eq!(
        LhmppConfig {
            preset: "lhmpp-700m".into(),
            shape_head: None,
            ..cfg
        },
        LhmppConfig::lhmpp_700m()
    );
    assert_eq!(
        RgbKind::of_preset("lhmpp-700m-smplx-free"),
        RgbKind::DisplayReady
    );
}

#[test]
fn lhmpps_hub_config_derives_the_one_group_dpt_head_and_its_official_keys() {
    // configs/train/LHMPP-any-view-DPTS.yaml: LHMPP-700M with `patch_dptonly`, depth 1.
    let dir = tempfile::tempdir().unwrap();
    let mut v: serde_json::Value = serde_json::from_str(OFFICIAL_CONFIG).unwrap();
    v["neural_renderer"]["type"] = json!("patch_dptonly");
    v["neural_renderer"]["depth"] = json!(1);
    let hub = open(dir.path(), &v);
    assert!(hub.config.neural_renderer.shared_tokens);
    assert_eq!(hub.config.neural_renderer.head_dim(), 1024);
    assert!(
        hub.config.preset.starts_with("hub:"),
        "{}",
        hub.config.preset
    );
    // The official list (DPTHead instantiated, its unused SD3 block not listed) is ours.
    assert_eq!(
        assert_key_list(&hub.config, &parse(LHMPPS_KEYS)),
        vec![0, 0, 0]
    );
    assert_eq!(RgbKind::of_hub("patch_dptonly", false), RgbKind::Latent);
    // Any other depth cannot run in the official class: refused, naming the field.
    v["neural_renderer"]["depth"] = json!(4);
    std::fs::write(dir.path().join("config.json"), v.to_string()).unwrap();
    let err = HubFolder::open(dir.path()).unwrap_err().to_string();
    assert!(err.contains("neural_renderer.depth = 4"), "{err}");
}

/// The shape-head fields both GS-supervised configs add (`configs/train/LHMPP-pixelshuffle.yaml`,
/// `configs/train/LHMPP-anyview-SMPLX-FREE.yaml`).
fn with_shape_head(mut v: serde_json::Value) -> serde_json::Value {
    v["predict_shape_dim"] = json!(10);
    v["use_pred_shape_for_render"] = json!(true);
    v["shape_head"] = json!({
        "dim_in": 1024, "trunk_depth": 2, "num_iterations": 4, "num_heads": 16,
        "mlp_ratio": 4.0, "init_values": 0.01
    });
    v
}

/// config.json of LHMPP-700M-PixelShuffle: merge 0, the `mlp_pixelshuffle` renderer.
fn pixelshuffle_config() -> serde_json::Value {
    let mut v = with_shape_head(serde_json::from_str(OFFICIAL_CONFIG).unwrap());
    v["transformer_decoder"]["merge_ratio"] = json!(0.0);
    v["neural_renderer"]["type"] = json!("mlp_pixelshuffle");
    v["neural_renderer"]["pixel_shuffle_factor"] = json!(2);
    v
}

fn open(dir: &Path, v: &serde_json::Value) -> HubFolder {
    std::fs::write(dir.join("config.json"), v.to_string()).unwrap();
    let weights = dir.join("model.safetensors");
    if !weights.exists() {
        safetensors::serialize_to_file(
            Vec::<(String, safetensors::tensor::TensorView)>::new(),
            None,
            &weights,
        )
        .unwrap();
    }
    HubFolder::open(dir).unwrap()
}

#[test]
fn released_configs_derive_the_gs_supervised_presets() {
    let dir = tempfile::tempdir().unwrap();
    let hub = open(dir.path(), &pixelshuffle_config());
    assert_eq!(hub.config, LhmppConfig::lhmpp_700m_pixelshuffle());
    assert!(hub.official.has_shape_head());
    let names: Vec<&str> = hub
        .differences
        .iter()
        .map(|d| d.split(':').next().unwrap())
        .collect();
    assert_eq!(
        names,
        [
            "transformer_decoder.merge_ratio",
            "neural_renderer.type mlp_pixelshuffle, pixel_shuffle_factor"
        ]
    );
    let hub = open(
        dir.path(),
        &with_shape_head(serde_json::from_str(OFFICIAL_CONFIG).unwrap()),
    );
    assert_eq!(hub.config, LhmppConfig::lhmpp_700m_smplx_free());
    // Without the shape head, the same file is the RGB-unsupervised LHMPP-700M.
    let hub = open(dir.path(), &serde_json::from_str(OFFICIAL_CONFIG).unwrap());
    assert_eq!(hub.config, LhmppConfig::lhmpp_700m());
    assert!(!hub.official.has_shape_head());
}

/// Seeded values in [-0.05, 0.05) for one extra tensor.
fn extra_bytes(n: usize, seed: u64) -> Vec<u8> {
    let mut s = seed;
    (0..n)
        .flat_map(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (((s >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * 0.1).to_le_bytes()
        })
        .collect()
}

/// A small random LHMPP-700M-PixelShuffle hub folder in `dir`: small widths (ViT-S, d 384, a
/// slim point backbone), the released renderer widths, two shards.
fn write_small_pixelshuffle_hub(dir: &Path) -> HubFolder {
    let mut v = pixelshuffle_config();
    official_support::vit_s_widths(&mut v);
    official_support::slim_point_backbone(&mut v);
    v["gs_mlp_network_config"]["n_neurons"] = json!(64);
    v["shape_head"]["dim_in"] = json!(384);
    v["shape_head"]["num_heads"] = json!(6);
    let hub = open(dir, &v);
    assert_eq!(hub.config.neural_renderer.pixel_shuffle, Some(2));
    assert!(
        hub.config.preset.starts_with("hub:"),
        "{}",
        hub.config.preset
    );
    // Two shards: our tensors (seeded, the shape head's included), and an official extra we
    // ignore (an unused SD3 block tensor).
    std::fs::remove_file(dir.join("model.safetensors")).unwrap();
    let ours = dir.join("model-00001-of-00002.safetensors");
    init_checkpoint(&hub.config, 7, &ours).unwrap();
    let extras: Vec<(String, Vec<usize>)> = vec![(
        "neural_renderer.transformer_block.0.norm1.linear.weight".into(),
        vec![6144, 1024],
    )];
    let data: Vec<(String, Vec<u8>, Vec<usize>)> = extras
        .iter()
        .enumerate()
        .map(|(i, (n, d))| {
            (
                n.clone(),
                extra_bytes(d.iter().product(), i as u64),
                d.clone(),
            )
        })
        .collect();
    official_support::write_tensors(
        &dir.join("model-00002-of-00002.safetensors"),
        safetensors::Dtype::F32,
        &data,
    );
    let mut map = serde_json::Map::new();
    for k in expected_tensors(&hub.config).unwrap().keys() {
        map.insert(k.clone(), json!("model-00001-of-00002.safetensors"));
    }
    for (k, _) in &extras {
        map.insert(k.clone(), json!("model-00002-of-00002.safetensors"));
    }
    std::fs::write(
        dir.join("model.safetensors.index.json"),
        json!({ "metadata": {}, "weight_map": map }).to_string(),
    )
    .unwrap();

    HubFolder::open(dir).unwrap()
}

#[test]
fn a_small_random_pixelshuffle_hub_folder_loads_and_renders_display_ready_frames() {
    let dir = tempfile::tempdir().unwrap();
    let hub = write_small_pixelshuffle_hub(dir.path());
    assert_eq!(hub.config.neural_renderer.pixel_shuffle, Some(2));
    let loaded = hub::load_checkpoint(
        dir.path(),
        &LhmppConfig::lhmpp_700m(),
        DType::F32,
        &Device::Cpu,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert!(loaded.shape_head);
    assert_eq!(
        loaded.neural_renderer_type.as_deref(),
        Some("mlp_pixelshuffle")
    );
    assert_eq!(loaded.rgb_kind(), RgbKind::DisplayReady);
    let summary = HubFolder::open(dir.path()).unwrap().check().unwrap();
    let unused = summary
        .ignored
        .iter()
        .find(|(p, _, _)| p == "neural_renderer.transformer_block.")
        .unwrap();
    assert_eq!(unused.1, 1, "{summary:?}");
    // `lhmpp model info FOLDER` names the renderer and the shape head.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_lhmpp"))
        .args(["model", "info"])
        .arg(dir.path())
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    assert!(text.contains("renderer mlp_pixelshuffle"), "{text}");
    assert!(
        text.contains("shape_head: 10 betas from the views' pose tokens (2 trunk blocks, 4 steps)"),
        "{text}"
    );
    let model = Lhmpp::new(&loaded.config, loaded.var_builder).unwrap();
    // The shape head reads the pose tokens of the views: 10 finite betas.
    let head = model.shape_head().expect("a shape head");
    assert_eq!(head.config().trunk_depth, 2);
    assert_eq!(head.config().dim_in, 384);
    let tokens = Tensor::randn(0f32, 1.0, (2, 5 + 12, 384), &Device::Cpu).unwrap();
    let betas = head.predict(&tokens).unwrap();
    assert_eq!(betas.dims(), &[1, 10]);
    assert!(betas
        .flatten_all()
        .unwrap()
        .to_vec1::<f32>()
        .unwrap()
        .iter()
        .all(|b| b.is_finite()));
    let renderer = model.neural_renderer();
    let feats = Tensor::randn(0f32, 1.0, (1, 128, 35, 21), &Device::Cpu).unwrap();
    let (rgb, mask) = renderer.forward(&feats).unwrap();
    assert_eq!(rgb.dims(), &[1, 3, 35, 21]);
    assert_eq!(mask.dims(), &[1, 1, 35, 21]);
    let v = rgb.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    assert!(v.iter().all(|x| (0.0..=1.0).contains(x)));
    // The channels-last CPU head equals the stock candle ops on the loaded weights.
    let (rgb_ref, _) = renderer.clone().with_candle_ops().forward(&feats).unwrap();
    let d = (rgb - rgb_ref)
        .unwrap()
        .abs()
        .unwrap()
        .flatten_all()
        .unwrap()
        .max(0)
        .unwrap()
        .to_scalar::<f32>()
        .unwrap();
    assert!(d < 1e-4, "{d}");
}

#[test]
fn the_node_reconstructor_carries_the_predicted_betas_and_takes_the_gaussian_rgb() {
    let tmp = tempfile::tempdir().unwrap();
    let hub = tmp.path().join("LHMPP-700M-PixelShuffle-small");
    std::fs::create_dir_all(&hub).unwrap();
    write_small_pixelshuffle_hub(&hub);
    let prior_dir = tmp.path().join("LHMPP-Prior");
    official_support::write_prior(&prior_dir, 2000);
    let config = ModelConfig {
        preset: "lhmpp-700m".into(),
        checkpoint: hub.display().to_string(),
        prior_dir: prior_dir.display().to_string(),
        num_points: 600,
        ..ModelConfig::default()
    };
    let mut recon = Reconstructor::new(&config, 4).unwrap();
    assert_eq!(recon.rgb_kind(), RgbKind::DisplayReady);
    assert_eq!(recon.neural_renderer_id(), "");
    assert!(
        recon.checkpoint_kind().contains("shape_head"),
        "{}",
        recon.checkpoint_kind()
    );
    assert!(recon.shape().is_none());
    let (a, b) = (official_support::view(56, 0), official_support::view(56, 9));
    recon.reconstruct(&[(1, &a), (2, &b)]).unwrap();
    let betas = recon.predicted_betas().expect("predicted betas").to_vec();
    assert_eq!(betas.len(), 10);
    assert!(betas.iter().all(|v| v.is_finite()));
    assert_eq!(
        recon.shape(),
        Some(&AcceptedShape::SmplxBetas(betas.clone()))
    );
    // A shape from the shape topic wins over the prediction.
    let topic = AcceptedShape::SmplxBetas(vec![0.5; 10]);
    recon.set_shape(topic.clone()).unwrap();
    recon.reconstruct(&[(1, &a)]).unwrap();
    assert_eq!(recon.shape(), Some(&topic));
    assert_ne!(
        recon.predicted_betas().unwrap(),
        &betas[..],
        "a new prediction for one view"
    );
}
