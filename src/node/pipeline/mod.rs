//! The node's processing pipeline, synchronous and driven by [`InputEvent`]s and a clock. The
//! [`Pipeline`] is a small dispatcher; a camera frame goes one way through its rooms:
//!
//! 1. [`intake`]: each camera's frames go to perception, wait for their mask topic, or go on
//!    whole;
//! 2. [`perceive`]: camera-only perception finds the persons, their masks and landmarks, and
//!    (with tracking) gives each a stable id;
//! 3. [`people`]: the persons perceived go to their [`Person`](person::Person) (made when first
//!    seen, released when the tracker lets go, handed over by cluster membership), and
//!    [`bodies`] does the same for poses and body shapes;
//! 4. [`person`]: each person's frame store, shape, pose path and schedule, and the steps that
//!    run for them (reconstruction, rendering);
//! 5. [`jobs`], [`publish`]: avatars, statuses, frames, previews and the end-of-replay
//!    animation leave through one [`Fanout`] of [`crate::node::outputs`]: the files (when
//!    `outputs.dir` is usable) and the live publishers (ROS 2, shared memory, the live page).
//!
//! The pose path (a perceived frame → the person's pose → published) never waits for a
//! reconstruction or a render: those run on [`lane`]s beside it, inline in a bag replay (the
//! same avatars whatever the machine's speed) and, once [`Pipeline::work_beside`] is called
//! (live runs), on threads of their own at a lower priority, their results coming back as
//! messages. Live topics and bag replay feed it the same events, so both share this code path.

mod bodies;
pub mod calibration;
mod intake;
mod jobs;
mod lane;
pub mod masks;
pub mod membership;
pub mod neural_frames;
mod people;
pub mod perceive;
mod person;
mod publish;
mod queries;
pub mod render;
mod setup;
mod stats;

pub use render::RenderedFrame;
pub use setup::PipelineError;
pub use stats::PipelineStats;

use crate::config::{Delight, PersonMask, PoseSource};
use crate::node::frame_store::StoreLimits;
use crate::node::inputs::InputEvent;
use crate::node::outputs::{Fanout, Publisher};
use crate::node::rejections::{RejectReason, Rejections};
use crate::node::scheduler::{first_waiting_first, SchedulerConfig};
use crate::perception::pose::PoseEstimator;
use crate::reconstruct::preprocess::PreprocessConfig;
use calibration::Calibration;
use jobs::{JobDone, SharedNetwork};
use lane::{Background, Lane};
use masks::MaskPairing;
use membership::Membership;
use perceive::Perception;
use person::Person;
use publish::Drawn;
use render::{FrameRenderer, VirtualCameras};
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// How often the pipeline looks for the lanes' results while they work.
const LANE_POLL: Duration = Duration::from_millis(5);
/// Tasks the drawing lane holds at once: a batch of frames and a preview.
const DRAWINGS_WAITING: usize = 2;

/// What every person is made with when first seen.
struct PersonSetup {
    /// Their frame store's bounds.
    limits: StoreLimits,
    /// Their schedule's debounce.
    schedule: SchedulerConfig,
    /// Where their pose comes from.
    source: PoseSource,
    /// A fresh pose estimator (`None`: no camera pose), cloned for each person.
    estimator: Option<PoseEstimator>,
    /// Publish camera poses on the pose topic, in this world frame.
    publish_pose: Option<String>,
}

