//! Bag replay: messages of an MCAP bag become the same [`InputEvent`]s a live subscription
//! produces (same decoding functions), paced by their log times scaled by a rate, or as fast as
//! the pipeline consumes them (rate 0).

use crate::bag::{BagError, BagMessage, BagReader, Salvage};
use crate::msgs::{BodyPose, BodyShape, CameraInfo, CompressedImage, Image, RosMessage, TFMessage};
use crate::node::inputs::{self, InputEvent};
use crate::node::rejections::RejectReason;
use crate::node::ros::ResolvedTopics;
use std::path::Path;
use std::time::Duration;

/// What one bag message turned into.
#[derive(Debug)]
pub enum Replayed {
    /// An input event for the pipeline.
    Event(InputEvent),
    /// A subscribed topic whose message could not be decoded (counted and logged by the
    /// caller: [`crate::node::pipeline::Pipeline::reject`]).
    Rejected {
        /// Topic.
        topic: String,
        /// Its CDR does not decode, or it is an unusable image.
        reason: RejectReason,
        /// What was wrong, naming the numbers.
        detail: String,
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
    /// Opens `path`; a damaged bag replays every readable message (unreadable chunks skipped,
    /// a cut file up to its last complete chunk), with a warning saying what was skipped.
    pub fn open(path: &Path, topics: ResolvedTopics, max_side: u32) -> Result<Self, BagError> {
        let reader = BagReader::open(path)?;
        if !reader.is_complete() {
            tracing::warn!(
                "{}: damaged bag, replaying the {} messages read: {}",
                path.display(),
                reader.messages().len(),
                reader.salvage()
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

    /// What reading the bag skipped; complete for an intact bag.
    pub fn salvage(&self) -> &Salvage {
        self.reader.salvage()
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
        let max_side = self.max_side;
        let result = if t.images.iter().any(|x| x == topic) {
            self.decode::<Image>(m).and_then(|msg| {
                inputs::image_event(topic, msg, arrival, max_side).map_err(image_error)
            })
        } else if t.compressed_images.iter().any(|x| x == topic) {
            self.decode::<CompressedImage>(m).and_then(|msg| {
                inputs::compressed_event(topic, msg, arrival, max_side).map_err(image_error)
            })
        } else if let Some(camera_index) = t.camera_infos.iter().position(|x| x == topic) {
            self.decode::<CameraInfo>(m)
                .map(|info| InputEvent::CameraInfo {
                    topic: topic.to_owned(),
                    camera_index,
                    arrival,
                    info: Box::new(info),
                })
        } else if t.mask.as_deref() == Some(topic) {
            self.decode::<Image>(m).and_then(|msg| {
                inputs::mask_event(topic, None, msg, arrival, max_side).map_err(image_error)
            })
        } else if let Some((_, camera)) = t.camera_masks.iter().find(|(x, _)| x == topic) {
            self.decode::<Image>(m).and_then(|msg| {
                inputs::mask_event(topic, Some(camera), msg, arrival, max_side).map_err(image_error)
            })
        } else if t.pose.as_deref() == Some(topic) {
            self.decode::<BodyPose>(m).map(|pose| InputEvent::BodyPose {
                topic: topic.to_owned(),
                arrival,
                pose: Box::new(pose),
            })
        } else if t.tf_inputs.iter().any(|x| x == topic) {
            self.decode::<TFMessage>(m)
                .map(|msg| InputEvent::Transforms {
                    topic: topic.to_owned(),
                    transforms: msg.transforms,
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
        Some(match result {
            Ok(event) => Replayed::Event(event),
            Err((reason, detail)) => Replayed::Rejected {
                topic: topic.to_owned(),
                reason,
                detail,
            },
        })
    }

    fn decode<M: RosMessage>(&self, m: &BagMessage) -> Result<M, (RejectReason, String)> {
        let decoded = self.reader.decode::<M>(m);
        decoded.map_err(|e| (RejectReason::Cdr, e.to_string()))
    }
}

/// An image that decoded from CDR but cannot be used.
fn image_error(detail: String) -> (RejectReason, String) {
    (RejectReason::Image, detail)
}
