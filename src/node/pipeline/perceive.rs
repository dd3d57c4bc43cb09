//! Camera-only perception inside the pipeline, either on the pipeline's thread (bag replay:
//! every frame, in order) or on a worker thread of its own (live: one pending frame per camera,
//! the newest wins, so perception never stalls the pipeline and its memory stays bounded).
//!
//! One person ([`Finders::One`]): each camera's frames go through its own [`PersonTracker`]
//! (person mask, landmarks; MoveNet MultiPose finds the person to follow unless
//! `perception.person_detector` says BlazePose). Several people ([`Finders::Many`],
//! `tracking.enabled`): every frame is split into persons by a [`PeopleFinder`] and one
//! [`PersonTracks`] over all cameras gives each a stable id (using where they stand when the
//! camera is calibrated).
//!
//! A camera in which nobody is found for `perception::nobody::NOBODY_SECONDS` of frames is
//! named in one warning that says what looked for people and what to try.

use crate::node::inputs::CameraFrame;
use crate::perception::follow::PixelBox;
use crate::perception::nobody::{NobodyStretch, NobodyWatch};
use crate::perception::{
    Landmark, PeopleConfig, PeopleFinder, PersonDetector, PersonTracker, PoseNetworks,
    TrackerConfig, BODY_LANDMARKS,
};
use crate::reconstruct::preprocess::mask_bbox;
use crate::tracking::{BoxPx, Detection, FloorCamera, PersonTracks, TrackingConfig, TrackingStats};
use image::GrayImage;
use std::collections::{BTreeMap, HashMap, VecDeque};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Results waiting for the pipeline, at most this many (the oldest is then dropped, counted).
const RESULTS_KEPT: usize = 4;

/// How perception turns a frame into a mask.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MaskSettings {
    /// Person probability at the mask's edge.
    pub threshold: f32,
    /// Half-width of the soft edge, in probability.
    pub feather: f32,
}

/// The person perception found in a frame.
#[derive(Debug, Clone)]
pub struct PersonSeen {
    /// Thresholded, feathered mask over the whole frame.
    pub mask: Arc<GrayImage>,
    /// World landmarks (metres, hip-centred, the camera's axes).
    pub world: [Landmark; BODY_LANDMARKS],
    /// Image landmarks (frame pixels).
    pub image: [Landmark; BODY_LANDMARKS],
    /// The tracked person's id (`None`: one person is followed, the configured one).
    pub id: Option<String>,
    /// The largest share of the person's box another person's box covers in this frame (0
    /// when one person is followed): such views mix people's pixels.
    pub hidden: f32,
    /// One person: the camera's tracker took up someone unlike the person it followed before
    /// ([`crate::perception::Perceived::someone_else`]); always `false` with several people.
    pub someone_else: bool,
}

/// What perception made of one frame.
#[derive(Debug, Clone)]
pub struct PerceivedFrame {
    /// The frame.
    pub frame: CameraFrame,
    /// The persons found (one at most when one person is followed).
    pub people: Vec<PersonSeen>,
    /// Every person the tracker holds after this frame (empty when one person is followed).
    pub tracked: Vec<String>,
    /// What perception was asked to do with the frame.
    pub task: Task,
    /// Time the networks took for this frame.
    pub took: Duration,
}

/// What perception does with a frame, and where the frame goes after.
#[derive(Debug, Clone)]
pub enum Task {
    /// Find the person (or, tracking, the persons); their mask crops the frame for the store.
    Find,
    /// Read the person inside this mask (from a mask topic): their landmarks for the pose,
    /// the camera fit and the colours; the given mask crops the frame for the store.
    Within(Arc<GrayImage>),
    /// Read the person for the pose only: the frame is stored by another route.
    PoseOnly,
}

impl Task {
    /// Whether the frame goes on to the frame store after perception.
    pub fn stores(&self) -> bool {
        !matches!(self, Task::PoseOnly)
    }
}

/// A frame handed to perception, with its camera's calibration when known.
#[derive(Clone)]
pub struct Submitted {
    /// The frame.
    pub frame: CameraFrame,
    /// The camera, for where tracked persons stand (several people only).
    pub camera: Option<FloorCamera>,
    /// What to do with it.
    pub task: Task,
}

