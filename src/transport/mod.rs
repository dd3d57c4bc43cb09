//! Zero-copy shared-memory transport over iceoryx2 for avatars and rendered frames.
//!
//! Each stream is one publish-subscribe service of `u64` slices (8-byte aligned bytes;
//! `lhmpp/<person>/avatar`,
//! `lhmpp/<person>/frame/<camera>`), whose samples hold the [`layout`] payload written in
//! place; publishers also notify `lhmpp/<person>/events`, on which subscribers wait.
//! This module is synchronous except [`ShmSubscriber::wait_async`], which lets a tokio task
//! sleep on the listener's file descriptor.

pub mod bench;
pub mod checksum;
mod error;
pub mod footprint;
pub mod layout;
mod node;
pub mod options;
mod publisher;
mod subscriber;

pub use error::ShmError;
pub use layout::{AvatarView, Decoded, FrameView, PayloadBody, PayloadKind, Stamp};
pub use node::ShmNode;
pub use options::ShmOptions;
pub use publisher::ShmPublisher;
pub use subscriber::{ShmSample, ShmSubscriber};
