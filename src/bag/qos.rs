//! The QoS a topic was offered with, serialised as rosbag2's `offered_qos_profiles` YAML.

/// Reliability policy.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Reliability {
    /// Retransmit until received.
    #[default]
    Reliable,
    /// Send once.
    BestEffort,
}

/// Durability policy.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Durability {
    /// Late joiners get nothing old.
    #[default]
    Volatile,
    /// Late joiners get the last `depth` messages.
    TransientLocal,
}

/// A publisher's QoS as rosbag2 records it (keep-last history, infinite deadline, lifespan and
/// lease, automatic liveliness).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QosProfile {
    /// Reliability.
    pub reliability: Reliability,
    /// Durability.
    pub durability: Durability,
    /// Keep-last history depth.
    pub depth: u32,
}

impl Default for QosProfile {
    /// The ROS 2 default: reliable, volatile, keep last 10.
    fn default() -> Self {
        Self {
            reliability: Reliability::Reliable,
            durability: Durability::Volatile,
            depth: 10,
        }
    }
}

/// How rosbag2 (Jazzy) writes an infinite duration.
const INFINITE: &str = "\n    sec: 9223372036\n    nsec: 854775807";

impl QosProfile {
    /// The `offered_qos_profiles` channel metadata: a YAML list with this one profile.
    pub fn offered_profiles_yaml(&self) -> String {
        let reliability = match self.reliability {
            Reliability::Reliable => "reliable",
            Reliability::BestEffort => "best_effort",
        };
        let durability = match self.durability {
            Durability::Volatile => "volatile",
            Durability::TransientLocal => "transient_local",
        };
        format!(
            "- history: keep_last\n  depth: {depth}\n  reliability: {reliability}\n  \
             durability: {durability}\n  deadline:{INFINITE}\n  lifespan:{INFINITE}\n  \
             liveliness: automatic\n  liveliness_lease_duration:{INFINITE}\n  \
             avoid_ros_namespace_conventions: false",
            depth = self.depth
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offered_profiles_are_a_yaml_list_with_the_policies() {
        let qos = QosProfile {
            reliability: Reliability::BestEffort,
            durability: Durability::TransientLocal,
            depth: 1,
        };
        let yaml: serde_yaml_ng::Value =
            serde_yaml_ng::from_str(&qos.offered_profiles_yaml()).unwrap();
        let profile = &yaml[0];
        assert_eq!(profile["reliability"].as_str(), Some("best_effort"));
        assert_eq!(profile["durability"].as_str(), Some("transient_local"));
        assert_eq!(profile["depth"].as_u64(), Some(1));
        assert_eq!(profile["deadline"]["sec"].as_i64(), Some(9223372036));
    }
}