/// How persons are found.
pub enum Finders {
    /// One person: a [`PersonTracker`] per camera topic, sharing the networks.
    One {
        /// The trackers' settings.
        config: TrackerConfig,
        /// Trackers by camera topic.
        trackers: HashMap<String, PersonTracker>,
    },
    /// Several people: every person in every frame, ids across cameras.
    Many {
        /// MoveNet MultiPose, then the landmark model per person.
        finder: Box<PeopleFinder>,
        /// Person ids over all cameras.
        tracks: PersonTracks,
    },
}

impl Finders {
    /// One person per camera.
    pub fn one(config: TrackerConfig) -> Self {
        Self::One {
            config,
            trackers: HashMap::new(),
        }
    }

    /// Several tracked people.
    pub fn many(
        networks: Arc<PoseNetworks>,
        people: PeopleConfig,
        tracking: TrackingConfig,
    ) -> Self {
        Self::Many {
            finder: Box::new(PeopleFinder::new(networks, people)),
            tracks: PersonTracks::new(tracking),
        }
    }

    fn tracking_stats(&self) -> Option<TrackingStats> {
        match self {
            Self::One { .. } => None,
            Self::Many { tracks, .. } => Some(tracks.stats()),
        }
    }

    /// What looks for people in `topic`'s `width × height` frames, in words.
    fn searched_with(&self, topic: &str, width: u32, height: u32) -> String {
        match self {
            Self::One { trackers, .. } => trackers
                .get(topic)
                .map(|t| t.searched_with(width, height))
                .unwrap_or_default(),
            Self::Many { finder, .. } => finder.searched_with(width, height),
        }
    }
}

/// The warning for `topic`, in which nobody was found over `stretch`; `searched` says what
/// looked for people, `detector` which one-person detector ran (`None`: several people).
pub fn nobody_found_warning(
    topic: &str,
    stretch: NobodyStretch,
    searched: &str,
    detector: Option<PersonDetector>,
) -> String {
    let mut tips = vec![
        "people who stand far from the camera (under about a sixth of the frame's height) \
         need a larger perception.people_detector_side (384 or 512: more time per search)"
            .to_owned(),
    ];
    if detector == Some(PersonDetector::BlazePose) {
        tips.insert(
            0,
            "perception.person_detector: movenet finds people who fill little of the frame"
                .to_owned(),
        );
    }
    tips.push("more light on the people, or a camera nearer to where they stand".to_owned());
    format!(
        "camera {topic}: nobody found in {} frames over {:.1} s. Looked with {searched}, then \
         BlazePose's landmark model on the person's crop. Try: {}",
        stretch.frames,
        stretch.seconds,
        tips.join("; ")
    )
}

/// The finders and what they run on.
struct CameraTrackers {
    networks: Arc<PoseNetworks>,
    finders: Finders,
    masks: MaskSettings,
    pool: rayon::ThreadPool,
    /// Cameras watched for frames in which nobody is found, by topic.
    nobody: HashMap<String, NobodyWatch>,
    /// The warnings given (one per camera at most).
    warnings: Vec<String>,
}

impl CameraTrackers {
    fn perceive(&mut self, job: Submitted) -> PerceivedFrame {
        let done = self.find(job);
        self.watch(&done);
        done
    }

    /// Logs the one warning for a camera in which nobody has been found for long enough.
    fn watch(&mut self, done: &PerceivedFrame) {
        let frame = &done.frame;
        let watch = self.nobody.entry(frame.topic.clone()).or_default();
        let Some(stretch) = watch.observe(!done.people.is_empty(), seconds(frame)) else {
            return;
        };
        let (w, h) = frame.image.dimensions();
        let detector = match &self.finders {
            Finders::One { config, .. } => Some(config.detector),
            Finders::Many { .. } => None,
        };
        let searched = self.finders.searched_with(&frame.topic, w, h);
        let warning = nobody_found_warning(&frame.topic, stretch, &searched, detector);
        tracing::warn!("{warning}");
        self.warnings.push(warning);
    }

