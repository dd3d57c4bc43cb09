//! `builtin_interfaces/msg/Time`: a ROS time stamp in seconds and nanoseconds.

use super::message::ros_message;
use serde::{Deserialize, Serialize};

/// `builtin_interfaces/msg/Time`.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default, Serialize, Deserialize,
)]
pub struct Time {
    /// Seconds component.
    pub sec: i32,
    /// Nanoseconds component, in `[0, 1e9)`.
    pub nanosec: u32,
}
ros_message!(
    Time,
    "builtin_interfaces",
    "Time",
    include_str!("defs/builtin_interfaces/Time.msg")
);

impl Time {
    /// The time `nanos` nanoseconds after the epoch (saturating at the `i32` seconds range).
    pub fn from_nanos(nanos: i64) -> Self {
        let sec = nanos.div_euclid(1_000_000_000);
        let nanosec = nanos.rem_euclid(1_000_000_000) as u32;
        Self {
            sec: sec.clamp(i32::MIN as i64, i32::MAX as i64) as i32,
            nanosec,
        }
    }

    /// Nanoseconds since the epoch.
    pub fn as_nanos(&self) -> i64 {
        self.sec as i64 * 1_000_000_000 + self.nanosec as i64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn negative_times_keep_nanoseconds_positive() {
        let t = Time::from_nanos(-1_700_000_000);
        assert_eq!((t.sec, t.nanosec), (-2, 300_000_000));
        assert_eq!(t.as_nanos(), -1_700_000_000);
    }
}
