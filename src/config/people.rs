//! Several people at once: the `tracking` section (persons found and followed in the camera
//! images, one avatar each) and the `cluster` section (which of them this node reconstructs).

use serde::{Deserialize, Serialize};
use std::ops::RangeInclusive;

/// Tracked persons (camera-only perception with several people).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackingSettings {
    /// Follow several people: every frame is split into persons (MoveNet MultiPose, then the
    /// landmark model per person), each gets a stable id (`person_<n>`) and its own frame
    /// store, avatar and rendered frames. Off: one person, `person_id`.
    pub enabled: bool,
    /// Seconds a person is kept without a sighting, in [`TrackingSettings::FORGET_AFTER`].
    pub forget_after: f64,
    /// Persons held at once, in [`TrackingSettings::MAX_PERSONS`]; past it the least recently
    /// seen one is dropped (counted in the status).
    pub max_persons: usize,
    /// Colour-histogram similarity from which a detection is a person seen in another camera
    /// or before, in [`super::PerceptionConfig::UNIT`].
    pub min_similarity: f32,
    /// Floor distance (metres, in [`TrackingSettings::FLOOR_GAP`]) within which a detection
    /// in a calibrated camera can be a person another camera saw a moment ago.
    pub max_floor_gap: f32,
}

impl TrackingSettings {
    /// Accepted `tracking.forget_after` values (seconds).
    pub const FORGET_AFTER: RangeInclusive<f64> = 0.1..=3600.0;
    /// Accepted `tracking.max_persons` values.
    pub const MAX_PERSONS: RangeInclusive<usize> = 1..=64;
    /// Accepted `tracking.max_floor_gap` values (metres).
    pub const FLOOR_GAP: RangeInclusive<f32> = 0.05..=5.0;

    /// The tracker's parameters.
    pub fn tracker(&self) -> crate::tracking::TrackingConfig {
        crate::tracking::TrackingConfig {
            forget_after: self.forget_after,
            max_persons: self.max_persons,
            min_similarity: self.min_similarity,
            max_floor_gap: self.max_floor_gap,
            ..crate::tracking::TrackingConfig::default()
        }
    }
}

impl Default for TrackingSettings {
    fn default() -> Self {
        let t = crate::tracking::TrackingConfig::default();
        Self {
            enabled: false,
            forget_after: t.forget_after,
            max_persons: t.max_persons,
            min_similarity: t.min_similarity,
            max_floor_gap: t.max_floor_gap,
        }
    }
}

/// Splitting the tracked persons between nodes that see the same cameras.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ClusterConfig {
    /// Nodes sharing the persons, in [`ClusterConfig::MEMBERS`].
    pub members: u32,
    /// This node's index, `0..members`: it reconstructs the persons whose id hashes to it and
    /// still tracks the others, so every node gives a person the same id.
    pub index: u32,
}

impl ClusterConfig {
    /// Accepted `cluster.members` values.
    pub const MEMBERS: RangeInclusive<u32> = 1..=64;
}

/// The position of `person_id` among `members` (its FNV-1a hash modulo `members`: the same on
/// every machine and build).
pub fn owner(person_id: &str, members: u32) -> u32 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in person_id.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    (h % u64::from(members.max(1))) as u32
}

impl Default for ClusterConfig {
    fn default() -> Self {
        Self {
            members: 1,
            index: 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The split puts every person in range, uses every member, and is stable.
    #[test]
    fn the_split_uses_every_member() {
        let mut used = [0; 3];
        for i in 0..12 {
            let id = format!("person_{i}");
            let member = owner(&id, 3);
            assert!(member < 3);
            assert_eq!(owner(&id, 3), member);
            used[member as usize] += 1;
        }
        assert!(used.iter().all(|&n| n > 0), "{used:?}");
        assert_eq!(owner("anyone", 1), 0);
    }
}
