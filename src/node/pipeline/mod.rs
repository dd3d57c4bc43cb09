//! The node's processing pipeline, synchronous and driven by [`InputEvent`]s and a clock:
//! decode → preprocess → frame store → scheduler → reconstruction → avatar → render → outputs.
//! Live topics and bag replay feed it the same events, so both share this code path. Results
//! leave through one [`Fanout`] of [`crate::node::outputs`]: the files (when `outputs.dir` is
//! usable) and the live publishers (ROS 2, shared memory).

pub mod calibration;
pub mod masks;
pub mod neural_frames;
pub mod perceive;
pub mod render;

use crate::avatar::Avatar;
use crate::body::Pose;
use crate::config::{LandmarkModelChoice, NodeConfig, PersonMask, PoseSource};
use crate::msgs::{BodyPose, BodyShape, Header, ReconstructionStatus, Time};
use crate::node::frame_store::{thumbnail_embedding, FrameStore, InsertOutcome, View};
use crate::node::inputs::{CameraFrame, InputEvent};
use crate::node::outputs::{status_message, AvatarUpdate, Fanout, FileOutputs, Publisher};
use crate::node::rejections::{RejectReason, Rejections};
use crate::node::scheduler::{Job, Scheduler, SchedulerConfig};
use crate::node::timings::Timings;
use crate::perception::pose::{PoseEstimator, PoseEstimatorConfig};
use crate::perception::shape::ShapeReader;
use crate::perception::{
    Landmark, LandmarkModel, PerceptionError, PoseNetworks, TrackerConfig, BODY_LANDMARKS,
};
use crate::reconstruct::preprocess::{preprocess, PreprocessConfig, Subject};
use crate::reconstruct::shape::AcceptedShape;
use crate::reconstruct::{shape, ReconstructError, Reconstructor};
use calibration::Calibration;
use image::GrayImage;
use masks::{MaskPairing, Paired};
use neural_frames::{choose_renderer, FrameSource, NeuralFrames, RendererSetupError};
use perceive::{MaskSettings, PerceivedFrame, Perception};
pub use render::RenderedFrame;
use render::{
    display_pose, render_frames, FrameRasterizer, FrameRasterizerError, FrameRenderer,
    VirtualCameras,
};
use std::collections::VecDeque;
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
/// With `inputs.pose_source: auto`, a pose topic counts as published for this long after its
/// last message.
const TOPIC_POSE_FRESH: Duration = Duration::from_secs(2);
/// The camera whose pose drives the avatar keeps that role while it saw the person this
/// recently.
const POSE_CAMERA_HOLD: Duration = Duration::from_millis(500);
/// Camera poses kept for the end-of-replay animation.
const POSE_TRACK_KEPT: usize = 240;

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
    /// Perceived frames that showed nobody (they never reach the frame store).
    pub no_person: u64,
    /// Time perception took per frame.
    pub perception_times: Timings,
    /// Poses read from the cameras.
    pub camera_poses: u64,
}

/// The latest avatar and what it was built from.
struct Current {
    revision: u64,
    avatar: Avatar,
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

/// The pose read from the cameras, and where and when.
struct CameraPose {
    pose: Pose,
    camera: String,
    at: Duration,
}

/// What drives the avatar and where its pose comes from.
struct Animation {
    source: PoseSource,
    /// The latest pose from the pose topic.
    topic_pose: Option<Pose>,
    /// When the last one arrived (node clock).
    topic_pose_at: Option<Duration>,
    /// Turns the pose camera's world landmarks into poses (`None`: no camera pose).
    estimator: Option<PoseEstimator>,
    camera_pose: Option<CameraPose>,
    /// Recent camera poses, for the end-of-replay animation.
    track: VecDeque<Pose>,
    /// Publish camera poses on the pose topic, in this world frame.
    publish: Option<String>,
}

impl Animation {
    /// The pose the frames show at `now` (`None`: the walk cycle).
    fn pose(&self, now: Duration) -> Option<&Pose> {
        let camera = self.camera_pose.as_ref().map(|c| &c.pose);
        match self.source {
            PoseSource::Walk => None,
            PoseSource::Topic => self.topic_pose.as_ref(),
            PoseSource::Camera => camera,
            PoseSource::Auto => {
                let fresh = self
                    .topic_pose_at
                    .is_some_and(|at| now.saturating_sub(at) < TOPIC_POSE_FRESH);
                if fresh {
                    self.topic_pose.as_ref()
                } else {
                    camera.or(self.topic_pose.as_ref())
                }
            }
        }
    }
}

/// The node's pipeline for one configured person.
pub struct Pipeline {
    person: String,
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
    animation: Animation,
    /// Camera calibration, and the body height read from calibrated views.
    calibration: Calibration,
    /// Whether the shape topic has given the body shape (it then wins over the views).
    shape_from_topic: bool,
    next_frame_id: u64,
    shape_changes: u64,
    current: Option<Current>,
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
    /// The last status published, republished with new counts when only they change.
    last_status: Option<ReconstructionStatus>,
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
        let recon = Reconstructor::new(&config.model, config.frame_store.max_views)?;
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
            person: config.person_id.clone(),
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
            animation: Animation {
                source: config.inputs.pose_source,
                topic_pose: None,
                topic_pose_at: None,
                estimator,
                camera_pose: None,
                track: VecDeque::new(),
                publish: config
                    .outputs
                    .camera_pose
                    .then(|| config.outputs.world_frame.clone()),
            },
            calibration,
            shape_from_topic: false,
            next_frame_id: 1,
            shape_changes: 0,
            current: None,
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
            last_status: None,
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

