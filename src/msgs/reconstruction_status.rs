//! `lhmpp_msgs/msg/ReconstructionStatus`: per-person progress of the avatar reconstruction.

use super::message::ros_message;
use super::Header;
use serde::{Deserialize, Serialize};

/// `lhmpp_msgs/msg/ReconstructionStatus`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ReconstructionStatus {
    /// Time of this status.
    pub header: Header,
    /// Tracked person.
    pub person_id: String,
    /// Views currently held for the person.
    pub views_held: u32,
    /// Revision of the newest avatar published (0: none yet).
    pub revision: u32,
    /// Duration of the last reconstruction in milliseconds.
    pub last_latency_ms: f64,
    /// Per-frame render time of the last rendered batch in milliseconds (0: none yet).
    pub last_render_ms: f64,
    /// One of the `STATE_*` constants; see [`ReconstructionState`].
    pub state: u8,
    /// Human-readable detail, e.g. an error.
    pub message: String,
    /// Reasons input messages were rejected for since the node started (`cdr`, `image`,
    /// `frame`, `pose`, `shape`), those with at least one rejection.
    pub rejected_reasons: Vec<String>,
    /// Messages rejected for each of `rejected_reasons`.
    pub rejected_counts: Vec<u64>,
}
ros_message!(
    ReconstructionStatus,
    "lhmpp_msgs",
    "ReconstructionStatus",
    include_str!("../../msg/msg/ReconstructionStatus.msg")
);

impl ReconstructionStatus {
    /// Nothing to do.
    pub const STATE_IDLE: u8 = 0;
    /// Views held, waiting for more or for a worker.
    pub const STATE_WAITING: u8 = 1;
    /// A reconstruction is running.
    pub const STATE_RECONSTRUCTING: u8 = 2;
    /// The last reconstruction failed.
    pub const STATE_ERROR: u8 = 3;

    /// The `state` field as an enum, `None` for a value outside the constants.
    pub fn reconstruction_state(&self) -> Option<ReconstructionState> {
        ReconstructionState::from_u8(self.state)
    }
}

/// The values of [`ReconstructionStatus::state`] as a Rust enum.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum ReconstructionState {
    /// Nothing to do.
    Idle = ReconstructionStatus::STATE_IDLE,
    /// Views held, waiting for more or for a worker.
    Waiting = ReconstructionStatus::STATE_WAITING,
    /// A reconstruction is running.
    Reconstructing = ReconstructionStatus::STATE_RECONSTRUCTING,
    /// The last reconstruction failed.
    Error = ReconstructionStatus::STATE_ERROR,
}

impl ReconstructionState {
    /// The state of a raw `state` value.
    pub fn from_u8(value: u8) -> Option<Self> {
        [Self::Idle, Self::Waiting, Self::Reconstructing, Self::Error]
            .into_iter()
            .find(|s| *s as u8 == value)
    }
}
