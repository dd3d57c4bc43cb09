//! Rendered-frame topics of tracked persons, `render/<person_id>/cam<i>/image_raw`, advertised
//! at each person's first frame. Tracked ids keep coming (`person_0`, `person_1`, ...), so only
//! the most recently used persons keep their publishers: memory stays bounded over a long run.

use super::ports::{OutputPort, PublishOutcome};
use super::{advertise, frame_output_qos, RosError};
use crate::config::FrameQos;
use crate::msgs::Image;
use crate::node::names::NameResolver;
use ros2_client::Node;
use std::collections::VecDeque;
use std::sync::Mutex;

/// The per-person frame publishers.
pub(crate) struct PersonFramePorts {
    names: NameResolver,
    qos: FrameQos,
    cameras: u32,
    /// Persons whose publishers are kept.
    kept: usize,
    /// Publishers by person, most recently used last.
    ports: Mutex<VecDeque<(String, Vec<OutputPort<Image>>)>>,
}

/// Topic of `person`'s frames from virtual camera `camera`, before namespace expansion.
pub fn person_frame_topic(person: &str, camera: usize) -> String {
    format!("render/{person}/cam{camera}/image_raw")
}

impl PersonFramePorts {
    /// Publishers for `cameras` virtual cameras per person, resolved by `names`, for the
    /// `kept` most recently rendered persons.
    pub(crate) fn new(names: NameResolver, qos: FrameQos, cameras: u32, kept: usize) -> Self {
        Self {
            names,
            qos,
            cameras,
            kept: kept.max(1),
            ports: Mutex::new(VecDeque::new()),
        }
    }

    /// Publishes `person`'s frame from virtual camera `camera`, advertising their topics first
    /// when needed.
    pub(crate) fn publish(
        &self,
        node: &Mutex<Node>,
        person: &str,
        camera: usize,
        msg: Image,
    ) -> Result<PublishOutcome, RosError> {
        let mut ports = self.ports.lock().unwrap_or_else(|e| e.into_inner());
        let at = match ports.iter().position(|(p, _)| p == person) {
            Some(at) => at,
            None => {
                let mut node = node.lock().unwrap_or_else(|e| e.into_inner());
                let made = (0..self.cameras as usize)
                    .map(|c| {
                        let topic = self.names.resolve(&person_frame_topic(person, c))?;
                        advertise(&mut node, &topic, frame_output_qos(self.qos))
                    })
                    .collect::<Result<Vec<_>, RosError>>()?;
                tracing::info!(
                    person,
                    cameras = made.len(),
                    "rendered-frame topics advertised"
                );
                ports.push_back((person.to_owned(), made));
                while ports.len() > self.kept {
                    if let Some((gone, _)) = ports.pop_front() {
                        tracing::debug!(person = gone, "rendered-frame topics retired");
                    }
                }
                ports.len() - 1
            }
        };
        let entry = ports.remove(at).expect("index found above");
        let result = match entry.1.get(camera) {
            Some(port) => port.publish(msg),
            None => Err(RosError::Publish {
                topic: person_frame_topic(person, camera),
                reason: format!("only {} virtual cameras are configured", self.cameras),
            }),
        };
        ports.push_back(entry);
        result
    }
}