    /// Views currently held for the person.
    pub fn views_held(&self) -> usize {
        self.store.len(&self.person)
    }

    /// Latest avatar revision (0 before the first).
    pub fn revision(&self) -> u64 {
        self.current.as_ref().map_or(0, |c| c.revision)
    }

    /// The latest avatar.
    pub fn avatar(&self) -> Option<&Avatar> {
        self.current.as_ref().map(|c| &c.avatar)
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
            && self.scheduler.in_flight(&self.person).is_none()
    }

    /// When the next scheduled work is due (reconstruction debounce or frame rendering).
    pub fn next_deadline(&self) -> Option<Duration> {
        let render = self
            .render_period
            .filter(|_| self.current.is_some() && self.outputs.live())
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
            } => match pose.to_pose() {
                Ok(p) => match self.recon.template().skeleton.check_pose(&p) {
                    Ok(()) => {
                        self.animation.topic_pose = Some(p);
                        self.animation.topic_pose_at = Some(arrival);
                    }
                    Err(e) => self.reject_pose(&topic, &e.to_string()),
                },
                Err(e) => self.reject_pose(&topic, &e.to_string()),
            },
            InputEvent::BodyShape {
                topic,
                arrival,
                shape,
            } => self.on_shape(&topic, &shape, arrival, now),
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

    /// Version of everything a reconstruction depends on: grows with every view-set change and
    /// every body-shape change.
    fn input_version(&self) -> u64 {
        self.store.version(&self.person) + self.shape_changes
    }

    fn on_shape(&mut self, topic: &str, msg: &BodyShape, arrival: Duration, now: Duration) {
        if !msg.person_id.is_empty() && msg.person_id != self.person {
            tracing::debug!(
                %topic,
                "body shape for person `{}` ignored (this node reconstructs `{}`)",
                msg.person_id,
                self.person
            );
            return;
        }
        let accepted = match shape::check_shape(topic, msg, self.recon.body_model()) {
            Ok(s) => s,
            Err(e) => {
                self.stats.shapes_rejected += 1;
                self.stats.rejections.add(RejectReason::Shape);
                tracing::warn!(%topic, "body shape rejected: {e}");
                return;
            }
        };
        match self.recon.set_shape(accepted) {
            Ok(false) => {}
            Ok(true) => {
                self.shape_from_topic = true;
                self.stats.shapes_applied += 1;
                self.shape_changes += 1;
                tracing::info!(
                    %topic,
                    person = %self.person,
                    shape_params = ?self.shape_params(),
                    "body shape applied"
                );
                if self.views_held() > 0 {
                    let version = self.input_version();
                    self.scheduler
                        .view_set_changed(&self.person, version, arrival, now);
                }
            }
            Err(e) => {
                self.stats.shapes_rejected += 1;
                self.stats.rejections.add(RejectReason::Shape);
                tracing::warn!(%topic, "body shape rejected: {e}");
            }
        }
    }

