//! Zero-copy shared-memory transport over iceoryx2 for avatars and rendered frames.
//!
//! Each stream is one publish-subscribe service of `u64` slices (8-byte aligned bytes;
//! `lhmpp/<person>/avatar`,
//! `lhmpp/<person>/frame/<camera>`), whose samples hold the [`layout`] payload written in
//! place; publishers also notify `lhmpp/<person>/events`, on which subscribers wait.
//! This module is synchronous except [`ShmSubscriber::wait_async`], which lets a tokio task
//! sleep on the listener's file descriptor.

pub mod checksum;
mod error;
mod factory;
pub mod footprint;
pub mod layout;
mod loan;
pub mod options;
mod publisher;
mod subscriber;

pub use error::ShmError;
pub use factory::ShmNode;
pub use layout::{AvatarView, Decoded, FrameShape, FrameView, PayloadBody, PayloadKind, Stamp};
pub use loan::{FrameArraysMut, FrameLoan, PayloadLoan};
pub use options::ShmOptions;
pub use publisher::ShmPublisher;
pub use subscriber::{ShmSample, ShmSubscriber};

#[cfg(test)]
mod tests {
    use super::*;

    fn is_send<T: Send>() {}

    #[test]
    fn ports_can_move_into_tokio_tasks() {
        is_send::<ShmNode>();
        is_send::<ShmPublisher>();
        is_send::<ShmSubscriber>();
        is_send::<ShmSample>();
        // A task awaiting the listener can be spawned on the multi-threaded runtime.
        fn is_send_value<T: Send>(_: T) {}
        let _spawnable = |s: &mut ShmSubscriber| is_send_value(s.wait_async());
    }
}
