//! Bad messages planted in a replayed bag (garbage and truncated CDR, images whose step and
//! size disagree or whose encoding is unsupported, a pose with an unknown bone, a shape out of
//! range) are each counted once by reason, and the counts agree everywhere: the warnings
//! logged, the summary `lhmpp replay` prints, the pipeline's counters and the last
//! ReconstructionStatus published. The good views still make an avatar. A bag with an
//! unreadable chunk replays everything else and the summary says what was skipped.

mod bag_support;

use lhmpp::bag::{BagReader, BagWriter};
use lhmpp::config::NodeConfig;
use lhmpp::msgs::{
    BodyPose, BodyShape, Header, Image, Quaternion, ReconstructionStatus, RosMessage, Transform,
};
use lhmpp::node::outputs::{AvatarUpdate, Publisher};
use lhmpp::node::pipeline::{Pipeline, RenderedFrame};
use lhmpp::node::rejections::RejectReason;
use lhmpp::node::replay::BagReplay;
use lhmpp::node::ros::{ResolvedTopics, RosNodeOptions};
use lhmpp::synth::capture::{image_topic, POSE_TOPIC, SHAPE_TOPIC, START_NS};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};
use std::time::Instant;

const VIEWS: usize = 3;

/// The planted bad messages by reason.
fn planted() -> BTreeMap<String, u64> {
    [("cdr", 3), ("image", 3), ("pose", 1), ("shape", 1)]
        .into_iter()
        .map(|(r, n)| (r.to_string(), n))
        .collect()
}

/// A synthetic person's bag with the bad messages written first.
fn bag_with_bad_messages(dir: &Path) -> PathBuf {
    let synth = bag_support::synthetic_person_bag(dir, "synth.mcap", VIEWS);
    let source = BagReader::open(&synth).unwrap();
    let path = dir.join("bad.mcap");
    let mut bag = BagWriter::create(&path).unwrap();
    let t = START_NS;
    let cam = |i: usize| image_topic(&format!("cam{i}"));
    // cdr 3: garbage on an image topic (twice), a BodyPose cut in half.
    let garbage = [0u8, 1, 0, 0, 0xde, 0xad, 0xbe, 0xef];
    bag.write_raw(&cam(0), Image::TYPE_NAME, t, &garbage)
        .unwrap();
    bag.write_raw(&cam(0), Image::TYPE_NAME, t, &garbage)
        .unwrap();
    let pose = |bone: &str| BodyPose {
        header: Header::default(),
        person_id: "person_0".into(),
        bone_names: vec![bone.into()],
        rotations: vec![Quaternion::default()],
        root: Transform::default(),
    };
    let cdr = pose("spine").encode_cdr();
    bag.write_raw(POSE_TOPIC, BodyPose::TYPE_NAME, t, &cdr[..cdr.len() / 2])
        .unwrap();
    // image 3: step and size disagree (twice), an unsupported encoding.
    let image = |encoding: &str, step: u32| Image {
        height: 4,
        width: 4,
        encoding: encoding.into(),
        step,
        data: vec![0; 48],
        ..Default::default()
    };
    bag.write(&cam(1), t, &image("rgb8", 13)).unwrap();
    bag.write(&cam(1), t, &image("rgb8", 13)).unwrap();
    bag.write(&cam(2), t, &image("16UC1", 12)).unwrap();
    // pose 1: a bone the skeleton does not have; shape 1: height_scale out of range.
    bag.write(POSE_TOPIC, t, &pose("tail_07")).unwrap();
    let shape = BodyShape {
        header: Header::default(),
        person_id: "person_0".into(),
        body_model: "makehuman-cc0".into(),
        shape_params: vec![1.0, 3.0],
    };
    bag.write(SHAPE_TOPIC, t, &shape).unwrap();
    for m in source.messages() {
        bag.write_raw(&m.topic, &m.type_name, m.log_time, &m.data)
            .unwrap();
    }
    bag.finish().unwrap();
    path
}

fn overrides(bag: &Path) -> Vec<String> {
    let topics: Vec<String> = (0..VIEWS)
        .map(|i| image_topic(&format!("cam{i}")))
        .collect();
    vec![
        format!("inputs.image_topics=[{}]", topics.join(",")),
        format!("inputs.shape_topic={SHAPE_TOPIC}"),
        "model.num_points=1024".into(),
        "frame_store.debounce_ms=0".into(),
        "outputs.dir=''".into(),
        "outputs.ros=false".into(),
        "outputs.render_rate_hz=0".into(),
        format!("replay.bag={}", bag.display()),
    ]
}

/// Runs `lhmpp replay --fast` on `bag` with the [`overrides`].
fn replay_cli(bag: &Path) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_lhmpp"));
    command.args(["replay", "--fast"]).arg(bag);
    for o in overrides(bag).iter().filter(|o| !o.starts_with("replay.")) {
        command.args(["--set", o]);
    }
    command.output().unwrap()
}

/// Keeps every status published.
#[derive(Clone, Default)]
struct Statuses(Arc<Mutex<Vec<ReconstructionStatus>>>);

