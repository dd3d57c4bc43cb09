//! The pose path never waits for a reconstruction. The pipeline works as the live node runs it
//! (perception on its worker, reconstructions and renders beside the pose path,
//! `Pipeline::work_beside`), fed a 30 Hz camera of a walking synthetic person on the node's
//! clock, with the default network on twice its anchor points (a reconstruction takes from a
//! good part of a second to seconds on 2 cores, at background priority) and every frame a new
//! view (reconstructions rerun back to back). While a reconstruction runs, the pipeline's calls
//! return at once and the pose read from the camera keeps being published; so do the rendered
//! frames. (Run inline, as before, the pose stops for the whole of each reconstruction.)

use lhmpp::config::NodeConfig;
use lhmpp::msgs::{BodyPose, ReconstructionStatus};
use lhmpp::node::inputs::{CameraFrame, InputEvent};
use lhmpp::node::outputs::{AvatarUpdate, Publisher};
use lhmpp::node::pipeline::{Pipeline, RenderedFrame};
use lhmpp::synth::stream::{render_stream, StreamOptions};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// What the outputs saw, each when it came.
#[derive(Debug, Clone)]
enum Seen {
    Pose,
    Frame,
    Reconstructing,
    Published,
}

#[derive(Clone, Default)]
struct Recorder(Arc<Mutex<Vec<(Instant, Seen)>>>);

impl Recorder {
    fn note(&self, seen: Seen) {
        self.0.lock().unwrap().push((Instant::now(), seen));
    }
}

