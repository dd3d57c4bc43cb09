//! DDS participant set-up for the node: domain id (config or `ROS_DOMAIN_ID`, which
//! ros2-client does not read), optional restriction to given interfaces (tests use 127.0.0.1),
//! socket buffer sizes, and the QoS profiles the node uses.

use super::RosError;
use crate::config::{FrameQos, ImageQos};
use ros2_client::dds::rustdds::DomainParticipantBuilder;
use ros2_client::qos::{Durability, History, QosProfile, Reliability, WhenFull};
use ros2_client::Context;
use std::net::IpAddr;
use std::time::Duration;

/// Highest DDS domain id ROS 2 allows.
pub const MAX_DOMAIN_ID: u16 = 232;

/// Resolves the configured domain id: `-1` reads `ROS_DOMAIN_ID` (`env_value`), falling back
/// to 0 when it is unset or empty.
pub fn resolve_domain_id(configured: i32, env_value: Option<&str>) -> Result<u16, RosError> {
    if configured >= 0 {
        return u16::try_from(configured)
            .ok()
            .filter(|d| *d <= MAX_DOMAIN_ID)
            .ok_or_else(|| {
                RosError::DomainId(format!("domain_id {configured} is not in 0..=232"))
            });
    }
    match env_value.map(str::trim) {
        None | Some("") => Ok(0),
        Some(text) => text
            .parse::<u16>()
            .ok()
            .filter(|d| *d <= MAX_DOMAIN_ID)
            .ok_or_else(|| RosError::DomainId(format!("ROS_DOMAIN_ID=`{text}` is not in 0..=232"))),
    }
}

/// How the DDS participant is created.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ParticipantOptions {
    /// DDS domain id.
    pub domain_id: u16,
    /// Use only interfaces with these addresses (e.g. `127.0.0.1` for loopback tests);
    /// empty means all.
    pub only_networks: Vec<IpAddr>,
    /// Socket receive buffer size in bytes (0 = RustDDS default).
    pub socket_receive_buffer: usize,
}

/// Creates the ros2-client context (one DDS participant).
pub fn create_context(opts: &ParticipantOptions) -> Result<Context, RosError> {
    let mut builder = DomainParticipantBuilder::new(opts.domain_id);
    if !opts.only_networks.is_empty() {
        builder = builder.with_only_networks(opts.only_networks.iter().copied());
    }
    if opts.socket_receive_buffer > 0 {
        builder = builder.socket_receive_buffer_size(opts.socket_receive_buffer);
    }
    if let Some((low, high)) = ephemeral_ports().and_then(|r| ports_in_range(opts.domain_id, r)) {
        tracing::warn!(
            "DDS domain {} uses UDP ports {low}..={high}, inside this host's ephemeral port range \
             (net.ipv4.ip_local_port_range): when another socket holds one, discovery fails now \
             and then; on Linux, domains 0..=101 and 215..=232 stay clear of it",
            opts.domain_id
        );
    }
    let participant = builder.build().map_err(|e| {
        RosError::Create(format!("DDS participant in domain {}: {e}", opts.domain_id))
    })?;
    Context::from_domain_participant(participant)
        .map_err(|e| RosError::Create(format!("ROS 2 context in domain {}: {e}", opts.domain_id)))
}

/// RTPS discovery and user ports of a domain (port base 7400, domain gain 250), for the
/// first ten participants on a host.
fn domain_ports(domain: u16) -> (u32, u32) {
    let base = 7400 + 250 * u32::from(domain);
    (base, base + 11 + 2 * 9)
}

/// The part of `domain`'s ports (`domain_ports`) inside `range`, if any.
fn ports_in_range(domain: u16, range: (u32, u32)) -> Option<(u32, u32)> {
    let (low, high) = domain_ports(domain);
    let (low, high) = (low.max(range.0), high.min(range.1));
    (low <= high).then_some((low, high))
}

/// This host's ephemeral port range (`/proc/sys/net/ipv4/ip_local_port_range`), if readable.
fn ephemeral_ports() -> Option<(u32, u32)> {
    let text = std::fs::read_to_string("/proc/sys/net/ipv4/ip_local_port_range").ok()?;
    let mut it = text.split_whitespace().map(|t| t.parse::<u32>().ok());
    Some((it.next()??, it.next()??))
}

/// The image subscriptions' QoS for `inputs.image_qos`: keep last 5, volatile; best effort
/// for `sensor_data` (as rclcpp's SensorDataQoS), reliable for `reliable`.
pub fn image_input_qos(qos: ImageQos) -> QosProfile {
    let base = QosProfile::subscription_default().history(History::KeepLast { depth: 5 });
    match qos {
        ImageQos::SensorData => base.reliability(Reliability::BestEffort),
        ImageQos::Reliable => base.reliability(Reliability::Reliable {
            when_full: WhenFull::DEFAULT,
        }),
    }
}

