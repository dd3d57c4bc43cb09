//! Our whole forward against the official LHM++ code itself: the fixture in
//! `tests/fixtures/official/forward` was written by `scripts/parity/official/generate.py`
//! running the official modules at small widths (reduced DINOv2 and DPT, slim PTv3 with
//! several attention patches per stage, merge ratio 0.5, part masks, 2 views) with their random
//! draws recorded: the order permutation after each GridPooling and the ToMe destinations of
//! each multi-modal block. We load the official weights under their own names, replay the
//! draws and compare every output.

mod official_support;

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use candle_core::{DType, Device, Tensor};
use lhmpp::model::draws::ForwardDraws;
use lhmpp::model::hub;
use lhmpp::model::{gs_head, tensor_file, Lhmpp, LhmppConfig};

/// Relative limit on max|ours − official| / max|official| for every output (f32).
const LIMIT: f32 = 1e-4;
/// Outputs of the point path, then the neural renderer's.
const OUTPUTS: [&str; 8] = [
    "features",
    "offsets",
    "scales",
    "rotations",
    "opacities",
    "colors",
    "neural_rgb",
    "neural_mask",
];

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/official/forward")
}

fn io() -> HashMap<String, Tensor> {
    tensor_file::read_safetensors(&dir().join("io.safetensors"), &Device::Cpu).unwrap()
}

fn meta() -> serde_json::Value {
    let m = tensor_file::read_metadata(&dir().join("io.safetensors")).unwrap();
    serde_json::from_str(&m["lhmpp.fixture"]).unwrap()
}

