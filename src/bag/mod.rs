//! MCAP bags in the rosbag2 layout: record, read, and replay topics of ROS 2 messages.
//!
//! [`BagWriter`] writes what `ros2 bag record -s mcap` writes: profile `ros2`, one `ros2msg`
//! schema per type (definition plus dependencies), channels with `cdr` encoding and
//! `offered_qos_profiles`, zstd chunks and a `rosbag2` metadata record. [`BagReader`] reads
//! such bags, including ones cut short by a killed recorder or with unreadable chunks (skipped,
//! reading goes on: [`Salvage`]), whole and sorted by log time;
//! [`BagStream`] streams them in file order for replays too large for memory; [`recover`]
//! writes what a damaged bag still holds into a clean one.

mod damage;
mod error;
mod metadata;
mod qos;
mod reader;
mod recover;
mod resync;
mod scan;
mod stream;
mod writer;

pub use damage::{Resync, Salvage, Skipped, Truncation};
pub use error::BagError;
pub use qos::{Durability, QosProfile, Reliability};
pub use reader::{BagMessage, BagReader, TopicInfo};
pub use recover::{recover, Recovery};
pub use stream::BagStream;
pub use writer::{BagWriter, BagWriterOptions};

/// Schema encoding of ROS 2 `.msg` definitions in MCAP.
pub const SCHEMA_ENCODING: &str = "ros2msg";
/// Message encoding of ROS 2 CDR payloads in MCAP.
pub const MESSAGE_ENCODING: &str = "cdr";
/// MCAP header profile of rosbag2 files.
pub const PROFILE: &str = "ros2";
