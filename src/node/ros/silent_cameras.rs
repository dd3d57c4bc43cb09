//! A warning for camera topics that stay silent after the node starts: the most common first
//! problem with a live camera is a topic name or QoS that does not match, and without a
//! message the node would just wait. The warning names the topic, the type, the QoS the node
//! subscribes with and the command that shows what is published.

use crate::config::ImageQos;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// How long a camera topic may stay silent before the node warns about it.
pub const SILENT_CAMERA_WARNING: Duration = Duration::from_secs(5);

/// The camera topics being watched, each with a flag its subscription sets on every message.
#[derive(Debug, Default)]
pub(crate) struct CameraWatch {
    topics: Vec<(String, &'static str, Arc<AtomicBool>)>,
}

impl CameraWatch {
    /// Watch `topic` of ROS type `type_name`; the returned flag is set by its subscription.
    pub(crate) fn watch(&mut self, topic: &str, type_name: &'static str) -> Arc<AtomicBool> {
        let seen = Arc::new(AtomicBool::new(false));
        self.topics
            .push((topic.to_owned(), type_name, seen.clone()));
        seen
    }

    /// The watched topics (with their types) that have had no message yet.
    fn silent(&self) -> Vec<(&str, &'static str)> {
        self.topics
            .iter()
            .filter(|(_, _, seen)| !seen.load(Ordering::Relaxed))
            .map(|(topic, type_name, _)| (topic.as_str(), *type_name))
            .collect()
    }

    /// After `after`, warns once for each watched topic that has had no message.
    pub(crate) fn spawn(self, after: Duration, qos: ImageQos) -> tokio::task::JoinHandle<()> {
        tokio::spawn(async move {
            tokio::time::sleep(after).await;
            for (topic, type_name) in self.silent() {
                tracing::warn!("{}", silence_warning(topic, type_name, qos, after));
            }
        })
    }
}

/// The warning for a camera topic with no message in its first `after`.
pub fn silence_warning(topic: &str, type_name: &str, qos: ImageQos, after: Duration) -> String {
    let qos_text = match qos {
        ImageQos::SensorData => {
            "best effort, keep last 5 (inputs.image_qos: sensor_data), which matches reliable \
             and best-effort publishers"
        }
        ImageQos::Reliable => {
            "reliable, keep last 5 (inputs.image_qos: reliable), which best-effort publishers \
             (most camera drivers) do not match: try inputs.image_qos: sensor_data"
        }
    };
    format!(
        "no message on camera topic {topic} ({type_name}) in the first {} s; the node \
         subscribes {qos_text}. Check what is published: `ros2 topic info -v {topic}` \
         (publishers and their QoS; the same ROS_DOMAIN_ID or domain_id), or point the node \
         at your camera with --remap {topic}:=/your/image_topic",
        after.as_secs()
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_warning_names_the_topic_the_qos_and_the_next_step() {
        let w = silence_warning(
            "/camera/image_raw",
            "sensor_msgs/msg/Image",
            ImageQos::Reliable,
            Duration::from_secs(5),
        );
        assert!(
            w.contains("/camera/image_raw (sensor_msgs/msg/Image)"),
            "{w}"
        );
        assert!(w.contains("in the first 5 s"), "{w}");
        assert!(w.contains("inputs.image_qos: sensor_data"), "{w}");
        assert!(w.contains("ros2 topic info -v /camera/image_raw"), "{w}");
        assert!(w.contains("--remap /camera/image_raw:="), "{w}");
    }

    #[test]
    fn only_topics_without_a_message_are_silent() {
        let mut watch = CameraWatch::default();
        let a = watch.watch("/a", "sensor_msgs/msg/Image");
        let _b = watch.watch("/b", "sensor_msgs/msg/CompressedImage");
        assert_eq!(watch.silent().len(), 2);
        a.store(true, Ordering::Relaxed);
        assert_eq!(watch.silent(), [("/b", "sensor_msgs/msg/CompressedImage")]);
    }
}
