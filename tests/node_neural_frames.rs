//! `outputs.renderer` end to end: the demo bag's first view replayed through the node pipeline.
//! A small random network in the official layout (a hub folder whose `config.json` is the
//! released one with small widths, `neural_renderer.type: patch_4dptonly`, so its Gaussian RGB
//! is latent) publishes frames decoded by its DPT neural renderer with `auto`; the embedded
//! default (trained on its RGB) publishes Gaussian frames; `neural` with a renderer that reads
//! another width than the Gaussians carry fails at startup naming both.

mod official_support;

use lhmpp::config::{NodeConfig, RendererChoice};
use lhmpp::model::checkpoint::init_checkpoint;
use lhmpp::model::hub::HubFolder;
use lhmpp::msgs::{GaussianAvatar, ReconstructionStatus};
use lhmpp::node::outputs::{avatar_message, AvatarUpdate, Publisher};
use lhmpp::node::pipeline::{Pipeline, PipelineError, RenderedFrame};
use lhmpp::node::replay::{BagReplay, Replayed};
use lhmpp::node::ros::{ResolvedTopics, RosNodeOptions};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// The `model:` section of the official `configs/train/LHMPP-any-view.yaml` as config.json.
const OFFICIAL_CONFIG: &str = include_str!("fixtures/official/config.json");
const RENDER_SIZE: u32 = 64;
/// Frames to collect per run.
const FRAMES: usize = 3;

/// One published frame, reduced to what the tests compare.
#[derive(Debug, Clone)]
struct Frame {
    width: u32,
    height: u32,
    corner_rgb: [f32; 3],
    corner_alpha: f32,
    rgb8_len: usize,
}

#[derive(Default)]
struct Seen {
    avatars: Vec<GaussianAvatar>,
    statuses: Vec<ReconstructionStatus>,
    frames: Vec<Frame>,
}

#[derive(Clone, Default)]
struct Captured(Arc<Mutex<Seen>>);

impl Publisher for Captured {
    fn avatar(&self, u: &AvatarUpdate<'_>) {
        let msg = avatar_message(u).unwrap();
        self.0.lock().unwrap().avatars.push(msg);
    }
    fn status(&self, msg: ReconstructionStatus) {
        self.0.lock().unwrap().statuses.push(msg);
    }
    fn frame(&self, _: &str, _: usize, f: &RenderedFrame, _: i64) {
        let o = f.output();
        self.0.lock().unwrap().frames.push(Frame {
            width: f.width(),
            height: f.height(),
            corner_rgb: [o.rgb[0], o.rgb[1], o.rgb[2]],
            corner_alpha: o.alpha[0],
            rgb8_len: f.rgb8().as_raw().len(),
        });
    }
}

/// The node config: the demo bag's first camera only, one virtual camera, no files.
fn config(checkpoint: &str, renderer: RendererChoice) -> NodeConfig {
    let mut cfg = NodeConfig::default();
    cfg.inputs.image_topics = vec!["/cam0/image_raw".into()];
    cfg.model.checkpoint = checkpoint.into();
    cfg.model.num_points = 1024;
    cfg.frame_store.debounce_ms = 0;
    cfg.outputs.dir = String::new();
    cfg.outputs.render_size = RENDER_SIZE;
    cfg.outputs.virtual_cameras = 1;
    // A 1 ms period: the neural path cannot hold it, so frames drop by policy.
    cfg.outputs.render_rate_hz = 1000.0;
    cfg.outputs.renderer = renderer;
    cfg
}

/// Replays the demo bag into a pipeline, then keeps stepping until `FRAMES` frames are out.
fn replay(cfg: &NodeConfig) -> (Pipeline, Captured) {
    let captured = Captured::default();
    let mut pipeline = Pipeline::new(cfg, Some(Box::new(captured.clone()))).unwrap();
    let options = RosNodeOptions::from_config(cfg, BTreeMap::new(), None).unwrap();
    let topics = ResolvedTopics::from_options(&options).unwrap();
    let bag = Path::new(env!("CARGO_MANIFEST_DIR")).join("bags/demo.mcap");
    let mut replay = BagReplay::open(&bag, topics, cfg.inputs.max_image_side).unwrap();
    let start = Instant::now();
    let clock = move || start.elapsed();
    while let Some((_, item)) = replay.next(clock) {
        if let Replayed::Event(event) = item {
            pipeline.handle(event, clock());
        }
        pipeline.step(clock(), clock);
    }
    let deadline = clock() + Duration::from_secs(300);
    while (!pipeline.idle() || captured.0.lock().unwrap().frames.len() < FRAMES)
        && clock() < deadline
    {
        std::thread::sleep(Duration::from_millis(2));
        pipeline.step(clock(), clock);
    }
    (pipeline, captured)
}

