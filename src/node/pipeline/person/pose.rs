//! A person's pose path: the pose that drives their frames and where it comes from (the pose
//! topic, or the cameras through a pose estimator), with the camera poses kept for the
//! end-of-replay animation. It runs on every perceived frame and pose message, apart from the
//! person's reconstruction jobs, which never touch it.

use crate::body::Pose;
use crate::config::PoseSource;
use crate::perception::pose::PoseEstimator;
use crate::perception::{Landmark, BODY_LANDMARKS};
use std::collections::VecDeque;
use std::time::Duration;

/// With `inputs.pose_source: auto`, a pose topic counts as published for this long after its
/// last message.
const TOPIC_POSE_FRESH: Duration = Duration::from_secs(2);
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

/// The pose read from the cameras, and where and when.
struct CameraPose {
    pose: Pose,
    camera: String,
    at: Duration,
}

/// What drives a person's frames and where their pose comes from.
pub struct PosePath {
    source: PoseSource,
    /// The latest pose from the pose topic.
    topic_pose: Option<Pose>,
    /// When the last one arrived (node clock).
    topic_pose_at: Option<Duration>,
    /// The last one's header stamp (ns) and frame.
    topic_pose_stamp: Option<(i64, String)>,
    /// Turns the pose camera's world landmarks into poses (`None`: no camera pose).
    estimator: Option<PoseEstimator>,
    camera_pose: Option<CameraPose>,
    /// Recent camera poses, for the end-of-replay animation.
    track: VecDeque<Pose>,
}

impl PosePath {
    /// A person's pose path: poses from `source`, camera poses through `estimator`.
    pub fn new(source: PoseSource, estimator: Option<PoseEstimator>) -> Self {
        Self {
            source,
            topic_pose: None,
            topic_pose_at: None,
            topic_pose_stamp: None,
            estimator,
            camera_pose: None,
            track: VecDeque::new(),
        }
    }

    /// A checked pose from the pose topic, stamped `stamp_ns` in TF frame `frame`, that
    /// arrived at `arrival`.
    pub fn topic_pose(&mut self, pose: Pose, arrival: Duration, stamp_ns: i64, frame: String) {
        self.topic_pose = Some(pose);
        self.topic_pose_at = Some(arrival);
        self.topic_pose_stamp = Some((stamp_ns, frame));
    }

    /// `camera`'s world landmarks of the person at `t` seconds: when that camera drives the
    /// pose (the current pose camera, or any camera once it has not seen the person for
    /// [`POSE_CAMERA_HOLD`]), the estimator turns them into the camera pose, which is returned
    /// (`None`: another camera drives it, or no pose is read from the cameras).
    pub fn camera_landmarks(
        &mut self,
        camera: &str,
        t: f64,
        world: &[Landmark; BODY_LANDMARKS],
        now: Duration,
    ) -> Option<Pose> {
        let estimator = self.estimator.as_mut()?;
        if let Some(current) = &self.camera_pose {
            if current.camera != camera {
                if now.saturating_sub(current.at) < POSE_CAMERA_HOLD {
                    return None;
                }
                estimator.reset();
            }
        }
        let pose = estimator.update(t, world);
        self.track.push_back(pose.clone());
        while self.track.len() > POSE_TRACK_KEPT {
            self.track.pop_front();
        }
        self.camera_pose = Some(CameraPose {
            pose: pose.clone(),
            camera: camera.to_owned(),
            at: now,
        });
        Some(pose)
    }

    /// The pose the frames show at `now` (`None`: the walk cycle).
    pub fn pose(&self, now: Duration) -> Option<&Pose> {
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

    /// The newest pose-topic pose, when given in `world_frame` and stamped at most
    /// [`POSE_SYNC_BEFORE_NS`] before a view stamped `view_stamp_ns` (and not after it by more
    /// than [`POSE_SYNC_AFTER_NS`]): the pose that places the view's colours.
    pub fn pose_at_view(&self, view_stamp_ns: i64, world_frame: &str) -> Option<&Pose> {
        let pose = self.topic_pose.as_ref()?;
        let (stamp, pose_frame) = self.topic_pose_stamp.as_ref()?;
        let lag = view_stamp_ns - stamp;
        (pose_frame == world_frame && (-POSE_SYNC_AFTER_NS..=POSE_SYNC_BEFORE_NS).contains(&lag))
            .then_some(pose)
    }

    /// The poses of the end-of-replay animation: the poses read from the cameras when they
    /// drove the avatar (every one kept, up to the last 240), else none (the walk cycle).
    pub fn animation_track(&self) -> Vec<Pose> {
        let camera_driven = matches!(self.source, PoseSource::Auto | PoseSource::Camera)
            && self.topic_pose.is_none();
        if camera_driven {
            self.track.iter().cloned().collect()
        } else {
            Vec::new()
        }
    }
}