/// The node's pipeline: the configured person, or (`tracking.enabled`) every tracked person,
/// each with their own frame store, schedule, avatar and frames.
pub struct Pipeline {
    /// The configured `person_id` (the one person without tracking).
    default_person: String,
    /// Persons come from the tracker (`tracking.enabled`).
    tracking: bool,
    /// Which persons this node reconstructs (`cluster`).
    membership: Membership,
    /// Every person followed, by id.
    persons: BTreeMap<String, Person>,
    setup: PersonSetup,
    /// The network, shared by every person's reconstructions.
    network: SharedNetwork,
    /// Where persons' jobs run (reconstructions).
    jobs: Lane<JobDone>,
    /// Where frames are rendered and the preview posed.
    drawing: Lane<Drawn>,
    /// A batch of frames, a preview is on the drawing lane.
    drawing_frames: bool,
    drawing_preview: bool,
    /// When the pipeline next looks for the lanes' results.
    lanes_due: Duration,
    preprocess: PreprocessConfig,
    next_frame_id: u64,
    masks: MaskPairing,
    /// `inputs.person_mask`, and whether a mask topic is shared by every camera.
    person_mask: PersonMask,
    shared_mask_topic: bool,
    /// Camera-only perception (`None` when no camera needs it).
    perception: Option<Perception>,
    /// When the pipeline next looks for perception results.
    perception_due: Duration,
    /// Recolour avatars from the perceived views (`perception.colours_from_views`), with a
    /// fitted key light divided out from these views (`perception.delight`).
    colours_from_views: bool,
    delight: Delight,
    /// Refinement of each job's avatar (`refine.*`; `None`: off).
    refine: Option<jobs::RefinePlan>,
    /// What stops a fit in flight (shared with [`jobs::RefinePlan::news`]).
    refine_news: Arc<std::sync::atomic::AtomicU64>,
    /// A replay's jobs are refined too (set at its end by [`Pipeline::refine_at_end`]).
    refine_inline: bool,
    /// Camera calibration (and the shape reader).
    calibration: Calibration,
    /// Where results go: the files first, then the live publishers (shared with the lanes).
    outputs: Arc<Fanout>,
    publish_masks: bool,
    cameras: Arc<VirtualCameras>,
    frames: Arc<Mutex<FrameRenderer>>,
    /// Frames go through the neural renderer.
    neural_frames: bool,
    render_period: Option<Duration>,
    render_rate_hz: f64,
    next_render: Duration,
    preview_period: Option<Duration>,
    next_preview: Duration,
    /// Fractional render periods skipped, not yet counted in `frames_dropped`.
    drop_debt: f64,
    /// Whether the "renders slower than the rate" warning was logged.
    slow_render_noted: bool,
    stats: PipelineStats,
    /// Rejections counted by the live subscriptions, as last reported.
    input_rejections: Rejections,
    /// When rejections may next republish the status (node clock).
    status_refresh_due: Duration,
}

impl Pipeline {
    /// Sets up the network, the perception, the renderers and the outputs from the node config.
    pub fn new(
        config: &crate::config::NodeConfig,
        publisher: Option<Box<dyn Publisher>>,
    ) -> Result<Self, PipelineError> {
        setup::pipeline(config, publisher)
    }

    /// Replaces the live publishers (ROS 2, shared memory); the files stay (the node sets
    /// them once the ROS 2 endpoint is up: the pipeline is built first, so a config that
    /// cannot run fails before DDS starts). Set before any work runs: while a lane holds the
    /// outputs, the publishers stay as they are (logged).
    pub fn set_publisher(&mut self, publisher: Option<Box<dyn Publisher>>) {
        match Arc::get_mut(&mut self.outputs) {
            Some(outputs) => outputs.replace_live(publisher),
            None => tracing::error!("the outputs are in use: the live publishers stay"),
        }
    }

    /// Runs reconstructions and the rendering of frames on threads of their own from now on,
    /// at a lower priority than the pose path (reconstructions niceness +10 on a pool of one
    /// thread per core, frames +5 on one thread, or one per core for the neural renderer): the live node calls this once, before any
    /// input. Without it (bag replay,
    /// tests) they run inline, on the caller's thread.
    pub fn work_beside(&mut self) {
        if self.jobs.threaded() {
            return;
        }
        // Nothing is in flight before the first input: the inline lanes are empty.
        self.jobs = Lane::thread(
            "lhmpp-jobs",
            jobs::JOBS_WAITING,
            Background::new("jobs", 0, lane::JOBS_NICENESS),
        );
        // Frames are drawn on a pool of their own, never behind a reconstruction's work, above
        // it in priority and below the pose path: one thread splats them (milliseconds each),
        // one per core runs the neural renderer.
        let drawing_threads = if self.neural_frames { 0 } else { 1 };
        self.drawing = Lane::thread(
            "lhmpp-drawing",
            DRAWINGS_WAITING,
            Background::new("drawing", drawing_threads, lane::DRAWING_NICENESS),
        );
    }

    /// Sets the camera topics (resolved) that have their own mask topic: their frames wait up
    /// to 150 ms for their mask before going on as whole frames.
    pub fn set_masked_cameras(&mut self, cameras: impl IntoIterator<Item = String>) {
        self.masks.set_masked_cameras(cameras);
    }

    /// Sets the camera topics (resolved: images, then compressed images) that CameraInfo
    /// messages pair with by position.
    pub fn set_cameras(&mut self, cameras: Vec<String>) {
        self.calibration.set_cameras(cameras);
    }

    /// Live cluster membership from `now` on: members whose heartbeat stops for 2 s hand
    /// their persons to the others (the node calls this once its ROS 2 endpoint is up).
    pub fn expect_heartbeats(&mut self, now: Duration) {
        self.membership.expect_heartbeats(now);
    }

