//! The node's processing pipeline, synchronous and driven by [`InputEvent`]s and a clock:
//! decode → preprocess → frame store → scheduler → reconstruction → avatar → render → outputs.
//! Live topics and bag replay feed it the same events, so both share this code path. Results
//! leave through one [`Fanout`] of [`crate::node::outputs`]: the files (when `outputs.dir` is
//! usable) and the live publishers (ROS 2, shared memory).

pub mod calibration;
pub mod masks;
pub mod membership;
pub mod neural_frames;
pub mod perceive;
mod person;
pub mod render;

use crate::avatar::Avatar;
use crate::body::Pose;
use crate::config::{Delight, NodeConfig, PersonMask, PoseSource};
use crate::msgs::{BodyPose, BodyShape, Header, ReconstructionStatus, Time};
use crate::node::frame_store::{thumbnail_embedding, FrameStore, InsertOutcome, View};
use crate::node::inputs::{CameraFrame, InputEvent};
use crate::node::outputs::{status_message, AvatarUpdate, Fanout, FileOutputs, Publisher};
use crate::node::rejections::{RejectReason, Rejections};
use crate::node::scheduler::{Job, Scheduler, SchedulerConfig};
use crate::node::timings::Timings;
use crate::perception::pose::{PoseEstimator, PoseEstimatorConfig};
use crate::perception::shape::ShapeReader;
use crate::perception::{Landmark, PerceptionError, BODY_LANDMARKS};
use crate::reconstruct::photo_colours::{colour_from_evidence, ViewEvidence};
use crate::reconstruct::preprocess::{preprocess, PreprocessConfig, Subject};
use crate::reconstruct::shape::AcceptedShape;
use crate::reconstruct::{shape, ReconstructError, Reconstructor};
use calibration::Calibration;
use image::GrayImage;
use masks::{MaskPairing, Paired};
use membership::Membership;
use neural_frames::{choose_renderer, FrameSource, NeuralFrames, RendererSetupError};
use perceive::{Finders, MaskSettings, PerceivedFrame, Perception};
use person::{Animation, CameraPose, Current, PersonState};
pub use render::RenderedFrame;
use render::{
    display_pose, render_frames, FrameRasterizer, FrameRasterizerError, FrameRenderer,
    VirtualCameras,
};
use std::collections::{BTreeMap, VecDeque};
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

/// Side of the thumbnail grid used as the frame-store embedding (cheap, no network pass).
const EMBEDDING_GRID: u32 = 12;
/// Masks kept to pair with frames by stamp (and camera, for per-camera mask topics).
const MASKS_KEPT: usize = 32;
/// How long a frame of a camera with its own mask topic waits for its mask.
const MASK_WAIT: Duration = Duration::from_millis(150);
/// Latencies kept for the summary.
const LATENCIES_KEPT: usize = 256;
/// Shortest time between statuses republished only because the rejection counts changed.
const STATUS_REFRESH: Duration = Duration::from_secs(1);
/// How often the pipeline looks for perception results while perception is busy.
const PERCEPTION_POLL: Duration = Duration::from_millis(5);
/// The camera whose pose drives the avatar keeps that role while it saw the person this
/// recently.
const POSE_CAMERA_HOLD: Duration = Duration::from_millis(500);
/// Camera poses kept for the end-of-replay animation.
const POSE_TRACK_KEPT: usize = 240;
/// A pose-topic pose places a view's colours when stamped at most this long before the view
/// (a pose topic holds until the next pose; a static person may publish one pose).
const POSE_SYNC_BEFORE_NS: i64 = 1_000_000_000;
/// ... and at most this long after it.
const POSE_SYNC_AFTER_NS: i64 = 100_000_000;

/// Counters of one run, printed at the end and used by tests.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PipelineStats {
    /// Camera frames received.
    pub frames: u64,
    /// Frames rejected (preprocessing failed).
    pub rejected: u64,
    /// Frames dropped as near-duplicates of held views.
    pub duplicates: u64,
    /// Frames cropped to the person by a mask of the same stamp (the rest: whole frames).
    pub masked: u64,
    /// Reconstructions run.
    pub reconstructions: u64,
    /// Reconstructions that failed.
    pub failures: u64,
    /// Latest latencies (last frame arrival → avatar published), milliseconds.
    pub latencies_ms: VecDeque<f64>,
    /// Reconstruction run times, milliseconds (same window).
    pub run_times_ms: VecDeque<f64>,
    /// Rendered frames produced.
    pub rendered_frames: u64,
    /// Render periods skipped because rendering a batch took longer than the period of
    /// `outputs.render_rate_hz` (the newest pose wins; per virtual camera).
    pub frames_dropped: u64,
    /// Per-frame render time of the last rendered batch, milliseconds (0: none yet).
    pub last_render_ms: f64,
    /// Body shapes accepted (changes of the shape in use).
    pub shapes_applied: u64,
    /// Body shapes rejected (wrong model, length or values).
    pub shapes_rejected: u64,
    /// Live camera frames' waits in the input queue (arrival → taken by the pipeline).
    pub queue_waits: Timings,
    /// Camera frames' age when taken (`header.stamp` → taken), recorded only for stamps of
    /// the last 10 minutes by this machine's clock (live streams, not replayed bags).
    pub frame_ages: Timings,
    /// Newest frame's arrival → avatar published, over the whole run.
    pub latencies: Timings,
    /// Input messages rejected by the pipeline's checks and reported to it by the bag replay
    /// ([`Pipeline::reject`]), by reason; [`Pipeline::rejections`] adds the live inputs'.
    pub rejections: Rejections,
    /// Frames camera-only perception ran on.
    pub perceived: u64,
    /// Frames cropped by a mask from perception.
    pub perception_masked: u64,
    /// Of those, views kept with their calibrated camera and the pose topic's pose, whose
    /// colours are projected through that camera (`perception.colours_from_views`).
    pub calibrated_views: u64,
    /// Perceived frames that showed nobody (they never reach the frame store).
    pub no_person: u64,
    /// Time perception took per frame.
    pub perception_times: Timings,
    /// Poses read from the cameras.
    pub camera_poses: u64,
    /// A camera frame's stamp → the pose read from it published, for stamps of the last 10
    /// minutes by this machine's clock (live streams).
    pub pose_ages: Timings,
    /// Persons the pipeline started following (1 without tracking once a frame arrived).
    pub persons_started: u64,
    /// Tracked persons let go (the tracker forgot or dropped them), with their views.
    pub persons_released: u64,
}

/// Where a camera's frames get their person mask.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum MaskRoute {
    /// A mask topic (paired by stamp; frames of cameras with their own topic wait for it).
    Topic,
    /// Camera-only perception.
    Perception,
    /// None: whole frames.
    Whole,
}

