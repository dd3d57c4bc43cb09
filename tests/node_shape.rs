//! The optional body-shape input end to end: a bag written here (synthetic views plus a
//! `BodyShape`) is replayed through the node pipeline; the avatar carries the shape and is
//! built on anchors of the reshaped body, and malformed shapes are rejected without stopping it.

use lhmpp::bag::{BagReader, BagWriter};
use lhmpp::config::NodeConfig;
use lhmpp::msgs::{BodyShape, GaussianAvatar, Header, Image, ReconstructionStatus};
use lhmpp::node::outputs::{avatar_message, AvatarUpdate, Publisher};
use lhmpp::node::pipeline::{Pipeline, RenderedFrame};
use lhmpp::node::replay::{BagReplay, Replayed};
use lhmpp::node::ros::{ResolvedTopics, RosNodeOptions};
use lhmpp::synth::capture::{image_topic, SHAPE_TOPIC, START_NS};
use lhmpp::synth::{write_synthetic_bag, SynthOptions, SyntheticPerson};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

const SEED: u64 = 3;
const VIEWS: usize = 3;

/// Keeps every published avatar as its ROS 2 message.
#[derive(Clone, Default)]
struct Captured(Arc<Mutex<Vec<GaussianAvatar>>>);

impl Publisher for Captured {
    fn avatar(&self, u: &AvatarUpdate<'_>) {
        let msg = avatar_message(u).unwrap();
        self.0.lock().unwrap().push(msg);
    }
    fn status(&self, _: ReconstructionStatus) {}
    fn frame(&self, _: &str, _: usize, _: &RenderedFrame, _: i64) {}
}

fn config(shape_topic: &str) -> NodeConfig {
    let mut cfg = NodeConfig::default();
    cfg.inputs.image_topics = (0..VIEWS)
        .map(|i| image_topic(&format!("cam{i}")))
        .collect();
    cfg.inputs.shape_topic = shape_topic.into();
    // Whole frames, as these shape tests were written: the camera-only masks (inputs.person_mask
    // auto) change when the views' reconstructions run, which tests/node_perception.rs covers.
    cfg.inputs.person_mask = lhmpp::config::PersonMask::Off;
    cfg.model.num_points = 1024;
    cfg.frame_store.debounce_ms = 0;
    cfg.outputs.dir = String::new();
    cfg.outputs.render_rate_hz = 0.0;
    cfg
}

/// Replays `bag` into a pipeline as `lhmpp run` does at rate 0; returns the pipeline and the
/// avatars it published.
fn replay(bag: &Path, cfg: &NodeConfig) -> (Pipeline, Vec<GaussianAvatar>) {
    let captured = Captured::default();
    let mut pipeline = Pipeline::new(cfg, Some(Box::new(captured.clone()))).unwrap();
    let options = RosNodeOptions::from_config(cfg, BTreeMap::new(), None).unwrap();
    let topics = ResolvedTopics::from_options(&options).unwrap();
    let mut replay = BagReplay::open(bag, topics, cfg.inputs.max_image_side).unwrap();
    let start = Instant::now();
    let clock = move || start.elapsed();
    while let Some((_, item)) = replay.next(clock) {
        if let Replayed::Event(event) = item {
            pipeline.handle(event, clock());
        }
        pipeline.step(clock(), clock);
    }
    let deadline = clock() + Duration::from_secs(120);
    while !pipeline.idle() && clock() < deadline {
        std::thread::sleep(Duration::from_millis(5));
        pipeline.step(clock(), clock);
    }
    let avatars = captured.0.lock().unwrap().clone();
    (pipeline, avatars)
}

fn height_of(points: &[glam::Vec3]) -> f32 {
    let (lo, hi) = points.iter().fold((f32::MAX, f32::MIN), |(lo, hi), p| {
        (lo.min(p.y), hi.max(p.y))
    });
    hi - lo
}

fn synthetic_bag(dir: &Path, publish_shape: bool) -> std::path::PathBuf {
    let path = dir.join(format!("shape_{publish_shape}.mcap"));
    let options = SynthOptions {
        seed: SEED,
        views: VIEWS,
        heldout: 0,
        size: 96,
        points: 4000,
        publish_shape,
        ..SynthOptions::default()
    };
    write_synthetic_bag(&path, &options).unwrap();
    path
}

