//! What the pipeline keeps for each person it reconstructs: the latest avatar, the body shape
//! in use and where it came from, the pose that drives the frames, and the status last
//! published. One person (the configured `person_id`) without tracking; one per tracked person
//! with it.

use super::calibration::HeightReading;
use crate::avatar::Avatar;
use crate::body::{Pose, Skeleton};
use crate::config::PoseSource;
use crate::msgs::ReconstructionStatus;
use crate::perception::pose::PoseEstimator;
use crate::reconstruct::shape::AcceptedShape;
use std::collections::VecDeque;
use std::time::Duration;

/// With `inputs.pose_source: auto`, a pose topic counts as published for this long after its
/// last message.
const TOPIC_POSE_FRESH: Duration = Duration::from_secs(2);

/// The latest avatar, its revision and the skeleton of the body it was built on.
pub(super) struct Current {
    pub(super) revision: u64,
    pub(super) avatar: Avatar,
    pub(super) skeleton: Skeleton,
}

/// The pose read from the cameras, and where and when.
pub(super) struct CameraPose {
    pub(super) pose: Pose,
    pub(super) camera: String,
    pub(super) at: Duration,
}

/// What drives a person's frames and where their pose comes from.
pub(super) struct Animation {
    pub(super) source: PoseSource,
    /// The latest pose from the pose topic.
    pub(super) topic_pose: Option<Pose>,
    /// When the last one arrived (node clock).
    pub(super) topic_pose_at: Option<Duration>,
    /// The last one's header stamp (ns) and frame.
    pub(super) topic_pose_stamp: Option<(i64, String)>,
    /// Turns the pose camera's world landmarks into poses (`None`: no camera pose).
    pub(super) estimator: Option<PoseEstimator>,
    pub(super) camera_pose: Option<CameraPose>,
    /// Recent camera poses, for the end-of-replay animation.
    pub(super) track: VecDeque<Pose>,
}

impl Animation {
    /// A person's animation: poses from `source`, camera poses through `estimator`.
    pub(super) fn new(source: PoseSource, estimator: Option<PoseEstimator>) -> Self {
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

    /// The pose the frames show at `now` (`None`: the walk cycle).
    pub(super) fn pose(&self, now: Duration) -> Option<&Pose> {
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

/// One person's state in the pipeline.
pub(super) struct PersonState {
    /// The latest avatar.
    pub(super) current: Option<Current>,
    pub(super) animation: Animation,
    /// The body shape to reconstruct with (`None`: the template as shipped).
    pub(super) shape: Option<AcceptedShape>,
    /// Whether the shape topic has given the shape (it then wins over the views).
    pub(super) shape_from_topic: bool,
    /// Shape changes so far (part of the reconstruction's input version).
    pub(super) shape_changes: u64,
    /// The body height read from this person's calibrated views.
    pub(super) heights: HeightReading,
    /// The last status published for this person.
    pub(super) last_status: Option<ReconstructionStatus>,
    /// Whether this node reconstructs the person (`cluster`); others are only tracked.
    pub(super) owned: bool,
}

impl PersonState {
    /// A person just seen.
    pub(super) fn new(animation: Animation, owned: bool) -> Self {
        Self {
            current: None,
            animation,
            shape: None,
            shape_from_topic: false,
            shape_changes: 0,
            heights: HeightReading::default(),
            last_status: None,
            owned,
        }
    }

    /// The latest avatar revision (0 before the first).
    pub(super) fn revision(&self) -> u64 {
        self.current.as_ref().map_or(0, |c| c.revision)
    }
}