impl Publisher for Recorder {
    fn avatar(&self, _: &AvatarUpdate<'_>) {}
    fn status(&self, msg: ReconstructionStatus) {
        match msg.state {
            ReconstructionStatus::STATE_RECONSTRUCTING => self.note(Seen::Reconstructing),
            ReconstructionStatus::STATE_IDLE if msg.message == "avatar published" => {
                self.note(Seen::Published)
            }
            _ => {}
        }
    }
    fn frame(&self, _: &str, _: usize, _: &RenderedFrame, _: i64) {
        self.note(Seen::Frame);
    }
    fn pose(&self, _: &BodyPose) {
        self.note(Seen::Pose);
    }
}

const RATE_HZ: f64 = 30.0;
/// Anchor points of the test's network (the default is 4,096).
const NUM_POINTS: usize = 8_192;
/// Reconstructions shorter than this cannot show a stall at 30 Hz; they are not judged.
const JUDGED_RUN: Duration = Duration::from_millis(300);
/// Reconstructions judged before the test ends (it feeds up to `FEED_LIMIT`).
const JUDGED: usize = 2;
const FEED_LIMIT: Duration = Duration::from_secs(60);

#[test]
fn poses_keep_flowing_while_a_slow_reconstruction_runs() {
    let topic = "/cam0/image_raw";
    let mut cfg = NodeConfig::default();
    cfg.inputs.image_topics = vec![topic.into()];
    cfg.inputs.camera_info_topics = Vec::new();
    cfg.inputs.pose_source = lhmpp::config::PoseSource::Camera;
    cfg.outputs.camera_pose = true;
    cfg.outputs.dir = String::new();
    cfg.outputs.render_rate_hz = 10.0;
    cfg.outputs.preview_rate_hz = 0.0;
    // The embedded default network on more anchor points: a reconstruction long enough to
    // stall an inline pipeline for many frames.
    cfg.model.num_points = NUM_POINTS;
    cfg.frame_store.duplicate_similarity = 1.0;
    cfg.frame_store.debounce_ms = 0;
    let stream = render_stream(
        &StreamOptions {
            seed: 5,
            cameras: 1,
            frames: 30,
            width: 320,
            height: 240,
            points: 30_000,
        },
        |_, _| {},
    )
    .unwrap();
    let images: Vec<Arc<image::RgbImage>> = stream
        .images
        .into_iter()
        .map(|mut views| Arc::new(views.remove(0)))
        .collect();

    let seen = Recorder::default();
    let mut pipeline = Pipeline::new(&cfg, Some(Box::new(seen.clone()))).unwrap();
    pipeline.work_beside();
    let start = Instant::now();
    let clock = move || start.elapsed();
    let period = Duration::from_secs_f64(1.0 / RATE_HZ);
    // Feed until `JUDGED` reconstructions long enough to judge have ended after the first
    // (made of the first few views only, on a cold network), at most `FEED_LIMIT`.
    let mut longest_call = Duration::ZERO;
    let mut tick = 0u64;
    loop {
        let due = period.mul_f64(tick as f64);
        if let Some(wait) = due.checked_sub(clock()) {
            std::thread::sleep(wait);
        }
        let frame = CameraFrame {
            topic: topic.into(),
            frame_id: "cam0_optical".into(),
            stamp_ns: 1_700_000_000_000_000_000 + (due.as_nanos() as i64),
            arrival: clock(),
            image: images[tick as usize % images.len()].clone(),
        };
        let called = Instant::now();
        pipeline.handle(InputEvent::Frame(frame), clock());
        pipeline.step(clock(), clock);
        longest_call = longest_call.max(called.elapsed());
        tick += 1;
        if judged(&windows(&seen.0.lock().unwrap())).len() >= JUDGED || start.elapsed() > FEED_LIMIT
        {
            break;
        }
    }
    let events = seen.0.lock().unwrap().clone();
    let stats = pipeline.stats().clone();
    eprintln!(
        "{tick} frames in {:.1} s: perceived {}, camera poses {}, views held {}, \
         reconstructions {}, rendered frames {}",
        start.elapsed().as_secs_f64(),
        stats.perceived,
        stats.camera_poses,
        pipeline.views_held(),
        stats.reconstructions,
        stats.rendered_frames
    );
    drop(pipeline);
    let windows = windows(&events);
    eprintln!(
        "reconstructions (ms): {:?}",
        windows
            .iter()
            .map(|(from, to)| (*to - *from).as_millis())
            .collect::<Vec<_>>()
    );
    let judged = judged(&windows);
    assert!(
        judged.len() >= JUDGED,
        "{} reconstructions of at least {JUDGED_RUN:?} after the first in {FEED_LIMIT:?}",
        judged.len()
    );
    for (from, to) in &judged {
        let run = *to - *from;
        let poses: Vec<Instant> = events
            .iter()
            .filter(|(at, s)| matches!(s, Seen::Pose) && at > from && at < to)
            .map(|(at, _)| *at)
            .collect();
        let frames = events
            .iter()
            .filter(|(at, s)| matches!(s, Seen::Frame) && at > from && at < to)
            .count();
        let gap = std::iter::once(*from)
            .chain(poses.iter().copied())
            .chain(std::iter::once(*to))
            .collect::<Vec<_>>()
            .windows(2)
            .map(|w| w[1] - w[0])
            .max()
            .unwrap();
        eprintln!(
            "reconstruction of {:.0} ms: {} poses (longest gap {:.0} ms), {frames} frames",
            run.as_secs_f64() * 1e3,
            poses.len(),
            gap.as_secs_f64() * 1e3
        );
        assert!(
            poses.len() as f64 >= 0.25 * run.as_secs_f64() * RATE_HZ,
            "{} poses published during a {run:?} reconstruction",
            poses.len()
        );
        assert!(
            gap < run / 2,
            "no pose for {gap:?} of a {run:?} reconstruction"
        );
        assert!(
            frames >= 1,
            "no frame rendered during a {run:?} reconstruction"
        );
    }
    eprintln!(
        "longest handle + step: {:.1} ms",
        longest_call.as_secs_f64() * 1e3
    );
    assert!(
        longest_call < Duration::from_millis(300),
        "the pipeline's thread waited {longest_call:?} in one call"
    );
}

/// Each reconstruction's window: its "reconstructing" status to its "avatar published".
fn windows(events: &[(Instant, Seen)]) -> Vec<(Instant, Instant)> {
    let mut windows = Vec::new();
    let mut open = None;
    for (at, s) in events {
        match s {
            Seen::Reconstructing => open = Some(*at),
            Seen::Published => {
                if let Some(from) = open.take() {
                    windows.push((from, *at));
                }
            }
            _ => {}
        }
    }
    windows
}

/// The windows after the first (the network is warm, the store holds views) long enough to
/// show a stall.
fn judged(windows: &[(Instant, Instant)]) -> Vec<(Instant, Instant)> {
    windows
        .iter()
        .skip(1)
        .filter(|(from, to)| *to - *from >= JUDGED_RUN)
        .copied()
        .collect()
}