/// How a person's animation is set up when the person is first seen.
struct AnimationSetup {
    source: PoseSource,
    /// A fresh pose estimator (`None`: no camera pose), cloned for each person.
    estimator: Option<PoseEstimator>,
    /// Publish camera poses on the pose topic, in this world frame.
    publish: Option<String>,
}

/// The node's pipeline: the configured person, or (`tracking.enabled`) every tracked person,
/// each with its own frame store entry, schedule, avatar and frames.
pub struct Pipeline {
    /// The configured `person_id` (the one person without tracking).
    default_person: String,
    /// Persons come from the tracker (`tracking.enabled`).
    tracking: bool,
    /// Which persons this node reconstructs (`cluster`).
    membership: Membership,
    persons: BTreeMap<String, PersonState>,
    recon: Reconstructor,
    store: FrameStore,
    scheduler: Scheduler,
    preprocess: PreprocessConfig,
    masks: MaskPairing,
    /// `inputs.person_mask`, and whether a mask topic is shared by every camera.
    person_mask: PersonMask,
    shared_mask_topic: bool,
    /// Camera-only perception (`None` when no camera needs it).
    perception: Option<Perception>,
    /// When the pipeline next looks for perception results.
    perception_due: Duration,
    publish_masks: bool,
    /// Recolour avatars from the perceived views (`perception.colours_from_views`).
    colours_from_views: bool,
    /// Which perceived views have a fitted key light divided out (`perception.delight`).
    delight: Delight,
    animation: AnimationSetup,
    /// Camera calibration (and the shape reader).
    calibration: Calibration,
    next_frame_id: u64,
    /// Where results go: the files first, then the live publishers.
    outputs: Fanout,
    cameras: VirtualCameras,
    frames: FrameRenderer,
    render_period: Option<Duration>,
    render_rate_hz: f64,
    next_render: Duration,
    preview_period: Option<Duration>,
    next_preview: Duration,
    /// Fractional render periods skipped, not yet counted in `frames_dropped`.
    drop_debt: f64,
    /// Whether the "renders slower than the rate" warning was logged.
    slow_render_noted: bool,
    neural_renderer_id: String,
    stats: PipelineStats,
    /// Rejections counted by the live subscriptions, as last reported.
    input_rejections: Rejections,
    /// When rejections may next republish the status (node clock).
    status_refresh_due: Duration,
}