    /// Counts and logs an input message rejected before it became an event (a bag message
    /// whose CDR or image does not decode).
    pub fn reject(&mut self, topic: &str, reason: RejectReason, detail: &str) {
        self.stats.rejections.add(reason);
        tracing::warn!(%topic, reason = reason.as_str(), "bag message rejected: {detail}");
    }

    /// Sets the rejections the live subscriptions have counted so far (they log their own).
    pub fn set_input_rejections(&mut self, rejections: Rejections) {
        self.input_rejections = rejections;
    }

    /// Feeds one input event; `now` is the node clock.
    pub fn handle(&mut self, event: InputEvent, now: Duration) {
        match event {
            InputEvent::Frame(frame) => self.on_camera_frame(frame, now),
            InputEvent::Mask(mask) => {
                if matches!(self.person_mask, PersonMask::Auto | PersonMask::Topic) {
                    let ready = self.masks.mask(mask);
                    self.admit(ready, now);
                }
            }
            InputEvent::CameraInfo {
                camera_index, info, ..
            } => self.calibration.camera_info(camera_index, &info),
            InputEvent::Transforms { transforms, .. } => self.calibration.transforms(&transforms),
            InputEvent::BodyPose {
                topic,
                pose,
                arrival,
            } => self.on_topic_pose(&topic, &pose, arrival),
            InputEvent::BodyShape {
                topic,
                arrival,
                shape,
            } => self.on_shape(&topic, &shape, arrival, now),
            InputEvent::ClusterHeartbeat {
                index,
                members,
                arrival,
            } => self.membership.heartbeat(index, members, arrival),
        }
    }

    /// Runs whatever is due at `now`: frames whose mask wait expired, perception results,
    /// hand-overs, reconstructions whose debounce expired, frame rendering, the preview and
    /// the statuses.
    pub fn step(&mut self, now: Duration, clock: impl Fn() -> Duration) {
        let unmasked = self.masks.expired(now);
        if !unmasked.is_empty() {
            tracing::debug!(
                frames = unmasked.len(),
                "no mask within the wait: whole frames"
            );
        }
        self.admit(unmasked, now);
        // After the mask waits: perceiving on this thread (replay) takes time that must not
        // count against a frame waiting for its mask.
        self.take_perceived(now);
        if self.tracking && self.membership.refresh(now) {
            self.reassign(now);
        }
        self.take_finished_jobs(&clock);
        self.run_due_jobs(now, &clock);
        self.take_drawn();
        self.publish_due(now);
        self.refresh_status(now);
        self.lanes_due = now + LANE_POLL;
    }

    /// Starts every person's job due at `now`, the person who has waited longest first, each
    /// on the shared network in turn (inline, each one's result is taken as it ends).
    fn run_due_jobs(&mut self, now: Duration, clock: &impl Fn() -> Duration) {
        let due = first_waiting_first(
            self.persons
                .iter_mut()
                .filter_map(|(id, p)| p.poll(id, now))
                .collect(),
        );
        for job in due {
            self.start_job(job);
            self.take_finished_jobs(clock);
        }
    }

    /// True when no frame waits for its mask or for perception and no reconstruction is
    /// pending or running.
    pub fn idle(&self) -> bool {
        !self.perception.as_ref().is_some_and(Perception::busy)
            && self.masks.waiting() == 0
            && self.next_job_due().is_none()
            && !self.persons.values().any(Person::busy)
            && self.jobs.in_flight() == 0
            && self.drawing.in_flight() == 0
    }

    /// When the next scheduled work is due (reconstruction debounce, frame rendering, a mask
    /// wait, perception results, the lanes' results).
    pub fn next_deadline(&self) -> Option<Duration> {
        // While a batch is drawn, the lanes' poll looks for its end.
        let render = self
            .render_period
            .filter(|_| self.any_avatar() && self.outputs.live() && !self.drawing_frames)
            .map(|_| self.next_render);
        let perception = self
            .perception
            .as_ref()
            .filter(|p| p.busy())
            .map(|_| self.perception_due);
        let lanes =
            (self.jobs.in_flight() + self.drawing.in_flight() > 0).then_some(self.lanes_due);
        [
            self.next_job_due(),
            render,
            self.masks.next_deadline(),
            perception,
            lanes,
        ]
        .into_iter()
        .flatten()
        .min()
    }

    /// When the next person's job is due, if one is pending.
    fn next_job_due(&self) -> Option<Duration> {
        self.persons
            .values()
            .filter_map(Person::next_deadline)
            .min()
    }

    /// Whether some person has an avatar.
    fn any_avatar(&self) -> bool {
        self.persons.values().any(|p| p.current().is_some())
    }
}
