//! The error type of bag reading and writing; every variant names the bag file.

use crate::msgs::MsgError;
use std::path::PathBuf;

/// A bag could not be written, opened or decoded.
#[derive(Debug, thiserror::Error)]
pub enum BagError {
    /// Creating, reading or writing the file failed.
    #[error("bag {path}: {source}")]
    Io {
        /// The bag file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The MCAP library rejected a write or a record.
    #[error("bag {path}: MCAP: {source}")]
    Mcap {
        /// The bag file.
        path: PathBuf,
        /// The MCAP error.
        source: mcap::McapError,
    },
    /// The file does not start with the MCAP magic bytes.
    #[error("bag {path}: not an MCAP file (bad magic bytes)")]
    NotMcap {
        /// The file.
        path: PathBuf,
    },
    /// A topic was written with two different message types.
    #[error("bag {path}: topic `{topic}` has type {existing}, cannot write a {given}")]
    TopicTypeMismatch {
        /// The bag file.
        path: PathBuf,
        /// The topic.
        topic: String,
        /// Type the topic was first written with.
        existing: String,
        /// Type of the rejected message.
        given: String,
    },
    /// A message type is unknown (no definition for its schema) or fails to decode.
    #[error("bag {path}, topic `{topic}`: {source}")]
    Message {
        /// The bag file.
        path: PathBuf,
        /// The topic.
        topic: String,
        /// The message error.
        source: MsgError,
    },
    /// A typed read asked for a type other than the topic's.
    #[error("bag {path}: topic `{topic}` holds {bag_type}, not {requested}")]
    WrongType {
        /// The bag file.
        path: PathBuf,
        /// The topic.
        topic: String,
        /// Type recorded in the bag.
        bag_type: String,
        /// Type asked for.
        requested: String,
    },
    /// A metadata record whose name the writer reserves for itself.
    #[error("bag {path}: metadata record `{name}` is written by the bag writer itself")]
    ReservedMetadata {
        /// The bag file.
        path: PathBuf,
        /// The record name.
        name: String,
    },
    /// A recovery asked to write over the bag it reads.
    #[error("bag {path}: will not write the recovered bag over the damaged one")]
    SameFile {
        /// The bag file.
        path: PathBuf,
    },
    /// Writing after `finish`.
    #[error("bag {path}: already finished")]
    Finished {
        /// The bag file.
        path: PathBuf,
    },
}