impl Publisher for Statuses {
    fn avatar(&self, _: &AvatarUpdate<'_>) {}
    fn status(&self, msg: ReconstructionStatus) {
        self.0.lock().unwrap().push(msg);
    }
    fn frame(&self, _: &str, _: usize, _: &RenderedFrame, _: i64) {}
}

#[test]
fn rejections_agree_across_log_summary_pipeline_and_status() {
    let dir = tempfile::tempdir().unwrap();
    let bag = bag_with_bad_messages(dir.path());

    // The node's replay path, with a publisher that keeps the statuses.
    let text = NodeConfig::default().to_param_file();
    let cfg = NodeConfig::from_yaml(&text, "<defaults>".as_ref(), &overrides(&bag)).unwrap();
    let statuses = Statuses::default();
    let mut pipeline = Pipeline::new(&cfg, Some(Box::new(statuses.clone()))).unwrap();
    let options = RosNodeOptions::from_config(&cfg, BTreeMap::new(), None).unwrap();
    let topics = ResolvedTopics::from_options(&options).unwrap();
    let mut replay = BagReplay::open(&bag, topics, cfg.inputs.max_image_side).unwrap();
    let start = Instant::now();
    let clock = move || start.elapsed();
    lhmpp::node::run::run_replay(
        &mut pipeline,
        &mut replay,
        0.0,
        &AtomicBool::new(false),
        &clock,
    );
    let counted: BTreeMap<String, u64> = pipeline
        .rejections()
        .nonzero()
        .map(|(r, n)| (r.as_str().to_string(), n))
        .collect();
    assert_eq!(counted, planted());
    assert_eq!(pipeline.rejections().count(RejectReason::Frame), 0);
    assert_eq!(pipeline.views_held(), VIEWS, "the good views are held");
    let last = statuses
        .0
        .lock()
        .unwrap()
        .last()
        .cloned()
        .expect("a status");
    assert!(last.revision >= 1, "an avatar was made: {last:?}");
    let in_status: BTreeMap<String, u64> = last
        .rejected_reasons
        .iter()
        .cloned()
        .zip(last.rejected_counts.iter().copied())
        .collect();
    assert_eq!(in_status, planted(), "{last:?}");

    // `lhmpp replay`: the summary line and the warnings logged.
    let out = replay_cli(&bag);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    println!("{stdout}");
    assert!(
        stdout.contains("rejected messages 8 (cdr 3, image 3, pose 1, shape 1),"),
        "{stdout}"
    );
    let logged = stderr.lines().filter(|l| l.contains(" rejected")).count();
    assert_eq!(logged, 8, "{stderr}");
}

#[test]
fn a_damaged_bag_replays_the_other_views_and_the_summary_says_what_was_skipped() {
    let dir = tempfile::tempdir().unwrap();
    let synth = bag_support::synthetic_person_bag(dir.path(), "synth.mcap", VIEWS);
    // Everything but the images in the first chunk, then one chunk per image.
    let source = BagReader::open(&synth).unwrap();
    let path = dir.path().join("one_chunk_per_view.mcap");
    let mut bag = BagWriter::create_with(&path, bag_support::flushed_chunks()).unwrap();
    let (images, others): (Vec<_>, Vec<_>) = source
        .messages()
        .iter()
        .partition(|m| m.topic.ends_with("/image_raw"));
    for m in others.iter().chain(&images) {
        bag.write_raw(&m.topic, &m.type_name, m.log_time, &m.data)
            .unwrap();
        bag.flush().unwrap();
    }
    bag.finish().unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    let index = bag_support::chunk_index(&bytes);
    assert_eq!(index.len(), others.len() + VIEWS);
    let lost = &index[others.len() + 1];
    bag_support::flip_chunk_crc(&mut bytes, lost);
    std::fs::write(&path, &bytes).unwrap();

    let out = replay_cli(&path);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    println!("{stdout}");
    assert!(stdout.contains("views held 2,"), "{stdout}");
    assert!(
        !stdout.contains("revision 0,"),
        "an avatar was made: {stdout}"
    );
    let expected = format!(
        "bag {}: skipped 1 unreadable range ({} bytes, 1 messages lost)",
        path.display(),
        lost.chunk_length
    );
    assert!(stdout.contains(&expected), "{stdout}");
}

#[test]
fn rejections_reach_the_status_within_a_second_without_a_state_change() {
    let text = NodeConfig::default().to_param_file();
    let cfg =
        NodeConfig::from_yaml(&text, "<defaults>".as_ref(), &["outputs.dir=''".into()]).unwrap();
    let statuses = Statuses::default();
    let mut pipeline = Pipeline::new(&cfg, Some(Box::new(statuses.clone()))).unwrap();
    let at = |ms: u64| std::time::Duration::from_millis(ms);
    pipeline.step(at(0), || at(0));
    assert!(statuses.0.lock().unwrap().is_empty(), "nothing to say yet");
    pipeline.reject("/camera/image_raw", RejectReason::Cdr, "garbage");
    pipeline.step(at(10), || at(10));
    pipeline.reject("/camera/image_raw", RejectReason::Image, "step");
    pipeline.step(at(500), || at(500));
    pipeline.step(at(1010), || at(1010));
    pipeline.step(at(1500), || at(1500));
    let sent = statuses.0.lock().unwrap().clone();
    let counts: Vec<(Vec<String>, Vec<u64>)> = sent
        .iter()
        .map(|s| (s.rejected_reasons.clone(), s.rejected_counts.clone()))
        .collect();
    let names = |n: &[&str]| n.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    assert_eq!(
        counts,
        [
            (names(&["cdr"]), vec![1]),
            (names(&["cdr", "image"]), vec![1, 1])
        ],
        "one status at the first rejection, the next a second later, none without news"
    );
    assert!(sent
        .iter()
        .all(|s| s.state == ReconstructionStatus::STATE_IDLE && s.revision == 0));
}
