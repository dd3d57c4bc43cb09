//! The endpoint's publishing internals: the output topic names (GaussianAvatar, rendered
//! frames as sensor_msgs/Image rgb8, one topic per virtual camera, ReconstructionStatus, the
//! preview), one port per topic and the rgb8 Image builder. A reliable writer whose send window
//! is full (typically before discovery has matched a reader) reports back-pressure, not an
//! error. What the node sends here is decided in [`crate::node::outputs`].

use super::RosError;
use crate::msgs::{Header, Image, Time};
use image::RgbImage;
use ros2_client::dds::{Node, Publisher};
use ros2_client::WriteError;
use serde::Serialize;
use std::sync::atomic::{AtomicU64, Ordering};

/// Output topic names before namespace expansion and remapping (relative names resolve in the
/// node's namespace).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OutputTopics {
    /// lhmpp_msgs/GaussianAvatar.
    pub avatar: String,
    /// lhmpp_msgs/CompactAvatar: the same avatar as SPZ plus its skin.
    pub compact_avatar: String,
    /// lhmpp_msgs/ReconstructionStatus.
    pub status: String,
    /// sensor_msgs/Image rgb8, one per virtual camera.
    pub frames: Vec<String>,
    /// sensor_msgs/PointCloud2 preview of the posed avatar (x y z + packed rgb).
    pub preview: String,
    /// tf2_msgs/TFMessage carrying the preview frame.
    pub tf: String,
}

impl OutputTopics {
    /// `avatar`, `avatar/compact`, `status`, `render/cam<i>/image_raw` for each virtual camera,
    /// `avatar/points` and `/tf`.
    pub fn for_virtual_cameras(count: u32) -> Self {
        Self {
            avatar: "avatar".into(),
            compact_avatar: "avatar/compact".into(),
            status: "status".into(),
            frames: (0..count)
                .map(|i| format!("render/cam{i}/image_raw"))
                .collect(),
            preview: "avatar/points".into(),
            tf: "/tf".into(),
        }
    }
}

/// Result of one publish call.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PublishOutcome {
    /// Handed to DDS.
    Sent,
    /// The reliable send window was full (no matched reader yet, or a slow one); the
    /// message was not sent. Try again with the next message.
    BackPressure,
    /// A transient-local output with no matched reader: the message is kept as the newest
    /// and published when a reader matches (see `latched`).
    Held,
}

/// A publisher with its resolved topic, counting back-pressure.
pub(crate) struct OutputPort<M: Serialize> {
    pub(crate) topic: String,
    pub(crate) publisher: Publisher<M>,
    back_pressure: AtomicU64,
}

impl<M: Serialize> OutputPort<M> {
    pub(crate) fn new(topic: String, publisher: Publisher<M>) -> Self {
        Self {
            topic,
            publisher,
            back_pressure: AtomicU64::new(0),
        }
    }

    pub(crate) fn publish(&self, msg: M) -> Result<PublishOutcome, RosError> {
        match self.publisher.publish(msg) {
            Ok(()) => Ok(PublishOutcome::Sent),
            Err(WriteError::WouldBlock { .. }) => {
                self.back_pressure.fetch_add(1, Ordering::Relaxed);
                tracing::debug!(topic = self.topic, "publish would block: back-pressure");
                Ok(PublishOutcome::BackPressure)
            }
            Err(e) => Err(RosError::Publish {
                topic: self.topic.clone(),
                reason: e.to_string(),
            }),
        }
    }

    /// Readers matched to this port's writer. ros2-client logs an ERROR for a writer that has
    /// never matched a reader, so the (cheaper, never failing) count of readers discovered on
    /// the topic is asked first: with none, none can be matched.
    pub(crate) fn matched_readers(&self, node: &std::sync::Mutex<Node>) -> usize {
        let node = node.lock().unwrap_or_else(|e| e.into_inner());
        if node.subscription_count(&self.topic) == 0 {
            return 0;
        }
        self.publisher.get_subscription_count(&node)
    }

    pub(crate) fn back_pressure(&self) -> u64 {
        self.back_pressure.load(Ordering::Relaxed)
    }
}

/// Builds an rgb8 `sensor_msgs/Image` from a rendered frame.
pub fn rgb8_image(image: &RgbImage, stamp_ns: i64, frame_id: &str) -> Image {
    Image {
        header: Header::new(Time::from_nanos(stamp_ns), frame_id),
        height: image.height(),
        width: image.width(),
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: image.width() * 3,
        data: image.as_raw().clone(),
    }
}