/// Errors that stop the pipeline from starting.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// The network or body template could not be set up.
    #[error(transparent)]
    Reconstruct(#[from] ReconstructError),
    /// The frame rasteriser's device is unavailable.
    #[error(transparent)]
    Rasterizer(#[from] FrameRasterizerError),
    /// The perception networks could not be loaded.
    #[error("perception: {0}")]
    Perception(#[from] PerceptionError),
    /// The pose solver does not fit the body template.
    #[error("perception pose: {0}")]
    PoseSolver(#[from] crate::perception::pose::PoseSolveError),
    /// `outputs.renderer` cannot be honoured with this network.
    #[error(transparent)]
    Renderer(#[from] RendererSetupError),
}

impl Pipeline {
    /// Sets up the network, the frame store and the outputs from the node config.
    pub fn new(
        config: &NodeConfig,
        publisher: Option<Box<dyn Publisher>>,
    ) -> Result<Self, PipelineError> {
        // The token cache holds every person's views.
        let people = if config.tracking.enabled {
            config.tracking.max_persons
        } else {
            1
        };
        let recon = Reconstructor::new(&config.model, config.frame_store.max_views * people)?;
        let (h, w) = recon.input_size();
        let rgb = recon.rgb_kind();
        // An unusable output directory costs the files only: the ROS 2 and shared-memory
        // outputs go on.
        let files = (!config.outputs.dir.is_empty())
            .then(|| FileOutputs::new(Path::new(&config.outputs.dir)))
            .and_then(|made| {
                made.map_err(|e| {
                    tracing::error!(
                        "outputs.dir `{}`: {e}; no avatar PLY files or PNG frames will be \
                         written, the ROS 2 and shared-memory outputs go on",
                        config.outputs.dir
                    )
                })
                .ok()
            })
            .map(|f| match rgb.display_ready() {
                true => f,
                false => f.with_latent_rgb(recon.checkpoint_kind()),
            })
            .map(|f| Box::new(f) as Box<dyn Publisher>);
        // The files first (an avatar's PLY is written before it is published), then the live
        // publishers.
        let outputs = Fanout(files.into_iter().chain(publisher).collect());
        let cameras = VirtualCameras::ring(
            config.outputs.virtual_cameras,
            config.outputs.render_size,
            recon.template().height(),
        );
        let rasterizer = FrameRasterizer::new(config.outputs.render_device)?;
        let neural_renderer_id = recon.neural_renderer_id();
        let decision = choose_renderer(
            config.outputs.renderer,
            rgb,
            recon.feature_channels(),
            recon.background_channels(),
            recon.neural_renderer_config().in_channels,
        )?;
        let neural = match decision.source {
            FrameSource::Gaussians => None,
            FrameSource::Neural => Some(NeuralFrames::new(
                recon.neural_renderer(),
                &recon.white_background_feature()?,
            )?),
        };
        tracing::info!(
            renderer = match decision.source {
                FrameSource::Gaussians => "gaussians",
                FrameSource::Neural => "neural",
            },
            checkpoint = recon.checkpoint_kind(),
            "frames: {}",
            decision.reason
        );
        let render_period = (config.outputs.render_rate_hz > 0.0)
            .then(|| Duration::from_secs_f64(1.0 / config.outputs.render_rate_hz));
        let perception = perception_stage(config)?;
        let camera_pose = perception.is_some()
            && matches!(
                config.inputs.pose_source,
                PoseSource::Auto | PoseSource::Camera
            );
        let reader = if perception.is_some()
            && config.perception.estimate_shape
            && recon.body_model() == crate::body::MAKEHUMAN_MODEL_ID
        {
            Some(ShapeReader::new(
                &crate::body::BodyTemplate::load_default()
                    .map_err(|e| PipelineError::Reconstruct(ReconstructError::Body(e)))?,
            )?)
        } else {
            None
        };
        let calibration = Calibration::new(
            &config.outputs.world_frame,
            reader,
            config.perception.min_visibility,
        );
        let estimator = if camera_pose {
            let mut cfg = PoseEstimatorConfig::default();
            cfg.solver.min_visibility = config.perception.min_visibility;
            Some(PoseEstimator::new(recon.template(), cfg)?)
        } else {
            None
        };
        tracing::info!(
            preset = %config.model.preset,
            weights = recon.weights(),
            points = config.model.num_points,
            input = %format!("{h}x{w}"),
            "reconstruction network ready"
        );
        Ok(Self {
            default_person: config.person_id.clone(),
            tracking: config.tracking.enabled,
            membership: Membership::new(&config.cluster),
            persons: BTreeMap::new(),
            recon,
            store: FrameStore::new((&config.frame_store).into()),
            scheduler: Scheduler::new(SchedulerConfig::from_debounce_ms(
                config.frame_store.debounce_ms,
            )),
            preprocess: PreprocessConfig {
                out_height: h,
                out_width: w,
                ..PreprocessConfig::default()
            },
            masks: MaskPairing::new(MASKS_KEPT, Vec::new(), MASK_WAIT),
            person_mask: config.inputs.person_mask,
            shared_mask_topic: !config.inputs.mask_topic.trim().is_empty(),
            perception,
            perception_due: Duration::ZERO,
            publish_masks: config.outputs.masks,
            colours_from_views: config.perception.colours_from_views,
            delight: config.perception.delight,
            animation: AnimationSetup {
                source: config.inputs.pose_source,
                estimator,
                publish: config
                    .outputs
                    .camera_pose
                    .then(|| config.outputs.world_frame.clone()),
            },
            calibration,
            next_frame_id: 1,
            outputs,
            cameras,
            frames: FrameRenderer::new(rasterizer, neural),
            render_period,
            render_rate_hz: config.outputs.render_rate_hz,
            next_render: Duration::ZERO,
            preview_period: (config.outputs.preview_rate_hz > 0.0)
                .then(|| Duration::from_secs_f64(1.0 / config.outputs.preview_rate_hz)),
            next_preview: Duration::ZERO,
            drop_debt: 0.0,
            slow_render_noted: false,
            neural_renderer_id,
            stats: PipelineStats::default(),
            input_rejections: Rejections::default(),
            status_refresh_due: Duration::ZERO,
        })
    }

    /// Replaces the live publishers (ROS 2, shared memory); the files stay (the node sets
    /// them once the ROS 2 endpoint is up: the pipeline is built first, so a config that
    /// cannot run fails before DDS starts).
    pub fn set_publisher(&mut self, publisher: Option<Box<dyn Publisher>>) {
        self.outputs.replace_live(publisher);
    }

    /// Whether frames go through the network's neural renderer (`outputs.renderer` resolved
    /// to `neural`).
    pub fn neural_frames(&self) -> bool {
        self.frames.is_neural()
    }

    /// Run counters so far.
    pub fn stats(&self) -> &PipelineStats {
        &self.stats
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

    /// Every input message rejected so far, by reason: the pipeline's, the replay's and the
    /// live subscriptions'.
    pub fn rejections(&self) -> Rejections {
        self.stats.rejections.merged(&self.input_rejections)
    }

    /// Views currently held for the configured person (without tracking).
    pub fn views_held(&self) -> usize {
        self.store.len(&self.default_person)
    }

    /// Latest avatar revision of the configured person (0 before the first).
    pub fn revision(&self) -> u64 {
        self.revision_of(&self.default_person)
    }

    /// The configured person's latest avatar.
    pub fn avatar(&self) -> Option<&Avatar> {
        self.avatar_of(&self.default_person)
    }

    /// The person tracker's counters (`tracking.enabled` only): persons started, forgotten
    /// after `forget_after`, dropped past `max_persons`.
    pub fn tracking_stats(&self) -> Option<crate::tracking::TrackingStats> {
        self.perception
            .as_ref()
            .and_then(Perception::tracking_stats)
    }

    /// The persons followed now (the configured one without tracking, once seen), by id.
    pub fn persons(&self) -> Vec<String> {
        self.persons.keys().cloned().collect()
    }

    /// Whether this node reconstructs `person` (`cluster`); the others are only tracked.
    pub fn reconstructs(&self, person: &str) -> bool {
        self.persons.get(person).is_some_and(|p| p.owned)
    }

    /// Views held for `person`.
    pub fn views_held_by(&self, person: &str) -> usize {
        self.store.len(person)
    }

    /// `person`'s latest avatar revision (0 before the first).
    pub fn revision_of(&self, person: &str) -> u64 {
        self.persons.get(person).map_or(0, PersonState::revision)
    }

    /// `person`'s latest avatar.
    pub fn avatar_of(&self, person: &str) -> Option<&Avatar> {
        self.persons
            .get(person)
            .and_then(|p| p.current.as_ref())
            .map(|c| &c.avatar)
    }

    /// Views the network has encoded (each held view once, thanks to the token cache).
    pub fn encoded_views(&self) -> usize {
        self.recon.encode_count()
    }

    /// Sets the camera topics (resolved) that have their own mask topic: their frames wait up
    /// to 150 ms for their mask before going on as whole frames.
    pub fn set_masked_cameras(&mut self, cameras: impl IntoIterator<Item = String>) {
        self.masks.set_masked_cameras(cameras);
    }

    /// Frames perception dropped unperceived (live: replaced by a newer frame of their camera
    /// before the worker took them).
    pub fn perception_dropped(&self) -> u64 {
        self.perception.as_ref().map_or(0, Perception::dropped)
    }

    /// True when no frame waits for its mask or for perception and no reconstruction is
    /// pending or running.
    pub fn idle(&self) -> bool {
        !self.perception.as_ref().is_some_and(Perception::busy)
            && self.masks.waiting() == 0
            && self.scheduler.next_deadline().is_none()
            && !self.scheduler.busy()
    }

    /// When the next scheduled work is due (reconstruction debounce or frame rendering).
    pub fn next_deadline(&self) -> Option<Duration> {
        let render = self
            .render_period
            .filter(|_| self.any_avatar() && self.outputs.live())
            .map(|_| self.next_render);
        let perception = self
            .perception
            .as_ref()
            .filter(|p| p.busy())
            .map(|_| self.perception_due);
        [
            self.scheduler.next_deadline(),
            render,
            self.masks.next_deadline(),
            perception,
        ]
        .into_iter()
        .flatten()
        .min()
    }

    /// Feeds one input event; `now` is the node clock.
    pub fn handle(&mut self, event: InputEvent, now: Duration) {
        match event {
            InputEvent::Frame(frame) => {
                self.stats.frames += 1;
                self.stats
                    .queue_waits
                    .record(now.saturating_sub(frame.arrival));
                if let Some(age) = live_age(frame.stamp_ns) {
                    self.stats.frame_ages.record(age);
                }
                self.on_camera_frame(frame, now);
            }
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

    /// Live cluster membership from `now` on: members whose heartbeat stops for 2 s hand
    /// their persons to the others (the node calls this once its ROS 2 endpoint is up).
    pub fn expect_heartbeats(&mut self, now: Duration) {
        self.membership.expect_heartbeats(now);
    }

    /// This node's `(cluster.index, cluster.members)`, when heartbeats are expected.
    pub fn heartbeat(&self) -> Option<(u32, u32)> {
        self.membership.live().then(|| self.membership.me())
    }

    /// After a change of the alive members: persons handed to this node are scheduled (their
    /// views are already held), persons handed away stop being reconstructed here.
    fn reassign(&mut self, now: Duration) {
        let changes: Vec<(String, bool)> = self
            .persons
            .iter()
            .filter(|(id, p)| p.owned != self.membership.owns(id))
            .map(|(id, p)| (id.clone(), !p.owned))
            .collect();
        for (person, owned) in changes {
            self.persons.get_mut(&person).expect("listed above").owned = owned;
            if owned {
                tracing::info!(person, "person handed to this node");
                if self.store.len(&person) > 0 {
                    let version = self.input_version(&person);
                    let arrival = self
                        .store
                        .snapshot(&person)
                        .and_then(|s| s.last_arrival())
                        .unwrap_or(now);
                    self.scheduler
                        .view_set_changed(&person, version, arrival, now);
                }
            } else {
                tracing::info!(person, "person handed to another cluster member");
                self.scheduler.forget(&person);
            }
        }
    }

    /// The person a pose or shape message is for: its `person_id`, or the configured person
    /// when it has none and nobody is tracked; `None` when no followed person has that id.
    fn addressee(&self, person_id: &str) -> Option<String> {
        match (person_id.is_empty(), self.tracking) {
            (true, false) => Some(self.default_person.clone()),
            (true, true) => None,
            (false, false) => (person_id == self.default_person).then(|| person_id.to_owned()),
            (false, true) => self
                .persons
                .contains_key(person_id)
                .then(|| person_id.to_owned()),
        }
    }

    fn on_topic_pose(&mut self, topic: &str, msg: &BodyPose, arrival: Duration) {
        let Some(person) = self.addressee(&msg.person_id) else {
            tracing::debug!(%topic, "body pose for person `{}` ignored (not followed here)", msg.person_id);
            return;
        };
        let checked = msg.to_pose().map_err(|e| e.to_string()).and_then(|p| {
            self.recon
                .template()
                .skeleton
                .check_pose(&p)
                .map(|()| p)
                .map_err(|e| e.to_string())
        });
        match checked {
            Ok(p) => {
                let state = self.person_mut(&person);
                state.animation.topic_pose = Some(p);
                state.animation.topic_pose_at = Some(arrival);
                state.animation.topic_pose_stamp =
                    Some((msg.header.stamp.as_nanos(), msg.header.frame_id.clone()));
            }
            Err(e) => self.reject_pose(topic, &e),
        }
    }

    fn reject_pose(&mut self, topic: &str, detail: &str) {
        self.stats.rejections.add(RejectReason::Pose);
        tracing::warn!(%topic, "body pose rejected: {detail}");
    }

    /// The body shape in use, as `GaussianAvatar.shape_params` carries it (empty if none).
    pub fn shape_params(&self) -> Vec<f32> {
        self.recon.shape().map_or_else(Vec::new, |s| s.params())
    }

    /// Anchor positions the next reconstruction starts from (canonical frame, metres).
    pub fn anchor_positions(&self) -> Result<Vec<glam::Vec3>, ReconstructError> {
        self.recon.anchor_positions()
    }

    /// Version of everything `person`'s reconstruction depends on: grows with every view-set
    /// change and every body-shape change.
    fn input_version(&self, person: &str) -> u64 {
        self.store.version(person) + self.persons.get(person).map_or(0, |p| p.shape_changes)
    }

    /// `person`'s state, made when first seen: with tracking, this node reconstructs them
    /// when `cluster` gives them to it.
    fn person_mut(&mut self, person: &str) -> &mut PersonState {
        if !self.persons.contains_key(person) {
            let owned = !self.tracking || self.membership.owns(person);
            let animation = Animation::new(self.animation.source, self.animation.estimator.clone());
            self.stats.persons_started += 1;
            if self.tracking {
                tracing::info!(person, reconstructed_here = owned, "tracking a new person");
            }
            self.persons
                .insert(person.to_owned(), PersonState::new(animation, owned));
        }
        self.persons.get_mut(person).expect("inserted above")
    }

    /// Lets go of tracked persons the tracker no longer holds: their views, schedule and
    /// avatar (their avatar was published; it is no longer rendered).
    fn release_untracked(&mut self, tracked: &[String]) {
        let gone: Vec<String> = self
            .persons
            .keys()
            .filter(|p| !tracked.contains(p))
            .cloned()
            .collect();
        for person in gone {
            self.persons.remove(&person);
            self.scheduler.forget(&person);
            if let Some(set) = self.store.snapshot(&person) {
                for v in &set.views {
                    self.recon.forget(v.frame_id);
                }
            }
            self.store.remove_person(&person);
            self.stats.persons_released += 1;
            tracing::info!(person, "person no longer tracked: released");
        }
    }

    /// A body shape from the shape topic for the person it names: checked against the
    /// network's body model, then used for that person's reconstructions (it wins over the
    /// height read from the views).
    fn on_shape(&mut self, topic: &str, msg: &BodyShape, arrival: Duration, now: Duration) {
        let Some(person) = self.addressee(&msg.person_id) else {
            tracing::debug!(
                %topic,
                "body shape for person `{}` ignored (not followed here)",
                msg.person_id
            );
            return;
        };
        let accepted = match shape::check_shape(topic, msg, self.recon.body_model()) {
            Ok(s) => s,
            Err(e) => {
                self.stats.shapes_rejected += 1;
                self.stats.rejections.add(RejectReason::Shape);
                tracing::warn!(%topic, "body shape rejected: {e}");
                return;
            }
        };
        // Applying it checks that it fits the body; the person's reconstruction applies it
        // again (the network serves every person).
        if let Err(e) = self.recon.use_shape(Some(accepted.clone())) {
            self.stats.shapes_rejected += 1;
            self.stats.rejections.add(RejectReason::Shape);
            tracing::warn!(%topic, "body shape rejected: {e}");
            return;
        }
        self.person_mut(&person).shape_from_topic = true;
        self.apply_shape(&person, accepted, arrival, now);
        tracing::debug!(%topic, person, "body shape from the shape topic");
    }

    /// Uses `shape` for `person` from their next reconstruction on; a change reruns it.
    fn apply_shape(
        &mut self,
        person: &str,
        shape: AcceptedShape,
        arrival: Duration,
        now: Duration,
    ) {
        let state = self.person_mut(person);
        if state.shape.as_ref() == Some(&shape) {
            return;
        }
        state.shape = Some(shape);
        state.shape_changes += 1;
        self.stats.shapes_applied += 1;
        tracing::info!(
            person,
            shape_params = ?self.persons[person].shape.as_ref().map(AcceptedShape::params),
            "body shape applied"
        );
        if self.store.len(person) > 0 && self.persons[person].owned {
            let version = self.input_version(person);
            self.scheduler
                .view_set_changed(person, version, arrival, now);
        }
    }

    /// Where frames of camera `topic` get their mask.
    fn route(&self, topic: &str) -> MaskRoute {
        if self.tracking {
            return MaskRoute::Perception;
        }
        match self.person_mask {
            PersonMask::Off => MaskRoute::Whole,
            PersonMask::Topic => MaskRoute::Topic,
            PersonMask::Perception => MaskRoute::Perception,
            PersonMask::Auto if self.shared_mask_topic || self.masks.is_masked(topic) => {
                MaskRoute::Topic
            }
            PersonMask::Auto => MaskRoute::Perception,
        }
    }

    /// A camera frame: to perception, to the mask pairing, or on as a whole frame; with
    /// `inputs.pose_source: camera` every frame also goes to perception for the pose.
    fn on_camera_frame(&mut self, frame: CameraFrame, now: Duration) {
        let route = self.route(&frame.topic);
        let camera = self
            .tracking
            .then(|| self.calibration.floor_camera(&frame))
            .flatten();
        match (route, self.perception.as_mut()) {
            (MaskRoute::Perception, Some(perception)) => perception.submit(frame, camera),
            (MaskRoute::Perception, None) => {
                let person = self.default_person.clone();
                self.on_frame(frame, StoreInput::whole_frame(), &person, now)
            }
            (MaskRoute::Topic | MaskRoute::Whole, perception) => {
                if let (PoseSource::Camera, Some(p)) = (self.animation.source, perception) {
                    p.submit(frame.clone(), camera);
                }
                if route == MaskRoute::Topic {
                    let ready = self.masks.frame(frame, now);
                    self.admit(ready, now);
                } else {
                    let person = self.default_person.clone();
                    self.on_frame(frame, StoreInput::whole_frame(), &person, now);
                }
            }
        }
    }

    /// Handles the frames perception has finished.
    fn take_perceived(&mut self, now: Duration) {
        let Some(perception) = self.perception.as_mut() else {
            return;
        };
        for done in perception.take_results() {
            self.on_perceived(done, now);
        }
        self.perception_due = now + PERCEPTION_POLL;
    }

    /// A perceived frame: the persons' masks are published (together, one camera mask), each
    /// person's landmarks update their camera pose and body height, and frames routed to
    /// perception go on to each person's frame store cropped by their mask (or, with nobody in
    /// them, no further).
    fn on_perceived(&mut self, done: PerceivedFrame, now: Duration) {
        let PerceivedFrame {
            frame,
            people,
            tracked,
            took,
        } = done;
        self.stats.perceived += 1;
        self.stats.perception_times.record(took);
        if self.publish_masks && self.outputs.live() {
            let mask = union_mask(&people, frame.image.width(), frame.image.height());
            self.outputs
                .mask(&frame.topic, &mask, frame.stamp_ns, &frame.frame_id);
        }
        if self.tracking {
            self.release_untracked(&tracked);
        }
        let to_store = self.route(&frame.topic) == MaskRoute::Perception;
        if people.is_empty() && to_store {
            self.stats.no_person += 1;
            tracing::debug!(topic = %frame.topic, "no person in the frame: not stored");
        }
        for seen in people {
            // Persons another cluster member reconstructs are followed too (views, pose,
            // height), so that they can be handed over at once.
            let person = seen.id.unwrap_or_else(|| self.default_person.clone());
            if self.tracking && !tracked.contains(&person) {
                // Dropped by the tracker in this very frame (past tracking.max_persons).
                continue;
            }
            self.person_mut(&person);
            self.on_camera_landmarks(&person, &frame, &seen.world, now);
            let state = self.persons.get_mut(&person).expect("made above");
            if let Some(height) =
                self.calibration
                    .landmarks(&mut state.heights, &frame, &seen.image)
            {
                self.on_height_from_views(&person, height, frame.arrival, now);
            }
            if to_store {
                self.stats.perception_masked += 1;
                let evidence = self.colours_from_views.then(|| {
                    let evidence =
                        ViewEvidence::new(&frame.image, &seen.mask, &seen.image, &seen.world);
                    Arc::new(match self.calibrated_view(&person, &frame) {
                        Some((camera, pose)) => {
                            self.stats.calibrated_views += 1;
                            evidence.with_calibration(camera, pose)
                        }
                        None => evidence,
                    })
                });
                let seen_as = StoreInput {
                    mask: Some(seen.mask),
                    evidence,
                    hidden: seen.hidden,
                };
                self.on_frame(frame.clone(), seen_as, &person, now);
            }
        }
    }

    /// `frame`'s calibrated camera and `person`'s pose in the world frame at the frame's time,
    /// when both are known: the camera calibrated (CameraInfo, TF to `outputs.world_frame`)
    /// and the newest pose-topic pose given in the world frame and stamped at most
    /// [`POSE_SYNC_BEFORE_NS`] before the frame (and not after it by more than
    /// [`POSE_SYNC_AFTER_NS`]).
    fn calibrated_view(
        &self,
        person: &str,
        frame: &CameraFrame,
    ) -> Option<(crate::splat::Camera, crate::body::Pose)> {
        let animation = &self.persons.get(person)?.animation;
        let pose = animation.topic_pose.as_ref()?;
        let (stamp, pose_frame) = animation.topic_pose_stamp.as_ref()?;
        let lag = frame.stamp_ns - stamp;
        if pose_frame != self.calibration.world_frame()
            || !(-POSE_SYNC_AFTER_NS..=POSE_SYNC_BEFORE_NS).contains(&lag)
        {
            return None;
        }
        let floor = self.calibration.floor_camera(frame)?;
        let [fx, fy, cx, cy] = floor.intrinsics;
        let camera = crate::splat::Camera {
            intrinsics: crate::splat::Intrinsics {
                fx,
                fy,
                cx,
                cy,
                width: frame.image.width(),
                height: frame.image.height(),
            },
            world_from_camera: floor.world_from_camera,
        };
        Some((camera, pose.clone()))
    }

    /// Updates `person`'s camera pose from `camera`'s world landmarks when that camera drives
    /// the pose (the current pose camera, or any camera once it has not seen the person for
    /// [`POSE_CAMERA_HOLD`]), and publishes it.
    fn on_camera_landmarks(
        &mut self,
        person: &str,
        frame: &CameraFrame,
        world: &[Landmark; BODY_LANDMARKS],
        now: Duration,
    ) {
        let publish = self.animation.publish.clone();
        let Some(state) = self.persons.get_mut(person) else {
            return;
        };
        let animation = &mut state.animation;
        let Some(estimator) = animation.estimator.as_mut() else {
            return;
        };
        if let Some(current) = &animation.camera_pose {
            if current.camera != frame.topic {
                if now.saturating_sub(current.at) < POSE_CAMERA_HOLD {
                    return;
                }
                estimator.reset();
            }
        }
        let t = if frame.stamp_ns > 0 {
            frame.stamp_ns as f64 * 1e-9
        } else {
            frame.arrival.as_secs_f64()
        };
        let pose = estimator.update(t, world);
        self.stats.camera_poses += 1;
        if let (Some(world_frame), true) = (&publish, self.outputs.live()) {
            let header = Header::new(Time::from_nanos(frame.stamp_ns), world_frame.as_str());
            self.outputs
                .pose(&BodyPose::from_pose(header, person.to_owned(), &pose));
            if let Some(age) = live_age(frame.stamp_ns) {
                self.stats.pose_ages.record(age);
            }
        }
        animation.track.push_back(pose.clone());
        while animation.track.len() > POSE_TRACK_KEPT {
            animation.track.pop_front();
        }
        animation.camera_pose = Some(CameraPose {
            pose,
            camera: frame.topic.clone(),
            at: now,
        });
    }

    /// A body height read from `person`'s calibrated views: applied (girth 1) unless the
    /// shape topic has given their shape; a change reruns their reconstruction.
    fn on_height_from_views(
        &mut self,
        person: &str,
        height: f32,
        arrival: Duration,
        now: Duration,
    ) {
        if self.persons.get(person).is_none_or(|p| p.shape_from_topic) {
            return;
        }
        let shape = crate::body::MakeHumanShape {
            height_scale: height.clamp(0.5, 2.0),
            girth_scale: 1.0,
        };
        tracing::debug!(
            person,
            height_scale = format!("{height:.3}"),
            "body height read from the calibrated views"
        );
        self.apply_shape(person, AcceptedShape::MakeHuman(shape), arrival, now);
    }

    /// Sets the camera topics (resolved: images, then compressed images) that CameraInfo
    /// messages pair with by position.
    pub fn set_cameras(&mut self, cameras: Vec<String>) {
        self.calibration.set_cameras(cameras);
    }

    /// Frames whose mask pairing is settled go on to preprocessing and the frame store.
    fn admit(&mut self, ready: Vec<Paired>, now: Duration) {
        let person = self.default_person.clone();
        for (frame, mask) in ready {
            self.stats.masked += u64::from(mask.is_some());
            let seen = StoreInput {
                mask,
                evidence: None,
                hidden: 0.0,
            };
            self.on_frame(frame, seen, &person, now);
        }
    }

    /// A frame of `person` (cropped by their mask, else whole; with what perception saw of
    /// them) into their frame store.
    fn on_frame(&mut self, frame: CameraFrame, seen: StoreInput, person: &str, now: Duration) {
        let StoreInput {
            mask,
            evidence,
            hidden,
        } = seen;
        self.person_mut(person);
        let subject = mask.as_deref().map_or(Subject::FullFrame, Subject::Mask);
        let image = match preprocess(&frame.image, subject, &self.preprocess) {
            Ok(image) => Arc::new(image),
            Err(e) => {
                self.stats.rejected += 1;
                self.stats.rejections.add(RejectReason::Frame);
                tracing::warn!(topic = %frame.topic, "frame rejected: {e}");
                return;
            }
        };
        let frame_id = self.next_frame_id;
        self.next_frame_id += 1;
        let view = View {
            frame_id,
            camera: frame.topic.clone(),
            stamp_ns: frame.stamp_ns,
            arrival: frame.arrival,
            embedding: thumbnail_embedding(&image, EMBEDDING_GRID),
            image,
            evidence,
            hidden,
        };
        let outcome = self.store.insert(person, view);
        match outcome {
            InsertOutcome::Dropped { .. } => self.stats.duplicates += 1,
            InsertOutcome::DroppedHidden => {}
            InsertOutcome::AddedEvicting { evicted } => self.recon.forget(evicted),
            InsertOutcome::Replaced { replaced, .. } => self.recon.forget(replaced),
            InsertOutcome::Added => {}
        }
        if outcome.changed() && self.persons[person].owned {
            let version = self.input_version(person);
            self.scheduler
                .view_set_changed(person, version, frame.arrival, now);
        }
    }

    /// Runs whatever is due at `now`: reconstructions whose debounce expired, frame rendering.
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
        for job in self.scheduler.poll(now) {
            self.run_job(job, &clock);
        }
        if let (Some(period), true) = (self.render_period, self.outputs.live()) {
            if self.any_avatar() && now >= self.next_render {
                let started = clock();
                self.publish_frames(now);
                let took = clock().saturating_sub(started);
                self.next_render = now + period;
                self.note_render_time(took, period);
            }
        }
        if let (Some(period), true) = (self.preview_period, self.outputs.live()) {
            if self.any_avatar() && now >= self.next_preview {
                self.publish_preview(now);
                self.next_preview = now + period;
            }
        }
        self.refresh_status(now);
    }

    /// Whether some person has an avatar.
    fn any_avatar(&self) -> bool {
        self.persons.values().any(|p| p.current.is_some())
    }

    /// Republishes the statuses (the last ones, or an idle one for the configured person
    /// before any) when the rejection counts changed, at most once per [`STATUS_REFRESH`], so
    /// they show without a state change.
    fn refresh_status(&mut self, now: Duration) {
        if !self.outputs.live() || now < self.status_refresh_due {
            return;
        }
        let (reasons, counts) = self.rejection_fields();
        let mut last: Vec<ReconstructionStatus> = self
            .persons
            .values()
            .filter_map(|p| p.last_status.clone())
            .collect();
        if last.is_empty() && !counts.is_empty() {
            let person = self.default_person.clone();
            let views = self.store.len(&person);
            let state = if views == 0 {
                ReconstructionStatus::STATE_IDLE
            } else {
                ReconstructionStatus::STATE_WAITING
            };
            last.push(status_message(
                &person,
                views,
                self.revision_of(&person),
                0.0,
                self.stats.last_render_ms,
                state,
                "",
                0,
            ));
        }
        let mut sent = false;
        for mut msg in last {
            if msg.rejected_counts == counts && msg.rejected_reasons == reasons {
                continue;
            }
            (msg.rejected_reasons, msg.rejected_counts) = (reasons.clone(), counts.clone());
            self.send_status(msg);
            sent = true;
        }
        if sent {
            self.status_refresh_due = now + STATUS_REFRESH;
        }
    }

    /// The rejection counts as `ReconstructionStatus` carries them.
    fn rejection_fields(&self) -> (Vec<String>, Vec<u64>) {
        self.rejections()
            .nonzero()
            .map(|(r, n)| (r.as_str().to_owned(), n))
            .unzip()
    }

    fn send_status(&mut self, msg: ReconstructionStatus) {
        if self.outputs.live() {
            self.outputs.status(msg.clone());
            // A released person's last status is not kept (nor are they made again).
            if let Some(state) = self.persons.get_mut(&msg.person_id) {
                state.last_status = Some(msg);
            }
        }
    }

    /// Poses the avatar (the configured person's; with tracking, the first tracked person's
    /// that has one) at the pose its frames use and hands it to the publishers' preview.
    fn publish_preview(&self, now: Duration) {
        let Some((state, current)) = self
            .persons
            .values()
            .find_map(|p| p.current.as_ref().map(|c| (p, c)))
        else {
            return;
        };
        if !self.outputs.live() {
            return;
        }
        let pose = display_pose(state.animation.pose(now), now.as_secs_f32());
        let matrices = current.skeleton.skinning_matrices(&pose);
        let posed = current.avatar.animate(&matrices);
        self.outputs.preview(&posed, unix_now_ns());
    }

    /// Counts the render periods a batch that took `took` skipped (the next batch starts when
    /// this one ends: the newest pose wins) and says so once, in the log and the status.
    fn note_render_time(&mut self, took: Duration, period: Duration) {
        let periods = took.as_secs_f64() / period.as_secs_f64();
        if periods <= 1.0 {
            return;
        }
        self.drop_debt += periods - 1.0;
        let whole = self.drop_debt.floor();
        self.drop_debt -= whole;
        let rendered = self.cameras.cameras().len()
            * self
                .persons
                .values()
                .filter(|p| p.current.is_some())
                .count();
        self.stats.frames_dropped += whole as u64 * rendered as u64;
        if !self.slow_render_noted {
            self.slow_render_noted = true;
            let achieved = 1.0 / took.as_secs_f64();
            let message = format!(
                "rendering holds {achieved:.2} Hz per camera, below outputs.render_rate_hz {:.2} \
                 ({:.0} ms per batch of {} frame(s), {} renderer): frames drop, the newest pose \
                 wins",
                self.render_rate_hz,
                took.as_secs_f64() * 1e3,
                rendered,
                if self.frames.is_neural() {
                    "neural"
                } else {
                    "gaussians"
                },
            );
            tracing::warn!("{message}");
            let revisions: Vec<(String, u64)> = self
                .persons
                .iter()
                .filter(|(_, p)| p.current.is_some())
                .map(|(id, p)| (id.clone(), p.revision()))
                .collect();
            for (person, revision) in revisions {
                self.publish_status(
                    &person,
                    revision,
                    0.0,
                    ReconstructionStatus::STATE_IDLE,
                    message.clone(),
                );
            }
        }
    }

    fn run_job(&mut self, job: Job, clock: &impl Fn() -> Duration) {
        let person = job.person.clone();
        let Some(set) = self.store.snapshot(&person) else {
            let _ = self.scheduler.failed(&person, job.revision);
            return;
        };
        self.publish_status(
            &person,
            job.revision.saturating_sub(1),
            0.0,
            ReconstructionStatus::STATE_RECONSTRUCTING,
            "reconstructing",
        );
        let shape = self.persons.get(&person).and_then(|p| p.shape.clone());
        let views: Vec<(u64, &crate::reconstruct::preprocess::Preprocessed)> = set
            .views
            .iter()
            .map(|v| (v.frame_id, v.image.as_ref()))
            .collect();
        let result = self
            .recon
            .use_shape(shape)
            .and_then(|_| self.recon.reconstruct(&views));
        match result {
            Ok(mut avatar) => {
                if self.colours_from_views {
                    let seen: Vec<&ViewEvidence> = set
                        .views
                        .iter()
                        .filter_map(|v| v.evidence.as_deref())
                        .collect();
                    colour_from_evidence(&mut avatar, self.recon.template(), &seen, self.delight);
                }
                let stamp = set.views.iter().map(|v| v.stamp_ns).max().unwrap_or(0);
                self.publish_avatar(&job, &avatar, set.views.len(), stamp);
                let skeleton = self.recon.template().skeleton.clone();
                if let Some(state) = self.persons.get_mut(&person) {
                    state.current = Some(Current {
                        revision: job.revision,
                        avatar,
                        skeleton,
                    });
                }
                match self.scheduler.finished(&person, job.revision, clock()) {
                    Ok(done) => {
                        let latency = done.latency.as_secs_f64() * 1e3;
                        let run = done.run_time.as_secs_f64() * 1e3;
                        push_bounded(&mut self.stats.latencies_ms, latency);
                        self.stats.latencies.record(done.latency);
                        push_bounded(&mut self.stats.run_times_ms, run);
                        self.stats.reconstructions += 1;
                        tracing::info!(
                            person = %job.person,
                            revision = job.revision,
                            views = set.views.len(),
                            latency_ms = format!("{latency:.0}"),
                            run_ms = format!("{run:.0}"),
                            "avatar published"
                        );
                        self.publish_status(
                            &person,
                            job.revision,
                            latency,
                            ReconstructionStatus::STATE_IDLE,
                            "avatar published",
                        );
                    }
                    Err(e) => tracing::error!("scheduler: {e}"),
                }
            }
            Err(e) => {
                self.stats.failures += 1;
                tracing::error!(person = %job.person, revision = job.revision, "reconstruction failed: {e}");
                let _ = self.scheduler.failed(&person, job.revision);
                self.publish_status(
                    &person,
                    job.revision,
                    0.0,
                    ReconstructionStatus::STATE_ERROR,
                    e.to_string(),
                );
            }
        }
    }

    fn publish_avatar(&mut self, job: &Job, avatar: &Avatar, views: usize, stamp: i64) {
        let shape_params = self.shape_params();
        self.outputs.avatar(&AvatarUpdate {
            person: &job.person,
            revision: job.revision,
            views_used: views,
            stamp_ns: stamp,
            avatar,
            template: self.recon.template(),
            shape_params: &shape_params,
            rgb_display_ready: self.recon.rgb_kind().display_ready(),
            neural_renderer: &self.neural_renderer_id,
        });
    }

    fn publish_status(
        &mut self,
        person: &str,
        revision: u64,
        latency_ms: f64,
        state: u8,
        message: impl Into<String>,
    ) {
        let mut msg = status_message(
            person,
            self.store.len(person),
            revision,
            latency_ms,
            self.stats.last_render_ms,
            state,
            message,
            0,
        );
        (msg.rejected_reasons, msg.rejected_counts) = self.rejection_fields();
        self.send_status(msg);
    }

    /// Renders every person's latest avatar from every virtual camera at the pose their
    /// frames use and hands the frames to the outputs.
    fn publish_frames(&mut self, now: Duration) {
        if !self.outputs.live() {
            return;
        }
        let started = std::time::Instant::now();
        let stamp = unix_now_ns();
        let mut count = 0;
        for (person, state) in &self.persons {
            let Some(current) = &state.current else {
                continue;
            };
            let pose = display_pose(state.animation.pose(now), now.as_secs_f32());
            let frames = render_frames(
                &current.avatar,
                &current.skeleton,
                &pose,
                &self.cameras,
                &mut self.frames,
            );
            for (i, f) in frames.iter().enumerate() {
                self.outputs.frame(person, i, f, stamp);
            }
            count += frames.len();
        }
        self.stats.last_render_ms = started.elapsed().as_secs_f64() * 1e3 / count.max(1) as f64;
        self.stats.rendered_frames += count as u64;
    }

    /// Renders a short animation of each person's latest avatar from every virtual camera and
    /// hands it to the outputs that store it (the files write
    /// `frames/<person>_cam<i>_<f>.png`); nothing is rendered when none does. The animation
    /// replays the poses read from the cameras when they drove the avatar (every one kept, up
    /// to the last 240), else `frames` frames of the built-in walk cycle. Returns the frames
    /// stored.
    pub fn write_animation(&mut self, frames: usize) -> usize {
        if !self.any_avatar() {
            return 0;
        }
        let Some(mut animation) = self.outputs.animation() else {
            return 0;
        };
        let mut written = 0;
        for (person, state) in &self.persons {
            let Some(current) = &state.current else {
                continue;
            };
            let camera_driven = matches!(
                state.animation.source,
                PoseSource::Auto | PoseSource::Camera
            ) && state.animation.topic_pose.is_none();
            let track: Vec<Pose> = if camera_driven {
                state.animation.track.iter().cloned().collect()
            } else {
                Vec::new()
            };
            let count = if track.is_empty() {
                frames
            } else {
                track.len()
            };
            for f in 0..count {
                let pose = track
                    .get(f)
                    .cloned()
                    .unwrap_or_else(|| display_pose(None, f as f32 / 24.0));
                let started = std::time::Instant::now();
                let images = render_frames(
                    &current.avatar,
                    &current.skeleton,
                    &pose,
                    &self.cameras,
                    &mut self.frames,
                );
                self.stats.last_render_ms =
                    started.elapsed().as_secs_f64() * 1e3 / images.len().max(1) as f64;
                for (c, image) in images.iter().enumerate() {
                    let name = format!("{person}_cam{c}_{f:03}");
                    written += usize::from(animation.frame(&name, image));
                }
            }
        }
        animation.finish();
        self.stats.rendered_frames += written as u64;
        written
    }
}

/// The persons' masks of one frame as one mask (the brightest value per pixel); an empty mask
/// when nobody was found.
fn union_mask(people: &[perceive::PersonSeen], width: u32, height: u32) -> GrayImage {
    let mut out = GrayImage::new(width, height);
    for p in people {
        if p.mask.dimensions() != (width, height) {
            continue;
        }
        for (o, m) in out.iter_mut().zip(p.mask.iter()) {
            *o = (*o).max(*m);
        }
    }
    out
}

/// The perception stage `config` needs: none when no camera can be routed to perception and
/// the pose does not come from the cameras; live runs perceive on a worker thread, bag
/// replays every frame in order.
fn perception_stage(config: &NodeConfig) -> Result<Option<Perception>, PerceptionError> {
    if !config.runs_perception() {
        return Ok(None);
    }
    let p = &config.perception;
    let model = p.landmark_model.model();
    let networks = Arc::new(p.networks()?);
    let live = config.replay.bag.is_empty();
    tracing::info!(
        landmark_model = model.name(),
        threads = p.threads,
        mode = if live {
            "worker, newest frame per camera"
        } else {
            "every frame, in order"
        },
        "camera-only perception ready"
    );
    let finders = if config.tracking.enabled {
        tracing::info!(
            max_persons = config.tracking.max_persons,
            cluster_members = config.cluster.members,
            cluster_index = config.cluster.index,
            "several people: MoveNet MultiPose, the landmark model per person, tracked ids"
        );
        Finders::many(networks.clone(), p.people(), config.tracking.tracker())
    } else {
        Finders::one(p.tracker(live))
    };
    Ok(Some(Perception::new(
        networks,
        finders,
        MaskSettings {
            threshold: p.mask_threshold,
            feather: p.mask_feather,
        },
        p.threads,
        live,
    )))
}

fn unix_now_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i64)
}

/// How old a frame stamped `stamp_ns` (ns since the epoch) is by this machine's clock, if
/// that is between 0 and 10 minutes (a live stream; replayed bags carry older stamps).
fn live_age(stamp_ns: i64) -> Option<Duration> {
    let age = u64::try_from(unix_now_ns().checked_sub(stamp_ns)?).ok()?;
    Some(Duration::from_nanos(age)).filter(|age| *age < Duration::from_secs(600))
}

fn push_bounded(q: &mut VecDeque<f64>, v: f64) {
    q.push_back(v);
    while q.len() > LATENCIES_KEPT {
        q.pop_front();
    }
}

/// What perception saw of a person in one frame, as the frame store takes it.
struct StoreInput {
    /// The person's mask over the frame (`None`: the whole frame).
    mask: Option<Arc<GrayImage>>,
    /// Their landmarks and mask for the colours (`perception.colours_from_views`).
    evidence: Option<Arc<ViewEvidence>>,
    /// How much of their box others covered ([`View::hidden`]).
    hidden: f32,
}

impl StoreInput {
    /// The whole frame, nothing perceived.
    fn whole_frame() -> Self {
        Self {
            mask: None,
            evidence: None,
            hidden: 0.0,
        }
    }
}