/// A hub folder in the official layout with small widths: the released `config.json` with a
/// ViT-S encoder (frame blocks and `pcl_dim` at its width), a small point backbone, 128
/// feature channels per Gaussian (the width of the official `background_embedding`, so the
/// white background feature can be splatted with them) and a neural renderer reading
/// `renderer_channels`; seeded random f32 weights for exactly its tensors.
fn small_hub_folder(dir: &Path, renderer_channels: usize) {
    use serde_json::json;
    std::fs::create_dir_all(dir).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(OFFICIAL_CONFIG).unwrap();
    official_support::vit_s_widths(&mut v);
    official_support::slim_point_backbone(&mut v);
    v["gs_query_dim"] = json!(128);
    v["gs_mlp_network_config"]["n_neurons"] = json!(64);
    v["neural_renderer"]["enc_channels"] = json!(renderer_channels);
    v["neural_renderer"]["img_dim"] = json!(64);
    assert_eq!(v["neural_renderer"]["type"], "patch_4dptonly");
    std::fs::write(dir.join("config.json"), v.to_string()).unwrap();
    // HubFolder::open needs a weight file to exist; the real one replaces it.
    let weights = dir.join("model.safetensors");
    safetensors::serialize_to_file(
        Vec::<(String, safetensors::tensor::TensorView)>::new(),
        None,
        &weights,
    )
    .unwrap();
    let hub = HubFolder::open(dir).unwrap();
    assert_eq!(hub.config.gs_head.gs_query_dim, 128);
    assert_eq!(hub.config.neural_renderer.in_channels, renderer_channels);
    init_checkpoint(&hub.config, 3, &weights).unwrap();
}

#[test]
fn auto_renders_a_latent_rgb_hub_checkpoint_through_its_neural_renderer() {
    let tmp = tempfile::tempdir().unwrap();
    let hub = tmp.path().join("LHMPP-small");
    small_hub_folder(&hub, 128);
    let cfg = config(&hub.display().to_string(), RendererChoice::Auto);
    let (pipeline, captured) = replay(&cfg);
    assert!(pipeline.neural_frames(), "auto picks the neural renderer");
    let seen = captured.0.lock().unwrap();
    assert_eq!(seen.avatars.len(), 1);
    let avatar = &seen.avatars[0];
    assert!(!avatar.rgb_display_ready);
    assert_eq!(
        avatar.neural_renderer,
        format!("patch_4dptonly@{}", hub.display())
    );
    assert!(seen.frames.len() >= FRAMES, "{} frames", seen.frames.len());
    for f in &seen.frames {
        // Rendered at 70² (a multiple of the patch 7), published at the configured size.
        assert_eq!((f.width, f.height), (RENDER_SIZE, RENDER_SIZE));
        assert_eq!(f.rgb8_len, (3 * RENDER_SIZE * RENDER_SIZE) as usize);
        // The corner shows only the background: the rasteriser's alpha there is exactly 0 and
        // its RGB white; the DPT head's mask is a sigmoid, strictly inside (0, 1).
        assert!(
            f.corner_alpha > 0.0 && f.corner_alpha < 1.0,
            "{}",
            f.corner_alpha
        );
        assert!(f.corner_rgb.iter().all(|c| c.is_finite()));
    }
    let stats = pipeline.stats();
    assert!(stats.frames_dropped > 0, "{stats:?}");
    assert!(stats.last_render_ms > 0.0);
    // The drop is said once, in a status that carries the render time.
    let slow: Vec<&ReconstructionStatus> = seen
        .statuses
        .iter()
        .filter(|s| s.message.contains("below outputs.render_rate_hz"))
        .collect();
    assert_eq!(slow.len(), 1, "{:?}", seen.statuses);
    assert!(slow[0].last_render_ms > 1.0, "{:?}", slow[0]);
}

#[test]
fn auto_renders_the_embedded_default_from_its_gaussian_rgb() {
    let cfg = config("", RendererChoice::Auto);
    let (pipeline, captured) = replay(&cfg);
    assert!(!pipeline.neural_frames());
    let seen = captured.0.lock().unwrap();
    assert_eq!(seen.avatars.len(), 1);
    assert!(seen.avatars[0].rgb_display_ready);
    assert_eq!(seen.avatars[0].neural_renderer, "");
    assert!(seen.frames.len() >= FRAMES);
    for f in &seen.frames {
        assert_eq!((f.width, f.height), (RENDER_SIZE, RENDER_SIZE));
        assert_eq!(f.corner_alpha, 0.0);
        assert_eq!(f.corner_rgb, [1.0; 3], "white background");
    }
}

#[test]
fn neural_with_a_renderer_of_another_width_fails_at_startup_naming_both() {
    let tmp = tempfile::tempdir().unwrap();
    let hub = tmp.path().join("LHMPP-mismatch");
    small_hub_folder(&hub, 48);
    let cfg = config(&hub.display().to_string(), RendererChoice::Neural);
    let err = match Pipeline::new(&cfg, None) {
        Err(e @ PipelineError::Renderer(_)) => e.to_string(),
        Err(e) => panic!("unexpected error: {e}"),
        Ok(_) => panic!("neural with 128 features and a 48-channel renderer must fail"),
    };
    assert!(
        err.contains("outputs.renderer") && err.contains("128") && err.contains("48"),
        "{err}"
    );
    // auto falls back to the Gaussians' RGB for the same network.
    let cfg = config(&hub.display().to_string(), RendererChoice::Auto);
    assert!(!Pipeline::new(&cfg, None).unwrap().neural_frames());
}
