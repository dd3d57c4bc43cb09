//! `std_msgs/msg/Header` (time stamp and coordinate frame of stamped data) and
//! `std_msgs/msg/String` (the cluster members' heartbeats).

use super::message::ros_message;
use super::Time;
use serde::{Deserialize, Serialize};

/// `std_msgs/msg/Header`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Header {
    /// Acquisition time of the data.
    pub stamp: Time,
    /// Coordinate frame the data is expressed in.
    pub frame_id: String,
}
ros_message!(
    Header,
    "std_msgs",
    "Header",
    include_str!("defs/std_msgs/Header.msg")
);

/// `std_msgs/msg/String` (named so that it does not shadow Rust's `String`).
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename = "String")]
pub struct StdString {
    /// The text.
    pub data: String,
}
ros_message!(
    StdString,
    "std_msgs",
    "String",
    include_str!("defs/std_msgs/String.msg")
);

impl Header {
    /// A header with the given stamp and frame.
    pub fn new(stamp: Time, frame_id: impl Into<String>) -> Self {
        Self {
            stamp,
            frame_id: frame_id.into(),
        }
    }
}
