//! Checkpoint naming, seeded init and validated loading.

use std::collections::HashMap;

use candle_core::{DType, Device};
use lhmpp::model::checkpoint::{self, CheckpointError};
use lhmpp::model::LhmppConfig;

/// Official LHMPP-700M state-dict keys and shapes (converted from the reference enumeration).
const OFFICIAL_KEYS: &str = include_str!("fixtures/lhmpp_700m_state_dict_keys.tsv");

fn official() -> HashMap<String, Vec<usize>> {
    OFFICIAL_KEYS
        .lines()
        .filter_map(|l| {
            let (k, s) = l.split_once('\t')?;
            let dims = s
                .trim_matches(|c| c == '[' || c == ']')
                .split(',')
                .map(|d| d.trim().parse().unwrap())
                .collect();
            Some((k.to_string(), dims))
        })
        .collect()
}

#[test]
fn lhmpp_700m_keys_and_shapes_equal_the_official_state_dict() {
    let expected = checkpoint::expected_tensors(&LhmppConfig::lhmpp_700m()).unwrap();
    let official = official();
    // The point backbone and renderer are checked once they are built in this crate; the
    // unused neural-renderer SD3 blocks are never built.
    let built = |prefix: &str| expected.keys().any(|k| k.starts_with(prefix));
    let (has_points, has_renderer) = (
        built("transformer.point_backbone."),
        built("neural_renderer."),
    );
    let covered = |k: &str| {
        !k.starts_with("neural_renderer.transformer_block.")
            && (has_points || !k.starts_with("transformer.point_backbone."))
            && (has_renderer || !k.starts_with("neural_renderer."))
    };
    let mut problems = Vec::new();
    for (k, dims) in &official {
        if !covered(k) {
            continue;
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
}

#[test]
fn parameter_count_matches_the_built_model_for_every_preset() {
    for name in LhmppConfig::PRESETS {
        let cfg = LhmppConfig::preset(name).unwrap();
        let built: usize = checkpoint::expected_tensors(&cfg)
            .unwrap()
            .values()
            .map(|d| d.iter().product::<usize>())
            .sum();
        let p = cfg.parameter_count();
        let ours = p.total() - missing_parts(&cfg, &p);
        assert_eq!(built, ours, "preset {name}");
    }
}

/// Parameters of parts not yet built by this crate (point backbone and renderer land separately).
fn missing_parts(cfg: &LhmppConfig, p: &lhmpp::model::config::ParameterCounts) -> usize {
    let keys = checkpoint::expected_tensors(cfg).unwrap();
    let has = |prefix: &str| keys.keys().any(|k| k.starts_with(prefix));
    (if has("transformer.point_backbone.") {
        0
    } else {
        p.point_backbone
    }) + (if has("neural_renderer.") {
        0
    } else {
        p.neural_renderer
    })
}

#[test]
fn init_then_load_round_trips_with_metadata() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tiny.safetensors");
    let cfg = LhmppConfig::tiny();
    let n = checkpoint::init_checkpoint(&cfg, 1, &path).unwrap();
    assert!(n > 0);
    let (preset, stored) = checkpoint::read_metadata(&path).unwrap();
    assert_eq!(preset.as_deref(), Some("tiny"));
    assert_eq!(stored.unwrap(), cfg);
    checkpoint::load_var_builder(&path, &cfg, DType::BF16, &Device::Cpu).unwrap();
    let model = checkpoint::load(&path, &cfg, DType::F32, &Device::Cpu).unwrap();
    assert_eq!(model.config(), &cfg);
    // Same seed, same tensors; another seed, other values.
    let tensors = |seed: u64| {
        let p = dir.path().join(format!("seed{seed}.safetensors"));
        checkpoint::init_checkpoint(&cfg, seed, &p).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        let mut v: Vec<(String, Vec<u8>)> = st
            .tensors()
            .into_iter()
            .map(|(n, t)| (n, t.data().to_vec()))
            .collect();
        v.sort();
        v
    };
    let (a, b, c) = (tensors(1), tensors(1), tensors(2));
    assert!(a == b, "same seed gave different tensors");
    assert!(a != c, "different seeds gave the same tensors");
}

#[test]
fn one_error_names_the_missing_the_misshapen_and_the_mistyped_tensor_and_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.safetensors");
    let cfg = LhmppConfig::tiny();
    checkpoint::init_checkpoint(&cfg, 3, &good).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let missing = "encoder.model.norm.bias";
    let misshapen = "motion_embed_mlp.0.weight";
    let mistyped = "renderer.background_embedding";
    let mut owned: Vec<(String, safetensors::Dtype, Vec<usize>, Vec<u8>)> = Vec::new();
    for (name, view) in st.tensors() {
        if name == missing {
            continue;
        }
        let (dtype, mut shape, mut data) =
            (view.dtype(), view.shape().to_vec(), view.data().to_vec());
        if name == misshapen {
            shape = vec![shape.iter().product::<usize>()];
        }
        let dtype = if name == mistyped {
            let v: &[f32] = bytemuck::cast_slice(&data);
            data =
                bytemuck::cast_slice(&v.iter().map(|&x| x as f64).collect::<Vec<f64>>()).to_vec();
            safetensors::Dtype::F64
        } else {
            dtype
        };
        owned.push((name, dtype, shape, data));
    }
    let views: Vec<(String, safetensors::tensor::TensorView)> = owned
        .iter()
        .map(|(n, d, s, b)| {
            (
                n.clone(),
                safetensors::tensor::TensorView::new(*d, s.clone(), b).unwrap(),
            )
        })
        .collect();
    let bad = dir.path().join("broken.safetensors");
    safetensors::serialize_to_file(views, None, &bad).unwrap();
    let Err(err) = checkpoint::load_var_builder(&bad, &cfg, DType::F32, &Device::Cpu) else {
        panic!("a broken checkpoint was accepted");
    };
    let msg = err.to_string();
    assert!(
        matches!(err, CheckpointError::Mismatch { ref problems, .. } if problems.len() == 3),
        "{msg}"
    );
    for needle in [
        missing,
        misshapen,
        mistyped,
        "broken.safetensors",
        "missing",
        "shape",
        "dtype",
    ] {
        assert!(msg.contains(needle), "`{needle}` not in: {msg}");
    }
}