/// Our config for the fixture: the official config.json through the hub derivation, with the
/// reduced DINOv2 (`dinov2_fixture14_reg`, not a released variant) and the DPT-head widths,
/// which the official code fixes in its constructors, from the fixture's metadata.
fn fixture_config() -> LhmppConfig {
    let m = meta();
    let n = |x: &serde_json::Value| x.as_u64().unwrap() as usize;
    let d = &m["dinov2"];
    let encoder = (n(&d["embed_dim"]), n(&d["depth"]), n(&d["num_heads"]));
    let path = dir().join("config.json");
    let official = hub::parse_config(&path).unwrap();
    let (mut cfg, _) =
        hub::derive_config_with_encoder(&official, Some(encoder), &path, &dir()).unwrap();
    cfg.neural_renderer.features = n(&m["dpt"]["features"]);
    let oc: Vec<usize> = m["dpt"]["out_channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(n)
        .collect();
    cfg.neural_renderer.out_channels = oc.try_into().unwrap();
    cfg.image_height = n(&m["image_size"][0]);
    cfg.image_width = n(&m["image_size"][1]);
    assert_eq!(
        cfg.gs_head.clip_scaling,
        m["clip_scaling"].as_f64().unwrap(),
        "clip scaling"
    );
    cfg
}

fn model(cfg: &LhmppConfig) -> Lhmpp {
    let loaded = hub::load_checkpoint(
        &dir().join("model.safetensors"),
        cfg,
        DType::F32,
        &Device::Cpu,
    )
    .unwrap();
    Lhmpp::new(&loaded.config, loaded.var_builder).unwrap()
}

/// Our forward on the fixture's inputs with `draws`: every output of [`OUTPUTS`].
fn forward(
    m: &Lhmpp,
    io: &HashMap<String, Tensor>,
    draws: &ForwardDraws,
) -> HashMap<String, Tensor> {
    let f32 = |n: &str| io[n].to_dtype(DType::F32).unwrap();
    let (images, anchors, normals) = (f32("images"), f32("anchors"), f32("normals"));
    let views: Vec<_> = (0..images.dim(0).unwrap())
        .map(|i| m.encode_view(&images.get(i).unwrap()).unwrap())
        .collect();
    let (feat, _) = m
        .fuse_with_draws(&anchors, &normals, &views, draws)
        .unwrap();
    let (hands, upper) = gs_head::part_masks(io)
        .unwrap()
        .expect("masks in the fixture");
    let g = m
        .gs_head()
        .forward(&feat, &anchors)
        .unwrap()
        .with_part_masks(&hands, &upper)
        .unwrap();
    let (rgb, mask) = m.neural_renderer().forward(&f32("feature_image")).unwrap();
    HashMap::from([
        ("features".to_string(), g.features),
        ("offsets".to_string(), g.offsets),
        ("scales".to_string(), g.scales),
        ("rotations".to_string(), g.rotations),
        ("opacities".to_string(), g.opacities),
        ("colors".to_string(), g.colors),
        ("neural_rgb".to_string(), rgb),
        ("neural_mask".to_string(), mask),
    ])
}

/// (max abs, max rel = max|ours − official| / max|official|) of one output.
fn diff(ours: &Tensor, official: &Tensor) -> (f32, f32) {
    assert_eq!(ours.dims(), official.dims());
    let abs = (ours - official).unwrap().abs().unwrap();
    let max_abs = abs.max_all().unwrap().to_scalar::<f32>().unwrap();
    let scale = official.abs().unwrap().max_all().unwrap();
    (max_abs, max_abs / scale.to_scalar::<f32>().unwrap())
}

/// The worst relative difference over every output, after printing the table.
fn worst(ours: &HashMap<String, Tensor>, io: &HashMap<String, Tensor>, label: &str) -> f32 {
    println!("{label}\noutput | max abs | max rel | limit");
    OUTPUTS
        .iter()
        .map(|name| {
            let (a, r) = diff(&ours[*name], &io[*name]);
            println!("{name} | {a:.2e} | {r:.2e} | {LIMIT:.0e}");
            r
        })
        .fold(0f32, f32::max)
}

#[test]
fn our_forward_replays_the_official_forward_within_1e_4() {
    let io = io();
    let draws = ForwardDraws::from_tensors(&io).unwrap();
    let m = meta();
    // The fixture exercises what it claims: random pooling orders and ToMe draws, merging, and
    // several attention patches in every stage.
    assert_eq!(draws.pooling_orders.len(), 3);
    assert!(draws.pooling_orders.iter().any(|p| p[..2] != [0, 1]));
    assert_eq!(draws.tome_destinations.len(), 6);
    assert!(draws.tome_destinations.iter().flatten().any(|&k| k != 0));
    let cfg = fixture_config();
    assert_eq!(cfg.transformer.merge_ratio, 0.5);
    let voxels = m["voxels"].as_u64().unwrap() as usize;
    assert!(voxels > 4 * cfg.point_backbone.enc_patch_size[0]);
    let ours = forward(&model(&cfg), &io, &draws);
    let w = worst(&ours, &io, "replayed official draws");
    assert!(
        w <= LIMIT,
        "worst relative difference {w:.2e} > {LIMIT:.0e}"
    );
}

#[test]
fn a_wrong_replay_of_the_official_draws_fails_the_comparison() {
    let io = io();
    let draws = ForwardDraws::from_tensors(&io).unwrap();
    let m = model(&fixture_config());
    // Each is a wiring mistake of the replay: the deterministic forward (no draws), the
    // pooling permutations applied to the wrong levels, the ToMe draws of the decoder taken
    // from the encoder's blocks.
    let mut reversed = draws.clone();
    reversed.pooling_orders.reverse();
    let mut shifted = draws.clone();
    let enc = shifted.tome_destinations.len() / 2;
    for j in 0..enc {
        shifted.tome_destinations[enc + j] = draws.tome_destinations[j].clone();
    }
    let mut no_tome = draws.clone();
    no_tome.tome_destinations.clear();
    let mut transposed = draws.clone();
    for d in transposed.tome_destinations.iter_mut().flatten() {
        *d = (*d % 2) * 2 + *d / 2;
    }
    for (label, wrong) in [
        ("no draws", ForwardDraws::default()),
        ("pooling orders on the wrong levels", reversed),
        ("decoder ToMe draws from the encoder", shifted),
        ("ToMe draws ignored", no_tome),
        ("ToMe cell index read column-major", transposed),
    ] {
        let w = worst(&forward(&m, &io, &wrong), &io, label);
        assert!(w > LIMIT, "{label}: {w:.2e} passes");
    }
}

#[test]
fn frame_blocks_wired_to_the_wrong_levels_fail_the_comparison() {
    // The weights of frame blocks 1 and 2 swapped: the second and third multi-modal levels
    // read the wrong frame block, and the decoder merges on the wrong block's keys.
    let cfg = fixture_config();
    let weights =
        tensor_file::read_safetensors(&dir().join("model.safetensors"), &Device::Cpu).unwrap();
    let prefix = |i: usize| format!("transformer.image_backbone.frame_blocks.{i}.");
    let swapped: HashMap<String, Tensor> = weights
        .into_iter()
        .map(|(k, v)| {
            let k = if let Some(rest) = k.strip_prefix(&prefix(1)) {
                prefix(2) + rest
            } else if let Some(rest) = k.strip_prefix(&prefix(2)) {
                prefix(1) + rest
            } else {
                k
            };
            (k, v.to_dtype(DType::F32).unwrap())
        })
        .collect();
    let vb = candle_nn::VarBuilder::from_tensors(swapped, DType::F32, &Device::Cpu);
    let m = Lhmpp::new(&cfg, vb).unwrap();
    let io = io();
    let draws = ForwardDraws::from_tensors(&io).unwrap();
    let w = worst(
        &forward(&m, &io, &draws),
        &io,
        "frame blocks 1 and 2 swapped",
    );
    assert!(w > LIMIT, "swapped frame blocks: {w:.2e} passes");
}

#[test]
fn lhmpp_model_forward_reads_bool_masks_and_draws_and_writes_every_output() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg_path = tmp.path().join("config.json");
    std::fs::write(&cfg_path, serde_json::to_string(&fixture_config()).unwrap()).unwrap();
    let out = tmp.path().join("out.safetensors");
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_lhmpp"))
        .args(["model", "forward", "--checkpoint"])
        .arg(dir().join("model.safetensors"))
        .arg("--config-json")
        .arg(&cfg_path)
        .arg("--input")
        .arg(dir().join("io.safetensors"))
        .arg("-o")
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
    let ours = tensor_file::read_safetensors(&out, &Device::Cpu).unwrap();
    let w = worst(&ours, &io(), "lhmpp model forward");
    assert!(
        w <= LIMIT,
        "worst relative difference {w:.2e} > {LIMIT:.0e}"
    );
}