    fn find(&mut self, job: Submitted) -> PerceivedFrame {
        let started = Instant::now();
        let Submitted {
            frame,
            camera,
            task,
        } = job;
        let people = match &mut self.finders {
            Finders::One { config, trackers } => {
                let tracker = trackers
                    .entry(frame.topic.clone())
                    .or_insert_with(|| PersonTracker::new(self.networks.clone(), *config));
                let given = match &task {
                    Task::Within(mask) => Some((mask.clone(), given_box(mask))),
                    Task::Find | Task::PoseOnly => None,
                };
                let found = self.pool.install(|| match &given {
                    Some((_, None)) => Ok(None),
                    Some((_, Some(within))) => {
                        tracker.perceive_within(&frame.image, seconds(&frame), *within)
                    }
                    None => tracker.perceive_at(&frame.image, seconds(&frame)),
                });
                match found {
                    Ok(found) => found
                        .map(|p| PersonSeen {
                            mask: match &given {
                                Some((mask, _)) => mask.clone(),
                                None => Arc::new(
                                    p.mask.to_mask(self.masks.threshold, self.masks.feather),
                                ),
                            },
                            world: p.landmarks.world,
                            image: p.landmarks.image,
                            id: None,
                            hidden: 0.0,
                            someone_else: p.someone_else,
                        })
                        .into_iter()
                        .collect(),
                    Err(e) => {
                        tracing::error!(topic = %frame.topic, "perception failed: {e}");
                        tracker.reset();
                        Vec::new()
                    }
                }
            }
            Finders::Many { finder, tracks } => {
                match self.pool.install(|| finder.find(&frame.image)) {
                    Ok(found) => {
                        let detections: Vec<Detection> = found
                            .iter()
                            .map(|p| {
                                let bbox = BoxPx::new(p.min.to_array(), p.max.to_array());
                                Detection::seen(&frame.image, &p.mask, bbox, camera.as_ref())
                            })
                            .collect();
                        let ids = tracks.update(&frame.topic, seconds(&frame), &detections);
                        found
                            .into_iter()
                            .zip(ids)
                            .map(|(p, a)| PersonSeen {
                                mask: Arc::new(p.mask),
                                world: p.landmarks.world,
                                image: p.landmarks.image,
                                hidden: a.hidden,
                                id: Some(a.person_id),
                                someone_else: false,
                            })
                            .collect()
                    }
                    Err(e) => {
                        tracing::error!(topic = %frame.topic, "perception failed: {e}");
                        Vec::new()
                    }
                }
            }
        };
        let tracked = match &self.finders {
            Finders::One { .. } => Vec::new(),
            Finders::Many { tracks, .. } => {
                tracks.persons().into_iter().map(String::from).collect()
            }
        };
        PerceivedFrame {
            frame,
            people,
            tracked,
            task,
            took: started.elapsed(),
        }
    }
}

/// The box of a given person mask's pixels (≥ 128), `None` for an empty mask.
fn given_box(mask: &GrayImage) -> Option<PixelBox> {
    let b = mask_bbox(mask, 128)?;
    Some(PixelBox::new(
        glam::Vec2::new(b.x0 as f32, b.y0 as f32),
        glam::Vec2::new(b.x1 as f32, b.y1 as f32),
    ))
}

/// A frame's time in seconds: its stamp, else its arrival.
fn seconds(frame: &CameraFrame) -> f64 {
    if frame.stamp_ns > 0 {
        frame.stamp_ns as f64 * 1e-9
    } else {
        frame.arrival.as_secs_f64()
    }
}

/// Frames waiting for the worker and results waiting for the pipeline.
#[derive(Default)]
struct Exchange {
    /// The newest frame of each camera not yet taken by the worker.
    pending: BTreeMap<String, Submitted>,
    /// The tracker's counters after the last frame (several people only).
    tracking: Option<TrackingStats>,
    /// The nobody-found warnings given so far.
    warnings: Vec<String>,
    results: VecDeque<PerceivedFrame>,
    /// Pending frames replaced by a newer one of their camera.
    replaced: u64,
    /// Results dropped because the pipeline did not take them in time.
    overflowed: u64,
    /// The worker is perceiving a frame.
    working: bool,
    stop: bool,
}

/// The live worker: a thread of its own, fed through [`Exchange`].
struct Worker {
    shared: Arc<(Mutex<Exchange>, Condvar)>,
    thread: Option<JoinHandle<()>>,
}