#[test]
fn replayed_shape_reaches_the_avatar_and_scales_its_anchors() {
    let dir = tempfile::tempdir().unwrap();
    let bag = synthetic_bag(dir.path(), true);
    let truth = SyntheticPerson::new(SEED, 100).unwrap().shape();
    // The test must tell a shaped body from an unshaped one.
    assert!((truth.height_scale - 1.0).abs() > 0.02, "{truth:?}");
    let sent = BagReader::open(&bag).unwrap();
    let shape_msgs: Vec<BodyShape> = sent
        .messages()
        .iter()
        .filter(|m| &*m.topic == SHAPE_TOPIC)
        .map(|m| sent.decode(m).unwrap())
        .collect();
    assert_eq!(shape_msgs.len(), 1);
    assert_eq!(shape_msgs[0].shape_params, truth.params().to_vec());

    let (shaped, avatars) = replay(&bag, &config(SHAPE_TOPIC));
    assert_eq!(shaped.stats().shapes_applied, 1);
    let last = avatars.last().expect("an avatar is published");
    assert_eq!(last.body_model, "makehuman-cc0");
    assert_eq!(last.shape_params, shape_msgs[0].shape_params);

    // Same bag, shape topic off: the unshaped body.
    let (plain, plain_avatars) = replay(&bag, &config(""));
    assert!(plain_avatars.last().unwrap().shape_params.is_empty());
    let ratio = height_of(&shaped.anchor_positions().unwrap())
        / height_of(&plain.anchor_positions().unwrap());
    assert!(
        (ratio / truth.height_scale - 1.0).abs() < 0.01,
        "anchor height ratio {ratio} vs height_scale {}",
        truth.height_scale
    );
    // The published skeleton is the shaped one too (its joints scale exactly).
    let joints_height = |a: &GaussianAvatar| {
        let ys: Vec<glam::Vec3> = a
            .bone_rest_positions
            .iter()
            .map(|p| glam::Vec3::new(p.x as f32, p.y as f32, p.z as f32))
            .collect();
        height_of(&ys)
    };
    let joint_ratio = joints_height(last) / joints_height(plain_avatars.last().unwrap());
    assert!(
        (joint_ratio - truth.height_scale).abs() < 1e-3,
        "{joint_ratio}"
    );
}

#[test]
fn malformed_shapes_are_rejected_and_the_avatar_still_comes_out() {
    let dir = tempfile::tempdir().unwrap();
    let source = BagReader::open(synthetic_bag(dir.path(), false)).unwrap();
    let path = dir.path().join("bad_shape.mcap");
    let mut bag = BagWriter::create(&path).unwrap();
    let bad = |model: &str, params: Vec<f32>| BodyShape {
        header: Header::default(),
        person_id: "person_0".into(),
        body_model: model.into(),
        shape_params: params,
    };
    bag.write(SHAPE_TOPIC, START_NS, &bad("makehuman-cc0", vec![1.0, 3.0]))
        .unwrap();
    bag.write(SHAPE_TOPIC, START_NS, &bad("makehuman-cc0", vec![1.1]))
        .unwrap();
    bag.write(SHAPE_TOPIC, START_NS, &bad("smplx", vec![0.5; 10]))
        .unwrap();
    bag.write(SHAPE_TOPIC, START_NS, &bad("scan", vec![1.0, 1.0]))
        .unwrap();
    for m in source.messages() {
        if m.topic.ends_with("/image_raw") {
            let image: Image = source.decode(m).unwrap();
            bag.write(&m.topic, m.log_time, &image).unwrap();
        }
    }
    bag.finish().unwrap();

    let (pipeline, avatars) = replay(&path, &config(SHAPE_TOPIC));
    assert_eq!(pipeline.stats().shapes_rejected, 4);
    assert_eq!(pipeline.stats().shapes_applied, 0);
    assert_eq!(pipeline.views_held(), VIEWS);
    let last = avatars.last().expect("the avatar still comes out");
    assert!(last.shape_params.is_empty());
    assert_eq!(last.gaussians.width, 1024);
}

#[test]
fn a_shape_after_the_views_reruns_the_reconstruction_with_it() {
    let dir = tempfile::tempdir().unwrap();
    let source = BagReader::open(synthetic_bag(dir.path(), false)).unwrap();
    let write = |name: &str, shape: Option<&BodyShape>| {
        let path = dir.path().join(name);
        let mut bag = BagWriter::create(&path).unwrap();
        let mut last = START_NS;
        for m in source.messages() {
            if m.topic.ends_with("/image_raw") {
                let image: Image = source.decode(m).unwrap();
                bag.write(&m.topic, m.log_time, &image).unwrap();
                last = last.max(m.log_time);
            }
        }
        if let Some(shape) = shape {
            bag.write(SHAPE_TOPIC, last + 1, shape).unwrap();
        }
        bag.finish().unwrap();
        path
    };
    let shape = BodyShape {
        person_id: "person_0".into(),
        body_model: "makehuman-cc0".into(),
        shape_params: vec![1.2, 1.0],
        ..Default::default()
    };
    let (_, without) = replay(&write("views.mcap", None), &config(SHAPE_TOPIC));
    let (shaped, with) = replay(
        &write("views_shape.mcap", Some(&shape)),
        &config(SHAPE_TOPIC),
    );
    assert_eq!(
        with.len(),
        without.len() + 1,
        "the shape alone triggers one rerun"
    );
    let last = with.last().unwrap();
    assert_eq!(last.revision as usize, with.len());
    assert_eq!(last.shape_params, vec![1.2, 1.0]);
    assert!(with[..without.len()]
        .iter()
        .all(|a| a.shape_params.is_empty()));
    let plain = Pipeline::new(&config(""), None).unwrap();
    let ratio = height_of(&shaped.anchor_positions().unwrap())
        / height_of(&plain.anchor_positions().unwrap());
    assert!((ratio - 1.2).abs() < 1e-3, "{ratio}");
}
