//! The released LHMPP-700M checkpoint as a user downloads it, without the real weights: a
//! hub folder (`config.json` = the official `model:` section, `model.safetensors` with
//! random bf16 values for exactly the official key list and shapes, the unused
//! `neural_renderer.transformer_block.*` included) and a small synthetic LHMPP-Prior, loaded
//! through the node's `Reconstructor` and run on 2 small views.

mod official_support;

use std::path::Path;
use std::time::Instant;

use lhmpp::config::ModelConfig;
use lhmpp::model::dpt::NeuralRenderer;
use lhmpp::model::hub;
use lhmpp::reconstruct::Reconstructor;

/// Official LHMPP-700M state-dict keys and shapes (converted from the reference enumeration).
const OFFICIAL_KEYS: &str = include_str!("fixtures/lhmpp_700m_state_dict_keys.tsv");
/// The `model:` section of the official `configs/train/LHMPP-any-view.yaml` as config.json.
const OFFICIAL_CONFIG: &str = include_str!("fixtures/official/config.json");

fn official_keys() -> Vec<(String, Vec<usize>)> {
    OFFICIAL_KEYS
        .lines()
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

/// SplitMix64 step.
fn splitmix(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Random bf16 bytes for one tensor: uniform with variance 1/fan_in for matrices and convs,
/// 1 ± 0.1 for norm weights, ±0.02 for other vectors; zeros for the unused blocks.
fn tensor_bytes(seed: u64, name: &str, dims: &[usize]) -> Vec<u8> {
    use rayon::prelude::*;
    let n: usize = dims.iter().product();
    if name.starts_with("neural_renderer.transformer_block.") {
        return vec![0u8; 2 * n];
    }
    let fan_in: usize = dims.iter().skip(1).product::<usize>().max(1);
    let (center, spread) = match dims.len() {
        0 | 1 if name.contains("norm") => (1.0f32, 0.1f32),
        0 | 1 => (0.0, 0.02),
        _ => (0.0, (3.0 / fan_in as f32).sqrt()),
    };
    let base = name.bytes().fold(seed, |h, b| splitmix(h ^ u64::from(b)));
    let mut out = vec![0u16; n];
    out.par_chunks_mut(4096).enumerate().for_each(|(c, chunk)| {
        let mut s = splitmix(base ^ c as u64);
        for four in chunk.chunks_mut(4) {
            s = splitmix(s);
            for (k, v) in four.iter_mut().enumerate() {
                // 16 random bits → uniform in [-1, 1).
                let u = ((s >> (16 * k)) & 0xffff) as f32 / 32768.0 - 1.0;
                *v = half::bf16::from_f32(center + spread * u).to_bits();
            }
        }
    });
    bytemuck::cast_slice::<u16, u8>(&out).to_vec()
}

/// Writes the hub folder; returns (tensors, parameters).
fn write_hub_folder(dir: &Path) -> (usize, usize) {
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(dir.join("config.json"), OFFICIAL_CONFIG).unwrap();
    let keys = official_keys();
    let data: Vec<(String, Vec<u8>, Vec<usize>)> = keys
        .iter()
        .map(|(k, d)| (k.clone(), tensor_bytes(7, k, d), d.clone()))
        .collect();
    let params = keys.iter().map(|(_, d)| d.iter().product::<usize>()).sum();
    official_support::write_tensors(
        &dir.join("model.safetensors"),
        safetensors::Dtype::BF16,
        &data,
    );
    (keys.len(), params)
}

#[test]
fn official_hub_folder_and_prior_run_through_the_node_reconstructor() {
    let tmp = tempfile::tempdir().unwrap();
    let hub = tmp.path().join("LHMPP-700M");
    let t0 = Instant::now();
    let (tensors, params) = write_hub_folder(&hub);
    assert_eq!(tensors, 1457);
    assert_eq!(params, 885_049_522);
    let t_write = t0.elapsed();
    let prior_dir = tmp.path().join("LHMPP-Prior");
    official_support::write_prior(&prior_dir, 4000);

    let config = ModelConfig {
        preset: "lhmpp-700m".into(),
        checkpoint: hub.display().to_string(),
        prior_dir: prior_dir.display().to_string(),
        num_points: 1200,
        ..ModelConfig::default()
    };
    let t1 = Instant::now();
    let mut recon = Reconstructor::new(&config, 4).unwrap();
    let t_load = t1.elapsed();
    assert_eq!(recon.input_size(), (840, 504), "the official input canvas");
    // The released layout's Gaussian RGB is latent: the node decodes it with the DPT head.
    assert_eq!(recon.rgb_kind(), lhmpp::model::RgbKind::Latent);
    assert_eq!(
        recon.neural_renderer_id(),
        format!("patch_4dptonly@{}", hub.display())
    );
    assert_eq!(
        recon.feature_channels(),
        recon.neural_renderer_config().in_channels
    );
    assert_eq!(
        recon.template().skeleton.len(),
        55,
        "bound to the SMPL-X prior"
    );

    // Two small views (8×8 patches of 14 px) instead of 840×504 to keep the CPU test fast;
    // the encoder interpolates its position embedding to any patch grid.
    let (a, b) = (
        official_support::view(112, 0),
        official_support::view(112, 10),
    );
    let t2 = Instant::now();
    let avatar = recon.reconstruct(&[(1, &a), (2, &b)]).unwrap();
    let t_forward = t2.elapsed();
    eprintln!(
        "write {:.1} s, load {:.1} s, forward (2 views 112², 1200 points) {:.1} s",
        t_write.as_secs_f64(),
        t_load.as_secs_f64(),
        t_forward.as_secs_f64()
    );
    assert_eq!(recon.encode_count(), 2);
    let g = &avatar.canonical;
    assert_eq!(g.len(), 1200);
    assert_eq!(avatar.skin.len(), 1200);
    assert_eq!(avatar.body_model, "smplx-lhmpp-prior");
    assert!(g.positions.iter().all(|p| p.is_finite()));
    assert!(g
        .rotations
        .iter()
        .all(|q| q.is_finite() && (q.length() - 1.0).abs() < 1e-3));
    // Scales are clamped to the official 5 cm, opacities are probabilities.
    for s in &g.scales {
        assert!(s.is_finite() && s.min_element() >= 0.0 && s.max_element() <= 0.05 + 1e-6);
    }
    assert!(g.opacities.iter().all(|o| (0.0..=1.0).contains(o)));
    // The official inference rules ran: hand Gaussians have opacity 0.95 exactly (random
    // weights never produce it), and the 0.02 m upper-body clamp holds for some Gaussians.
    assert!(g.opacities.iter().filter(|o| **o == 0.95).count() > 10);
    assert!(g.scales.iter().any(|s| s.max_element() <= 0.02));
    // Every Gaussian is skinned to SMPL-X joints.
    assert!(avatar.skin.bones.iter().flatten().all(|b| *b < 55));
    // Features for the neural renderer: 128 per Gaussian, finite.
    assert_eq!(g.feature_channels, 128);
    assert_eq!(g.features.len(), 1200 * 128);
    assert!(g.features.iter().all(|f| f.is_finite()));
    assert!(g.sh.iter().flatten().all(|c| c.is_finite()));

    drop(recon);

    // The neural renderer (the node's frames with outputs.renderer auto) runs on the same weights: a 131-channel
    // splat is reduced to its 128 features, patchified 7×7 and decoded to RGB + mask.
    // The folder was validated above; map only the renderer's tensors.
    let folder = hub::HubFolder::open(&hub).unwrap();
    // SAFETY: the files are not modified while mapped.
    let vb = unsafe {
        candle_nn::VarBuilder::from_mmaped_safetensors(
            &folder.weights,
            candle_core::DType::F32,
            &candle_core::Device::Cpu,
        )
    }
    .unwrap();
    let renderer =
        NeuralRenderer::new(&folder.config.neural_renderer, vb.pp("neural_renderer")).unwrap();
    let features =
        candle_core::Tensor::randn(0f32, 1.0, (1, 128, 56, 70), &candle_core::Device::Cpu).unwrap();
    let (rgb, mask) = renderer.forward(&features).unwrap();
    assert_eq!(rgb.dims(), &[1, 3, 56, 70]);
    assert_eq!(mask.dims(), &[1, 1, 56, 70]);
    for t in [rgb, mask] {
        let v = t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        assert!(v.iter().all(|x| x.is_finite() && (0.0..=1.0).contains(x)));
    }

    // `lhmpp model info FOLDER` summarises the hub folder from the headers alone.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_lhmpp"))
        .args(["model", "info"])
        .arg(&hub)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("equals preset lhmpp-700m"), "{text}");
    assert!(
        text.contains("valid: 1287 tensors, 738.64M parameters (1287 BF16)"),
        "{text}"
    );
    assert!(
        text.contains("ignored: neural_renderer.transformer_block.* (170 tensors, 146.40M)"),
        "{text}"
    );
    eprintln!("{text}");
}

#[test]
fn prior_settings_fail_fast_with_the_file_or_key_named() {
    let tmp = tempfile::tempdir().unwrap();
    // The prior is for the official network only.
    let tiny = ModelConfig {
        preset: "tiny".into(),
        prior_dir: tmp.path().display().to_string(),
        ..ModelConfig::default()
    };
    let err = Reconstructor::new(&tiny, 4).err().unwrap().to_string();
    assert!(
        err.contains("model.prior_dir") && err.contains("tiny"),
        "{err}"
    );
    // A missing prior file is reported before any weights are built or read.
    let official = ModelConfig {
        preset: "lhmpp-700m".into(),
        prior_dir: tmp.path().display().to_string(),
        ..ModelConfig::default()
    };
    let t = Instant::now();
    let err = Reconstructor::new(&official, 4).err().unwrap().to_string();
    assert!(err.contains("dense_sample_points/1_160000.ply"), "{err}");
    assert!(t.elapsed().as_secs_f64() < 2.0, "failed fast");
}
