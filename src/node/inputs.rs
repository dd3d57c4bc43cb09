//! What the node receives: decoded camera frames, masks, camera calibration, body poses and shapes,
//! all delivered as [`InputEvent`]s, and the conversions from the messages that live
//! subscriptions ([`super::ros`]) and bag replay ([`super::replay`]) share. Live image messages
//! wait in the bounded input queue still encoded ([`Incoming::Image`]) and are decoded when
//! taken, so a frame dropped at a full queue costs no decoding and little memory.
//! Synchronous: no ROS 2 endpoint and no runtime.

use crate::msgs::{
    BodyPose, BodyShape, CameraInfo, CompressedImage, Header, Image, TransformStamped,
};
use crate::reconstruct::image_decode::{decode_compressed, decode_mask, decode_raw, RawImage};
use image::{GrayImage, RgbImage};
use std::sync::Arc;
use std::time::Duration;

/// A decoded camera frame.
#[derive(Debug, Clone)]
pub struct CameraFrame {
    /// Resolved topic it came from (identifies the camera).
    pub topic: String,
    /// `header.frame_id` (the camera's optical frame).
    pub frame_id: String,
    /// `header.stamp` in nanoseconds since the epoch.
    pub stamp_ns: i64,
    /// Node clock at arrival.
    pub arrival: Duration,
    /// Pixels, RGB8.
    pub image: Arc<RgbImage>,
}

/// A decoded person mask.
#[derive(Debug, Clone)]
pub struct MaskFrame {
    /// Resolved topic.
    pub topic: String,
    /// The camera topic whose frames it masks; `None` for the shared mask topic (any camera).
    pub camera: Option<String>,
    /// `header.stamp` in nanoseconds since the epoch (matches the frame it masks).
    pub stamp_ns: i64,
    /// Node clock at arrival.
    pub arrival: Duration,
    /// Mask, 0 = background, 255 = person.
    pub mask: Arc<GrayImage>,
}

/// One decoded input message.
#[derive(Debug, Clone)]
pub enum InputEvent {
    /// A camera frame (from `Image` or `CompressedImage`).
    Frame(CameraFrame),
    /// A person mask.
    Mask(MaskFrame),
    /// Calibration of a camera.
    CameraInfo {
        /// Resolved CameraInfo topic.
        topic: String,
        /// Index of the matching image topic (camera infos pair with image topics by position).
        camera_index: usize,
        /// Node clock at arrival.
        arrival: Duration,
        /// The message.
        info: Box<CameraInfo>,
    },
    /// A body pose that drives the avatar.
    BodyPose {
        /// Resolved topic.
        topic: String,
        /// Node clock at arrival.
        arrival: Duration,
        /// The message.
        pose: Box<BodyPose>,
    },
    /// Transforms of the TF tree (`/tf` or `/tf_static`): where the cameras are.
    Transforms {
        /// Resolved topic.
        topic: String,
        /// The transforms.
        transforms: Vec<TransformStamped>,
    },
    /// Another cluster member is alive (`cluster`, its heartbeat).
    ClusterHeartbeat {
        /// Its `cluster.index`.
        index: u32,
        /// Its `cluster.members`.
        members: u32,
        /// Node clock at arrival.
        arrival: Duration,
    },
    /// A body shape (checked by the pipeline, which knows the body model in use).
    BodyShape {
        /// Resolved topic.
        topic: String,
        /// Node clock at arrival.
        arrival: Duration,
        /// The message.
        shape: Box<BodyShape>,
    },
}

/// What waits in the live input queue: an event, or an image message not yet decoded.
#[derive(Debug)]
pub enum Incoming {
    /// A message that needs no decoding (camera info, pose, shape).
    Event(InputEvent),
    /// A camera image or mask, decoded when taken ([`EncodedImage::decode`]).
    Image(Box<EncodedImage>),
}

/// An image message as it arrived on its topic, with what decoding it needs.
#[derive(Debug)]
pub struct EncodedImage {
    /// Resolved topic.
    pub topic: String,
    /// Node clock at arrival.
    pub arrival: Duration,
    /// Larger sides are refused before decoding (`inputs.max_image_side`).
    pub max_side: u32,
    /// The message.
    pub message: ImageMessage,
}

/// The image message kinds the node subscribes to.
#[derive(Debug)]
pub enum ImageMessage {
    /// A raw camera image.
    Raw(Image),
    /// A compressed (JPEG/PNG) camera image.
    Compressed(CompressedImage),
    /// A mono8 person mask of `camera` (`None`: any camera).
    Mask {
        /// The camera topic it masks.
        camera: Option<String>,
        /// The message.
        image: Image,
    },
}

impl EncodedImage {
    /// Decodes the image into its event; the error names the topic and what is wrong.
    pub fn decode(self) -> Result<InputEvent, String> {
        let Self {
            topic,
            arrival,
            max_side,
            message,
        } = self;
        match message {
            ImageMessage::Raw(msg) => image_event(&topic, msg, arrival, max_side),
            ImageMessage::Compressed(msg) => compressed_event(&topic, msg, arrival, max_side),
            ImageMessage::Mask { camera, image } => {
                mask_event(&topic, camera.as_deref(), image, arrival, max_side)
            }
        }
    }
}

/// `sensor_msgs/Image` → [`InputEvent::Frame`].
pub(crate) fn image_event(
    topic: &str,
    msg: Image,
    arrival: Duration,
    max_side: u32,
) -> Result<InputEvent, String> {
    let raw = RawImage::from(&msg);
    let image = decode_raw(topic, &raw, max_side).map_err(|e| e.to_string())?;
    Ok(frame_event(topic, msg.header, arrival, image))
}

/// `sensor_msgs/CompressedImage` → [`InputEvent::Frame`].
pub(crate) fn compressed_event(
    topic: &str,
    msg: CompressedImage,
    arrival: Duration,
    max_side: u32,
) -> Result<InputEvent, String> {
    let image =
        decode_compressed(topic, &msg.format, &msg.data, max_side).map_err(|e| e.to_string())?;
    Ok(frame_event(topic, msg.header, arrival, image))
}

/// A decoded camera image of `topic` as an [`InputEvent::Frame`].
fn frame_event(topic: &str, header: Header, arrival: Duration, image: RgbImage) -> InputEvent {
    InputEvent::Frame(CameraFrame {
        topic: topic.to_owned(),
        stamp_ns: header.stamp.as_nanos(),
        frame_id: header.frame_id,
        arrival,
        image: Arc::new(image),
    })
}

/// mono8 `sensor_msgs/Image` → [`InputEvent::Mask`] of `camera` (`None`: any camera).
pub(crate) fn mask_event(
    topic: &str,
    camera: Option<&str>,
    msg: Image,
    arrival: Duration,
    max_side: u32,
) -> Result<InputEvent, String> {
    let raw = RawImage::from(&msg);
    let mask = decode_mask(topic, &raw, max_side).map_err(|e| e.to_string())?;
    Ok(InputEvent::Mask(MaskFrame {
        topic: topic.to_owned(),
        camera: camera.map(str::to_owned),
        stamp_ns: msg.header.stamp.as_nanos(),
        arrival,
        mask: Arc::new(mask),
    }))
}
