//! `tf2_msgs/msg/TFMessage`: a batch of transforms as published on `/tf` and `/tf_static`.

use super::message::ros_message;
use super::TransformStamped;
use serde::{Deserialize, Serialize};

/// `tf2_msgs/msg/TFMessage`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[allow(clippy::upper_case_acronyms)]
pub struct TFMessage {
    /// The transforms.
    pub transforms: Vec<TransformStamped>,
}
ros_message!(
    TFMessage,
    "tf2_msgs",
    "TFMessage",
    include_str!("defs/tf2_msgs/TFMessage.msg")
);