/// QoS of low-rate inputs that must not be lost (CameraInfo, BodyPose): reliable, keep last 10.
pub fn reliable_input_qos() -> QosProfile {
    QosProfile::subscription_default()
        .history(History::KeepLast { depth: 10 })
        .reliability(Reliability::Reliable {
            when_full: WhenFull::DEFAULT,
        })
}

/// QoS of the avatar and status outputs: reliable and transient-local (late joiners get the
/// latest avatar), keep last 1; a full send window fails at once (back-pressure, not a stall).
pub fn latched_output_qos() -> QosProfile {
    QosProfile::subscription_default()
        .history(History::KeepLast { depth: 1 })
        .durability(Durability::TransientLocal)
        .reliability(Reliability::Reliable {
            when_full: WhenFull::Wait(Duration::from_millis(5)),
        })
}

/// QoS of rendered frames (`outputs.frame_qos`), volatile keep last 2 (a video stream).
/// `Reliable` (the default) is matched by reliable subscribers (RViz2's image display, rqt)
/// and best-effort ones alike; a full send window fails after 5 ms (back-pressure, the frame
/// is dropped), so a slow reader never stalls rendering. `BestEffort` matches best-effort
/// subscribers only.
pub fn frame_output_qos(choice: FrameQos) -> QosProfile {
    let base = QosProfile::subscription_default().history(History::KeepLast { depth: 2 });
    match choice {
        FrameQos::Reliable => base.reliability(Reliability::Reliable {
            when_full: WhenFull::Wait(Duration::from_millis(5)),
        }),
        FrameQos::BestEffort => base.reliability(Reliability::BestEffort),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn domains_whose_ports_meet_the_linux_ephemeral_range_are_found() {
        let linux = (32768, 60999);
        assert_eq!(ports_in_range(0, linux), None);
        assert_eq!(ports_in_range(100, linux), None);
        assert_eq!(ports_in_range(101, linux), None);
        assert_eq!(ports_in_range(102, linux), Some((32900, 32929)));
        assert_eq!(ports_in_range(150, linux), Some((44900, 44929)));
        assert_eq!(ports_in_range(214, linux), Some((60900, 60929)));
        assert_eq!(ports_in_range(215, linux), None);
        assert_eq!(ports_in_range(232, linux), None);
    }

    #[test]
    fn domain_id_comes_from_config_then_env_then_zero() {
        assert_eq!(resolve_domain_id(7, Some("3")).unwrap(), 7);
        assert_eq!(resolve_domain_id(-1, Some("3")).unwrap(), 3);
        assert_eq!(resolve_domain_id(-1, Some(" 42 ")).unwrap(), 42);
        assert_eq!(resolve_domain_id(-1, None).unwrap(), 0);
        assert_eq!(resolve_domain_id(-1, Some("")).unwrap(), 0);
    }

    #[test]
    fn bad_domain_ids_are_errors_naming_the_source() {
        let e = resolve_domain_id(-1, Some("abc")).unwrap_err().to_string();
        assert!(e.contains("ROS_DOMAIN_ID") && e.contains("abc"), "{e}");
        let e = resolve_domain_id(-1, Some("300")).unwrap_err().to_string();
        assert!(e.contains("300"), "{e}");
        assert!(resolve_domain_id(233, None).is_err());
    }

    #[test]
    fn frames_are_reliable_keep_last_2_unless_best_effort_is_asked_for() {
        let q = frame_output_qos(FrameQos::Reliable);
        assert!(matches!(q.reliability, Reliability::Reliable { .. }));
        assert_eq!(q.history, History::KeepLast { depth: 2 });
        assert_eq!(q.durability, Durability::Volatile);
        let q = frame_output_qos(FrameQos::BestEffort);
        assert_eq!(q.reliability, Reliability::BestEffort);
        assert_eq!(q.history, History::KeepLast { depth: 2 });
    }

    #[test]
    fn sensor_data_is_best_effort_keep_last_5() {
        let q = image_input_qos(ImageQos::SensorData);
        assert_eq!(q.reliability, Reliability::BestEffort);
        assert_eq!(q.history, History::KeepLast { depth: 5 });
        let r = image_input_qos(ImageQos::Reliable);
        assert!(matches!(r.reliability, Reliability::Reliable { .. }));
        assert_eq!(r.history, History::KeepLast { depth: 5 });
    }
}
