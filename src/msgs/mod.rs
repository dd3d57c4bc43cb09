//! ROS 2 message types (standard and `lhmpp_msgs`) as serde structs encoded in CDR, matching
//! the `.msg` definitions under `msg/` and `src/msgs/defs/` byte for byte.
//!
//! Every type implements [`RosMessage`]: its ROS 2 and DDS type names, its `.msg` definition
//! (embedded, with dependencies resolved through [`registry`]) and CDR encode/decode with the
//! 4-byte encapsulation header that ROS 2 puts on the wire and in bags.

mod body_pose;
mod body_shape;
mod builtin;
mod compact_avatar;
pub mod definition;
mod error;
mod gaussian_avatar;
pub mod gaussian_cloud;
mod geometry;
mod message;
mod reconstruction_status;
pub mod registry;
mod sensor;
mod std_msgs;
mod tf2;

pub use body_pose::BodyPose;
pub use body_shape::BodyShape;
pub use builtin::Time;
pub use compact_avatar::CompactAvatar;
pub use error::MsgError;
pub use gaussian_avatar::GaussianAvatar;
pub use gaussian_cloud::{GaussianCloud, GaussianColors};
pub use geometry::{GeometryPose, Point, Quaternion, Transform, TransformStamped, Vector3};
pub use message::{dds_type_name, RosMessage, CDR_LE_HEADER};
pub use reconstruction_status::{ReconstructionState, ReconstructionStatus};
pub use sensor::{CameraInfo, CompressedImage, Image, PointCloud2, PointField, RegionOfInterest};
pub use std_msgs::{Header, StdString};
pub use tf2::TFMessage;
