//! Bag replay: messages of an MCAP bag become the same [`InputEvent`]s a live subscription
//! produces (same decoding functions), paced by their log times scaled by a rate, or as fast as
//! the pipeline consumes them (rate 0).

use crate::bag::{BagError, BagMessage, BagReader};
use crate::msgs::{BodyPose, BodyShape, CameraInfo, CompressedImage, Image, RosMessage};
use crate::node::ros::{inputs, InputEvent, ResolvedTopics};
use std::path::Path;
use std::time::Duration;

/// What one bag message turned into.
#[derive(Debug)]
pub enum Replayed {
    /// An input event for the pipeline.
    Event(InputEvent),
    /// A subscribed topic whose message could not be decoded (logged by the caller).
    Rejected {
        /// Topic.
        topic: String,
        /// Why.
        reason: String,
    },
}

/// A bag opened for replay, restricted to the node's input topics.
pub struct BagReplay {
    reader: BagReader,
    topics: ResolvedTopics,
    max_side: u32,
    next: usize,
    start_ns: u64,
}

impl BagReplay {
    /// Opens `path`; a truncated bag replays up to its last complete chunk (with a warning).
    pub fn open(path: &Path, topics: ResolvedTopics, max_side: u32) -> Result<Self, BagError> {
        let reader = BagReader::open(path)?;
        if let Some(t) = reader.truncation() {
            tracing::warn!(
                "{}: incomplete bag, replaying up to byte {} ({})",
                path.display(),
                t.offset,
                t.reason
            );
        }
        let start_ns = reader.time_range().map_or(0, |(s, _)| s);
        Ok(Self {
            reader,
            topics,
            max_side,
            next: 0,
            start_ns,
        })
    }

    /// Messages in the bag (all topics).
    pub fn len(&self) -> usize {
        self.reader.messages().len()
    }

    /// True for an empty bag.
    pub fn is_empty(&self) -> bool {
        self.reader.messages().is_empty()
    }

    /// The next message on a subscribed topic with its offset from the bag start (log time),
    /// converted to an event stamped with `arrival`; `None` at the end.
    pub fn next(&mut self, arrival: impl Fn() -> Duration) -> Option<(Duration, Replayed)> {
        while let Some(m) = self.reader.messages().get(self.next) {
            self.next += 1;
            let offset = Duration::from_nanos(m.log_time.saturating_sub(self.start_ns));
            if let Some(r) = self.convert(m, arrival()) {
                return Some((offset, r));
            }
        }
        None
    }

    fn convert(&self, m: &BagMessage, arrival: Duration) -> Option<Replayed> {
        let topic: &str = &m.topic;
        let t = &self.topics;
        let reject = |reason: String| Replayed::Rejected {
            topic: topic.to_owned(),
            reason,
        };
        let result = if t.images.iter().any(|x| x == topic) {
            self.decode::<Image>(m)
                .and_then(|msg| inputs::image_event(topic, msg, arrival, self.max_side))
        } else if t.compressed_images.iter().any(|x| x == topic) {
            self.decode::<CompressedImage>(m)
                .and_then(|msg| inputs::compressed_event(topic, msg, arrival, self.max_side))
        } else if let Some(camera_index) = t.camera_infos.iter().position(|x| x == topic) {
            self.decode::<CameraInfo>(m)
                .map(|info| InputEvent::CameraInfo {
                    topic: topic.to_owned(),
                    camera_index,
                    arrival,
                    info: Box::new(info),
                })
        } else if t.mask.as_deref() == Some(topic) {
            self.decode::<Image>(m)
                .and_then(|msg| inputs::mask_event(topic, None, msg, arrival, self.max_side))
        } else if let Some((_, camera)) = t.camera_masks.iter().find(|(x, _)| x == topic) {
            self.decode::<Image>(m).and_then(|msg| {
                inputs::mask_event(topic, Some(camera), msg, arrival, self.max_side)
            })
        } else if t.pose.as_deref() == Some(topic) {
            self.decode::<BodyPose>(m).map(|pose| InputEvent::BodyPose {
                topic: topic.to_owned(),
                arrival,
                pose: Box::new(pose),
            })
        } else if t.shape.as_deref() == Some(topic) {
            self.decode::<BodyShape>(m)
                .map(|shape| InputEvent::BodyShape {
                    topic: topic.to_owned(),
                    arrival,
                    shape: Box::new(shape),
                })
        } else {
            return None;
        };
        Some(result.map_or_else(reject, Replayed::Event))
    }

    fn decode<M: RosMessage>(&self, m: &BagMessage) -> Result<M, String> {
        self.reader.decode::<M>(m).map_err(|e| e.to_string())
    }
}