    /// Where frames of camera `topic` get their mask.
    fn route(&self, topic: &str) -> MaskRoute {
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
        match (route, self.perception.as_mut()) {
            (MaskRoute::Perception, Some(perception)) => perception.submit(frame),
            (MaskRoute::Perception, None) => self.on_frame(frame, None, now),
            (MaskRoute::Topic | MaskRoute::Whole, perception) => {
                if let (PoseSource::Camera, Some(p)) = (self.animation.source, perception) {
                    p.submit(frame.clone());
                }
                if route == MaskRoute::Topic {
                    let ready = self.masks.frame(frame, now);
                    self.admit(ready, now);
                } else {
                    self.on_frame(frame, None, now);
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

    /// A perceived frame: its mask is published, the person's landmarks update the camera
    /// pose, and frames routed to perception go on to the frame store cropped by the mask (or,
    /// with nobody in them, no further).
    fn on_perceived(&mut self, done: PerceivedFrame, now: Duration) {
        let PerceivedFrame {
            frame,
            person,
            took,
        } = done;
        self.stats.perceived += 1;
        self.stats.perception_times.record(took);
        if self.publish_masks && self.outputs.live() {
            let empty;
            let mask = match &person {
                Some(p) => p.mask.as_ref(),
                None => {
                    empty = GrayImage::new(frame.image.width(), frame.image.height());
                    &empty
                }
            };
            self.outputs
                .mask(&frame.topic, mask, frame.stamp_ns, &frame.frame_id);
        }
        if let Some(p) = &person {
            self.on_camera_landmarks(&frame, &p.world, now);
            if let Some(height) = self.calibration.landmarks(&frame, &p.image) {
                self.on_height_from_views(height, frame.arrival, now);
            }
        }
        if self.route(&frame.topic) != MaskRoute::Perception {
            return;
        }
        match person {
            Some(p) => {
                self.stats.perception_masked += 1;
                self.on_frame(frame, Some(p.mask), now);
            }
            None => {
                self.stats.no_person += 1;
                tracing::debug!(topic = %frame.topic, "no person in the frame: not stored");
            }
        }
    }

    /// Updates the camera pose from `camera`'s world landmarks when that camera drives the
    /// pose (the current pose camera, or any camera once it has not seen the person for
    /// [`POSE_CAMERA_HOLD`]), and publishes it.
    fn on_camera_landmarks(
        &mut self,
        frame: &CameraFrame,
        world: &[Landmark; BODY_LANDMARKS],
        now: Duration,
    ) {
        let animation = &mut self.animation;
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
        if let (Some(world_frame), true) = (&animation.publish, self.outputs.live()) {
            let header = Header::new(Time::from_nanos(frame.stamp_ns), world_frame.as_str());
            self.outputs
                .pose(&BodyPose::from_pose(header, self.person.clone(), &pose));
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

    /// A body height read from calibrated views: applied (girth 1) unless the shape topic has
    /// given the shape; a change reruns the reconstruction.
    fn on_height_from_views(&mut self, height: f32, arrival: Duration, now: Duration) {
        if self.shape_from_topic {
            return;
        }
        let shape = crate::body::MakeHumanShape {
            height_scale: height.clamp(0.5, 2.0),
            girth_scale: 1.0,
        };
        match self.recon.set_shape(AcceptedShape::MakeHuman(shape)) {
            Ok(true) => {
                self.stats.shapes_applied += 1;
                self.shape_changes += 1;
                tracing::info!(
                    person = %self.person,
                    height_scale = format!("{height:.3}"),
                    "body height read from the calibrated views"
                );
                if self.views_held() > 0 {
                    let version = self.input_version();
                    self.scheduler
                        .view_set_changed(&self.person, version, arrival, now);
                }
            }
            Ok(false) => {}
            Err(e) => tracing::warn!("body height from the views not applied: {e}"),
        }
    }

    /// Sets the camera topics (resolved: images, then compressed images) that CameraInfo
    /// messages pair with by position.
    pub fn set_cameras(&mut self, cameras: Vec<String>) {
        self.calibration.set_cameras(cameras);
    }

    /// Frames whose mask pairing is settled go on to preprocessing and the frame store.
    fn admit(&mut self, ready: Vec<Paired>, now: Duration) {
        for (frame, mask) in ready {
            self.stats.masked += u64::from(mask.is_some());
            self.on_frame(frame, mask, now);
        }
    }

    fn on_frame(&mut self, frame: CameraFrame, mask: Option<Arc<GrayImage>>, now: Duration) {
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
        };
        let outcome = self.store.insert(&self.person, view);
        match outcome {
            InsertOutcome::Dropped { .. } => self.stats.duplicates += 1,
            InsertOutcome::AddedEvicting { evicted } => self.recon.forget(evicted),
            InsertOutcome::Replaced { replaced, .. } => self.recon.forget(replaced),
            InsertOutcome::Added => {}
        }
        if outcome.changed() {
            let version = self.input_version();
            self.scheduler
                .view_set_changed(&self.person, version, frame.arrival, now);
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
        for job in self.scheduler.poll(now) {
            self.run_job(job, &clock);
        }
        if let (Some(period), true) = (self.render_period, self.outputs.live()) {
            if self.current.is_some() && now >= self.next_render {
                let started = clock();
                self.publish_frames(now);
                let took = clock().saturating_sub(started);
                self.next_render = now + period;
                self.note_render_time(took, period);
            }
        }
        if let (Some(period), true) = (self.preview_period, self.outputs.live()) {
            if self.current.is_some() && now >= self.next_preview {
                self.publish_preview(now);
                self.next_preview = now + period;
            }
        }
        self.refresh_status(now);
    }

    /// Republishes the status (the last one, or an idle one before any) when the rejection
    /// counts changed, at most once per [`STATUS_REFRESH`], so they show without a state
    /// change.
    fn refresh_status(&mut self, now: Duration) {
        if !self.outputs.live() || now < self.status_refresh_due {
            return;
        }
        let (reasons, counts) = self.rejection_fields();
        let Some(mut msg) = self.last_status.clone().or_else(|| {
            (!counts.is_empty()).then(|| {
                let state = if self.views_held() == 0 {
                    ReconstructionStatus::STATE_IDLE
                } else {
                    ReconstructionStatus::STATE_WAITING
                };
                let render_ms = self.stats.last_render_ms;
                let views = self.views_held();
                status_message(
                    &self.person,
                    views,
                    self.revision(),
                    0.0,
                    render_ms,
                    state,
                    "",
                    0,
                )
            })
        }) else {
            return;
        };
        if msg.rejected_counts == counts && msg.rejected_reasons == reasons {
            return;
        }
        (msg.rejected_reasons, msg.rejected_counts) = (reasons, counts);
        self.status_refresh_due = now + STATUS_REFRESH;
        self.send_status(msg);
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
            self.last_status = Some(msg);
        }
    }

    /// Poses the avatar at the pose the frames use and hands it to the publishers' preview.
    fn publish_preview(&self, now: Duration) {
        let (Some(current), true) = (&self.current, self.outputs.live()) else {
            return;
        };
        let pose = display_pose(self.animation.pose(now), now.as_secs_f32());
        let matrices = self.recon.template().skeleton.skinning_matrices(&pose);
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
        self.stats.frames_dropped += whole as u64 * self.cameras.cameras().len() as u64;
        if !self.slow_render_noted {
            self.slow_render_noted = true;
            let achieved = 1.0 / took.as_secs_f64();
            let message = format!(
                "rendering holds {achieved:.2} Hz per camera, below outputs.render_rate_hz {:.2} \
                 ({:.0} ms per batch of {} frame(s), {} renderer): frames drop, the newest pose \
                 wins",
                self.render_rate_hz,
                took.as_secs_f64() * 1e3,
                self.cameras.cameras().len(),
                if self.frames.is_neural() {
                    "neural"
                } else {
                    "gaussians"
                },
            );
            tracing::warn!("{message}");
            self.publish_status(
                self.revision(),
                0.0,
                ReconstructionStatus::STATE_IDLE,
                message,
            );
        }
    }

    fn run_job(&mut self, job: Job, clock: &impl Fn() -> Duration) {
        let Some(set) = self.store.snapshot(&job.person) else {
            let _ = self.scheduler.failed(&job.person, job.revision);
            return;
        };
        self.publish_status(
            job.revision.saturating_sub(1),
            0.0,
            ReconstructionStatus::STATE_RECONSTRUCTING,
            "reconstructing",
        );
        let views: Vec<(u64, &crate::reconstruct::preprocess::Preprocessed)> = set
            .views
            .iter()
            .map(|v| (v.frame_id, v.image.as_ref()))
            .collect();
        let result = self.recon.reconstruct(&views);
        match result {
            Ok(avatar) => {
                let stamp = set.views.iter().map(|v| v.stamp_ns).max().unwrap_or(0);
                self.publish_avatar(&job, &avatar, set.views.len(), stamp);
                self.current = Some(Current {
                    revision: job.revision,
                    avatar,
                });
                match self.scheduler.finished(&job.person, job.revision, clock()) {
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
                let _ = self.scheduler.failed(&job.person, job.revision);
                self.publish_status(
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
        revision: u64,
        latency_ms: f64,
        state: u8,
        message: impl Into<String>,
    ) {
        let mut msg = status_message(
            &self.person,
            self.views_held(),
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

    fn publish_frames(&mut self, now: Duration) {
        let (Some(current), true) = (&self.current, self.outputs.live()) else {
            return;
        };
        let pose = display_pose(self.animation.pose(now), now.as_secs_f32());
        let started = std::time::Instant::now();
        let frames = render_frames(
            &current.avatar,
            self.recon.template(),
            &pose,
            &self.cameras,
            &mut self.frames,
        );
        self.stats.last_render_ms =
            started.elapsed().as_secs_f64() * 1e3 / frames.len().max(1) as f64;
        let stamp = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as i64);
        for (i, f) in frames.iter().enumerate() {
            self.outputs.frame(i, f, stamp);
        }
        self.stats.rendered_frames += frames.len() as u64;
    }

    /// Renders a short animation of the latest avatar from every virtual camera and hands it
    /// to the outputs that store it (the files write `frames/<person>_cam<i>_<f>.png`);
    /// nothing is rendered when none does. The animation replays the poses read from the
    /// cameras when they drove the avatar (every one kept, up to the last 240), else `frames`
    /// frames of the built-in walk cycle. Returns the frames stored.
    pub fn write_animation(&mut self, frames: usize) -> usize {
        let Some(current) = &self.current else {
            return 0;
        };
        let Some(mut animation) = self.outputs.animation() else {
            return 0;
        };
        let camera_driven = matches!(self.animation.source, PoseSource::Auto | PoseSource::Camera)
            && self.animation.topic_pose.is_none();
        let track: Vec<Pose> = if camera_driven {
            self.animation.track.iter().cloned().collect()
        } else {
            Vec::new()
        };
        let frames = if track.is_empty() {
            frames
        } else {
            track.len()
        };
        let mut written = 0;
        for f in 0..frames {
            let pose = track
                .get(f)
                .cloned()
                .unwrap_or_else(|| display_pose(None, f as f32 / 24.0));
            let started = std::time::Instant::now();
            let images = render_frames(
                &current.avatar,
                self.recon.template(),
                &pose,
                &self.cameras,
                &mut self.frames,
            );
            self.stats.last_render_ms =
                started.elapsed().as_secs_f64() * 1e3 / images.len().max(1) as f64;
            for (c, image) in images.iter().enumerate() {
                let name = format!("{}_cam{c}_{f:03}", self.person);
                written += usize::from(animation.frame(&name, image));
            }
        }
        animation.finish();
        self.stats.rendered_frames += written as u64;
        written
    }
}

/// The perception stage `config` needs: none when no camera can be routed to perception and
/// the pose does not come from the cameras; live runs perceive on a worker thread, bag
/// replays every frame in order.
fn perception_stage(config: &NodeConfig) -> Result<Option<Perception>, PerceptionError> {
    if !config.runs_perception() {
        return Ok(None);
    }
    let p = &config.perception;
    let model = match p.landmark_model {
        LandmarkModelChoice::Lite => LandmarkModel::Lite,
        LandmarkModelChoice::Full => LandmarkModel::Full,
        LandmarkModelChoice::Heavy => LandmarkModel::Heavy,
    };
    let heavy = (!p.heavy_weights.is_empty()).then(|| Path::new(&p.heavy_weights));
    let networks = Arc::new(PoseNetworks::load(model, heavy)?);
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
    Ok(Some(Perception::new(
        networks,
        TrackerConfig {
            min_detection_score: p.min_detection_score,
            min_presence: p.min_presence,
            smooth_masks: live,
        },
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
