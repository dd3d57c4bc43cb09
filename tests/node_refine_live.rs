//! Refinement as the live node runs it: the demo bag's four calibrated views (no mask topics,
//! so perception reads the person and CameraInfo, `/tf_static` and the pose topic place each
//! view) fed to a pipeline whose jobs run beside the pose path (`Pipeline::work_beside`). Each
//! job's avatar is refined on the jobs lane after the network made it, a refined avatar that
//! beat the network's is published under a revision of its own, and the fit never holds the
//! pipeline's calls up.

use lhmpp::config::NodeConfig;
use lhmpp::msgs::{BodyPose, ReconstructionStatus};
use lhmpp::node::outputs::{AvatarUpdate, Publisher};
use lhmpp::node::pipeline::{Pipeline, RenderedFrame};
use lhmpp::node::replay::{BagReplay, Replayed};
use lhmpp::node::ros::{ResolvedTopics, RosNodeOptions};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Revisions of the avatars published, and the statuses' messages.
#[derive(Clone, Default)]
struct Recorder {
    avatars: Arc<Mutex<Vec<u64>>>,
    statuses: Arc<Mutex<Vec<String>>>,
}

impl Publisher for Recorder {
    fn avatar(&self, update: &AvatarUpdate<'_>) {
        self.avatars.lock().unwrap().push(update.revision);
    }
    fn status(&self, msg: ReconstructionStatus) {
        self.statuses.lock().unwrap().push(msg.message);
    }
    fn frame(&self, _: &str, _: usize, _: &RenderedFrame, _: i64) {}
    fn pose(&self, _: &BodyPose) {}
}

#[test]
fn live_jobs_publish_their_refined_avatar_under_a_revision_of_their_own() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let bag = root.join("bags/demo.mcap");
    let overrides = [
        "inputs.mask_topics=[]".to_string(),
        "outputs.dir=\"\"".to_string(),
        "outputs.virtual_cameras=1".to_string(),
        format!("replay.bag={}", bag.display()),
    ];
    let config = NodeConfig::load(&root.join("launch_configs/demo.yaml"), &overrides).unwrap();
    let options = RosNodeOptions::from_config(&config, BTreeMap::new(), None).unwrap();
    let topics = ResolvedTopics::from_options(&options).unwrap();
    let mut pipeline = Pipeline::new(&config, None).unwrap();
    pipeline.set_cameras(topics.images.clone());
    let recorder = Recorder::default();
    pipeline.set_publisher(Some(Box::new(recorder.clone()) as Box<dyn Publisher>));
    pipeline.work_beside();
    let mut replay = BagReplay::open(&bag, topics, config.inputs.max_image_side).unwrap();
    let started = Instant::now();
    let clock = || started.elapsed();
    let mut longest_call = Duration::ZERO;
    let mut call = |f: &mut dyn FnMut()| {
        let t = Instant::now();
        f();
        longest_call = longest_call.max(t.elapsed());
    };
    while let Some((_, item)) = replay.next(clock) {
        if let Replayed::Event(event) = item {
            let mut event = Some(event);
            call(&mut || pipeline.handle(event.take().expect("handled once"), clock()));
        }
        call(&mut || pipeline.step(clock(), clock));
    }
    while !pipeline.idle() {
        assert!(clock() < Duration::from_secs(300), "the jobs did not end");
        std::thread::sleep(Duration::from_millis(5));
        call(&mut || pipeline.step(clock(), clock));
    }
    let stats = pipeline.stats();
    assert!(stats.reconstructions >= 1);
    assert!(
        stats.refinements >= 1,
        "live, a job's avatar is refined after the network made it"
    );
    assert!(stats.refinements_kept >= 1, "{stats:?}");
    let avatars = recorder.avatars.lock().unwrap().clone();
    assert!(
        avatars.windows(2).all(|w| w[0] < w[1]),
        "revisions increase: {avatars:?}"
    );
    assert_eq!(
        pipeline.revision(),
        *avatars.last().unwrap(),
        "the person's latest is the last avatar published"
    );
    let statuses = recorder.statuses.lock().unwrap().clone();
    assert!(
        statuses
            .iter()
            .any(|m| m.contains("refined:") && m.contains("steps") && m.contains("kept")),
        "the status says how far the fit went: {statuses:?}"
    );
    // The fit runs on the jobs lane: the pipeline's calls return at once (a fit takes seconds).
    assert!(
        longest_call < Duration::from_millis(1000),
        "a pipeline call took {longest_call:?}"
    );
}
