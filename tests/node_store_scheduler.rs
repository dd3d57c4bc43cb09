//! Frame store + scheduler driven together by a simulated stream: 4 cameras × 100 frames of a
//! slowly turning synthetic person, preprocessed and embedded as the node does it, with a
//! reconstruction that takes longer than the frame interval.

use image::{Rgb, RgbImage};
use lhmpp::node::frame_store::{thumbnail_embedding, FrameStore, StoreLimits, View};
use lhmpp::node::scheduler::{Scheduler, SchedulerConfig};
use lhmpp::reconstruct::preprocess::{preprocess, BBox, PreprocessConfig, Subject};
use std::sync::Arc;
use std::time::Duration;

const CAMERAS: usize = 4;
const FRAMES_PER_CAMERA: u64 = 100;
const FRAME_INTERVAL_MS: u64 = 33;
const RECONSTRUCTION_MS: u64 = 400;

/// A 96×64 frame: grey background, a "person" whose coloured stripes shift as it turns by
/// `angle` (radians), seen from camera `cam`.
fn frame(cam: usize, angle: f32) -> RgbImage {
    let phase = angle + cam as f32 * std::f32::consts::FRAC_PI_2;
    RgbImage::from_fn(96, 64, |x, y| {
        if (36..60).contains(&x) && (8..60).contains(&y) {
            let stripe = ((y as f32 / 6.0 + phase * 3.0).sin() * 0.5 + 0.5) * 255.0;
            let side = ((x as f32 / 5.0 - phase * 2.0).cos() * 0.5 + 0.5) * 255.0;
            Rgb([stripe as u8, side as u8, (255.0 - stripe) as u8])
        } else {
            Rgb([90, 90, 90])
        }
    })
}

#[test]
fn stream_of_400_frames_keeps_at_most_k_views_and_few_reconstructions() {
    let k = 16;
    let mut store = FrameStore::new(StoreLimits {
        max_views: k,
        duplicate_similarity: 0.98,
        ..StoreLimits::default()
    });
    let mut sched = Scheduler::new(SchedulerConfig {
        debounce: Duration::from_millis(200),
        max_delay: Duration::from_millis(1000),
    });
    let pre = PreprocessConfig {
        out_height: 70,
        out_width: 42,
        ..PreprocessConfig::default()
    };
    let person_box = BBox {
        x0: 36,
        y0: 8,
        x1: 60,
        y1: 60,
    };

    let mut frame_id = 0u64;
    let mut in_flight: Option<(u64, Duration)> = None; // (revision, finishes at)
    let mut revisions = Vec::new();
    let mut latencies = Vec::new();
    let mut duplicates = 0;
    let mut max_memory = 0;
    let end = FRAMES_PER_CAMERA * FRAME_INTERVAL_MS + 5_000;
    for t_ms in 0..end {
        let now = Duration::from_millis(t_ms);
        // Finish the running job.
        if let Some((revision, done_at)) = in_flight {
            if now >= done_at {
                let done = sched
                    .finished("p0", revision, now)
                    .expect("job was in flight");
                latencies.push(done.latency);
                in_flight = None;
            }
        }
        // Frames from all cameras on the frame clock; the person turns a full circle.
        if t_ms % FRAME_INTERVAL_MS == 0 && t_ms / FRAME_INTERVAL_MS < FRAMES_PER_CAMERA {
            let i = t_ms / FRAME_INTERVAL_MS;
            // Still for the first half (pure duplicates), then turning.
            let angle = if i < 50 { 0.0 } else { (i - 50) as f32 * 0.06 };
            for cam in 0..CAMERAS {
                frame_id += 1;
                let img = preprocess(&frame(cam, angle), Subject::BBox(person_box), &pre).unwrap();
                let embedding = thumbnail_embedding(&img, 6);
                let view = View {
                    frame_id,
                    camera: format!("/cam{cam}/image_raw"),
                    stamp_ns: (t_ms * 1_000_000) as i64,
                    arrival: now,
                    image: Arc::new(img),
                    embedding,
                    evidence: None,
                    hidden: 0.0,
                };
                let outcome = store.insert("p0", view);
                if outcome.changed() {
                    sched.view_set_changed("p0", store.version("p0"), now, now);
                } else {
                    duplicates += 1;
                }
                assert!(store.len("p0") <= k);
                max_memory = max_memory.max(store.memory_bytes());
            }
        }
        for job in sched.poll(now) {
            assert!(in_flight.is_none(), "two reconstructions in flight");
            assert!(
                job.set_version <= store.version("p0"),
                "job for a future set"
            );
            revisions.push(job.revision);
            in_flight = Some((job.revision, now + Duration::from_millis(RECONSTRUCTION_MS)));
        }
    }

    let frames = CAMERAS as u64 * FRAMES_PER_CAMERA;
    eprintln!(
        "{frames} frames: {duplicates} duplicates dropped, {} reconstructions, latencies {:?}..{:?}",
        revisions.len(),
        latencies.iter().min(),
        latencies.iter().max()
    );
    assert_eq!(frame_id, frames);
    assert_eq!(store.len("p0"), k, "the turning person fills the store");
    // While still, each camera's repeated frame is a duplicate: at least 49 per camera.
    assert!(duplicates >= 4 * 49, "only {duplicates} duplicates dropped");
    assert!(
        (revisions.len() as u64) * 10 < frames,
        "{} reconstructions for {frames} frames",
        revisions.len()
    );
    assert!(revisions.len() >= 2, "the stream must trigger reruns");
    assert!(
        revisions.windows(2).all(|w| w[1] > w[0]),
        "revisions {revisions:?}"
    );
    assert_eq!(latencies.len(), revisions.len(), "every job completes");
    assert!(latencies
        .iter()
        .all(|l| *l >= Duration::from_millis(RECONSTRUCTION_MS)));
    // Memory bound: K views of one preprocessed image (3×70×42 f32) plus embeddings.
    let per_view = 3 * 70 * 42 * 4 + 3 * 36 * 4;
    assert!(
        max_memory <= k * per_view,
        "{max_memory} > {}",
        k * per_view
    );
}
