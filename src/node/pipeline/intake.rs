//! The first room a camera frame enters: it is counted, then goes to camera-only perception,
//! waits for its mask topic (and then to perception, which reads the person inside the mask),
//! or goes on whole to the configured person.

use super::masks::Paired;
use super::people::StoreInput;
use super::perceive::Task;
use super::Pipeline;
use crate::config::{PersonMask, PoseSource};
use crate::node::inputs::CameraFrame;
use std::time::Duration;

/// Where a camera's frames get their person mask.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum MaskRoute {
    /// A mask topic (paired by stamp; frames of cameras with their own topic wait for it).
    Topic,
    /// Camera-only perception.
    Perception,
    /// None: whole frames.
    Whole,
}

impl Pipeline {
    /// Where frames of camera `topic` get their mask.
    pub(super) fn route(&self, topic: &str) -> MaskRoute {
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

    /// A camera frame: counted, then to perception, to the mask pairing, or on as a whole
    /// frame; with `inputs.pose_source: camera` every frame also goes to perception for the
    /// pose.
    pub(super) fn on_camera_frame(&mut self, frame: CameraFrame, now: Duration) {
        self.stats.frames += 1;
        self.stats
            .queue_waits
            .record(now.saturating_sub(frame.arrival));
        if let Some(age) = live_age(frame.stamp_ns) {
            self.stats.frame_ages.record(age);
        }
        let route = self.route(&frame.topic);
        let camera = self
            .tracking
            .then(|| self.calibration.floor_camera(&frame))
            .flatten();
        match (route, self.perception.as_mut()) {
            (MaskRoute::Perception, Some(perception)) => {
                perception.submit(frame, camera, Task::Find)
            }
            (MaskRoute::Perception, None) => {
                let person = self.default_person.clone();
                self.on_frame(frame, StoreInput::whole_frame(), &person, now)
            }
            (MaskRoute::Topic, _) => {
                let ready = self.masks.frame(frame, now);
                self.admit(ready, now);
            }
            (MaskRoute::Whole, perception) => {
                if let (PoseSource::Camera, Some(p)) = (self.setup.source, perception) {
                    p.submit(frame.clone(), camera, Task::PoseOnly);
                }
                let person = self.default_person.clone();
                self.on_frame(frame, StoreInput::whole_frame(), &person, now);
            }
        }
    }

    /// Frames whose mask pairing is settled: those with a mask go to perception, which reads
    /// the person inside it (pose, camera fit, colours) before they go on to the configured
    /// person cropped by that mask; without perception, or without a mask, they go on at once
    /// (whole frames when no mask came; with `inputs.pose_source: camera` perception still
    /// reads their pose).
    pub(super) fn admit(&mut self, ready: Vec<Paired>, now: Duration) {
        let person = self.default_person.clone();
        for (frame, mask) in ready {
            self.stats.masked += u64::from(mask.is_some());
            match (mask, self.perception.as_mut()) {
                (Some(mask), Some(perception)) => {
                    perception.submit(frame, None, Task::Within(mask));
                }
                (mask, perception) => {
                    if let (PoseSource::Camera, Some(p)) = (self.setup.source, perception) {
                        p.submit(frame.clone(), None, Task::PoseOnly);
                    }
                    let seen = StoreInput {
                        mask,
                        evidence: None,
                        hidden: 0.0,
                    };
                    self.on_frame(frame, seen, &person, now);
                }
            }
        }
    }
}

/// How old a frame stamped `stamp_ns` (ns since the epoch) is by this machine's clock, if
/// that is between 0 and 10 minutes (a live stream; replayed bags carry older stamps).
pub(super) fn live_age(stamp_ns: i64) -> Option<Duration> {
    let age = u64::try_from(super::render::unix_now_ns().checked_sub(stamp_ns)?).ok()?;
    Some(Duration::from_nanos(age)).filter(|age| *age < Duration::from_secs(600))
}