impl Worker {
    fn start(mut trackers: CameraTrackers) -> Self {
        let shared = Arc::new((Mutex::new(Exchange::default()), Condvar::new()));
        let theirs = shared.clone();
        let thread = std::thread::Builder::new()
            .name("lhmpp-perception".into())
            .spawn(move || {
                let (lock, wake) = &*theirs;
                loop {
                    let frame = {
                        let mut x = lock.lock().expect("perception exchange poisoned");
                        loop {
                            if x.stop {
                                return;
                            }
                            // The camera whose pending frame arrived first goes first.
                            let next = x
                                .pending
                                .iter()
                                .min_by_key(|(_, f)| f.frame.arrival)
                                .map(|(topic, _)| topic.clone());
                            if let Some(frame) = next.and_then(|t| x.pending.remove(&t)) {
                                x.working = true;
                                break frame;
                            }
                            x = wake.wait(x).expect("perception exchange poisoned");
                        }
                    };
                    let done = trackers.perceive(frame);
                    let mut x = lock.lock().expect("perception exchange poisoned");
                    x.working = false;
                    x.tracking = trackers.finders.tracking_stats();
                    if x.warnings.len() != trackers.warnings.len() {
                        x.warnings.clone_from(&trackers.warnings);
                    }
                    x.results.push_back(done);
                    while x.results.len() > RESULTS_KEPT {
                        x.results.pop_front();
                        x.overflowed += 1;
                    }
                }
            })
            .expect("spawning the perception thread");
        Self {
            shared,
            thread: Some(thread),
        }
    }

    fn exchange(&self) -> std::sync::MutexGuard<'_, Exchange> {
        self.shared.0.lock().expect("perception exchange poisoned")
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        self.exchange().stop = true;
        self.shared.1.notify_all();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Where the trackers run.
enum Runner {
    /// On the caller's thread, every frame in order, when the results are taken.
    Inline {
        trackers: Box<CameraTrackers>,
        pending: VecDeque<Submitted>,
    },
    /// On a worker thread, the newest frame per camera.
    Worker(Worker),
}

/// The pipeline's perception stage.
pub struct Perception {
    runner: Runner,
}

impl Perception {
    /// A stage running the networks on `threads` CPU threads; `live` puts them on a worker
    /// thread (newest frame per camera wins), otherwise every frame is perceived in order on
    /// the caller's thread.
    pub fn new(
        networks: Arc<PoseNetworks>,
        finders: Finders,
        masks: MaskSettings,
        threads: usize,
        live: bool,
    ) -> Self {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads.max(1))
            .thread_name(|i| format!("lhmpp-perception-{i}"))
            .build()
            .expect("building the perception thread pool");
        let trackers = CameraTrackers {
            networks,
            finders,
            masks,
            pool,
            nobody: HashMap::new(),
            warnings: Vec::new(),
        };
        let runner = if live {
            Runner::Worker(Worker::start(trackers))
        } else {
            Runner::Inline {
                trackers: Box::new(trackers),
                pending: VecDeque::new(),
            }
        };
        Self { runner }
    }

    /// Hands a frame to perception for `task` (live: it replaces the camera's pending frame);
    /// `camera` is its calibration, when known.
    pub fn submit(&mut self, frame: CameraFrame, camera: Option<FloorCamera>, task: Task) {
        let job = Submitted {
            frame,
            camera,
            task,
        };
        match &mut self.runner {
            Runner::Inline { pending, .. } => pending.push_back(job),
            Runner::Worker(worker) => {
                {
                    let mut x = worker.exchange();
                    if x.pending.insert(job.frame.topic.clone(), job).is_some() {
                        x.replaced += 1;
                    }
                }
                worker.shared.1.notify_all();
            }
        }
    }

    /// The frames perceived since the last call, oldest first (inline: perceived now).
    pub fn take_results(&mut self) -> Vec<PerceivedFrame> {
        match &mut self.runner {
            Runner::Inline { trackers, pending } => {
                pending.drain(..).map(|f| trackers.perceive(f)).collect()
            }
            Runner::Worker(worker) => worker.exchange().results.drain(..).collect(),
        }
    }

    /// Whether frames are pending or being perceived.
    pub fn busy(&self) -> bool {
        match &self.runner {
            Runner::Inline { pending, .. } => !pending.is_empty(),
            Runner::Worker(worker) => {
                let x = worker.exchange();
                x.working || !x.pending.is_empty() || !x.results.is_empty()
            }
        }
    }

    /// The person tracker's counters (several people only).
    pub fn tracking_stats(&self) -> Option<TrackingStats> {
        match &self.runner {
            Runner::Inline { trackers, .. } => trackers.finders.tracking_stats(),
            Runner::Worker(worker) => worker.exchange().tracking,
        }
    }

    /// The warnings given for cameras in which nobody was found for
    /// `perception::nobody::NOBODY_SECONDS` of frames (one per camera at most).
    pub fn nobody_warnings(&self) -> Vec<String> {
        match &self.runner {
            Runner::Inline { trackers, .. } => trackers.warnings.clone(),
            Runner::Worker(worker) => worker.exchange().warnings.clone(),
        }
    }

    /// Frames dropped unperceived: replaced by a newer frame of their camera, or results the
    /// pipeline did not take in time.
    pub fn dropped(&self) -> u64 {
        match &self.runner {
            Runner::Inline { .. } => 0,
            Runner::Worker(worker) => {
                let x = worker.exchange();
                x.replaced + x.overflowed
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::perception::LandmarkModel;
    use image::RgbImage;

    /// `count` frames of an empty grey room on `topic`, `period_s` apart.
    fn empty_frames(topic: &str, count: usize, period_s: f64) -> Vec<CameraFrame> {
        let image = Arc::new(RgbImage::from_fn(320, 240, |x, y| {
            image::Rgb([90 + (x % 7) as u8, 95 + (y % 5) as u8, 100])
        }));
        (0..count)
            .map(|i| CameraFrame {
                topic: topic.into(),
                frame_id: "cam_optical".into(),
                stamp_ns: 1_700_000_000_000_000_000 + (i as f64 * period_s * 1e9) as i64,
                arrival: Duration::from_secs_f64(i as f64 * period_s),
                image: image.clone(),
            })
            .collect()
    }

    fn perception(finders: impl FnOnce(Arc<PoseNetworks>) -> Finders) -> Perception {
        let networks = Arc::new(PoseNetworks::load(LandmarkModel::Lite, None).unwrap());
        let masks = MaskSettings {
            threshold: 0.5,
            feather: 0.1,
        };
        Perception::new(networks.clone(), finders(networks), masks, 1, false)
    }

    #[test]
    fn a_camera_that_sees_nobody_for_seconds_gets_one_warning_saying_what_to_try() {
        let mut stage = perception(|_| Finders::one(TrackerConfig::default()));
        let log = crate::testing::warnings_logged(|| {
            // 2 Hz for 10 s on one camera, 3 frames on another: only the first is named.
            for frame in empty_frames("/cam0/image_raw", 20, 0.5)
                .into_iter()
                .chain(empty_frames("/cam1/image_raw", 3, 0.5))
            {
                stage.submit(frame, None, Task::Find);
                let done = stage.take_results();
                assert!(done.iter().all(|d| d.people.is_empty()));
            }
        });
        assert_eq!(log.matches(" WARN ").count(), 1, "{log}");
        let warnings = stage.nobody_warnings();
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        let w = &warnings[0];
        assert!(log.contains(w.as_str()), "{log}");
        for needed in [
            "camera /cam0/image_raw",
            "11 frames over 5.0 s",
            "MoveNet MultiPose at a 352×256 input (short side 256)",
            "perception.people_detector_side",
            "light",
        ] {
            assert!(w.contains(needed), "`{needed}` missing from: {w}");
        }
        assert!(!w.contains("perception.person_detector"), "{w}");
    }

    #[test]
    fn with_blazepose_the_warning_points_at_movenet() {
        let config = TrackerConfig {
            detector: PersonDetector::BlazePose,
            ..TrackerConfig::default()
        };
        let mut stage = perception(|_| Finders::one(config));
        // Logged under a subscriber too: a callsite first reached without one could be cached
        // as never interesting for the other test.
        let log = crate::testing::warnings_logged(|| {
            for frame in empty_frames("/cam0/image_raw", 12, 0.5) {
                stage.submit(frame, None, Task::Find);
                stage.take_results();
            }
        });
        assert_eq!(log.matches(" WARN ").count(), 1, "{log}");
        let warnings = stage.nobody_warnings();
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(
            warnings[0].contains("BlazePose's person detector at a 224×224 input"),
            "{}",
            warnings[0]
        );
        assert!(
            warnings[0].contains("perception.person_detector: movenet"),
            "{}",
            warnings[0]
        );
    }
}
