//! Bag recording of the node's topics: the configured inputs (images, compressed images,
//! camera infos, mask, pose, shape) and the node's outputs (avatar, status, rendered frames).
//!
//! [`record`] subscribes with ros2-client to every topic of a [`RecordTopic`] plan, writes each
//! message's CDR bytes to a [`BagWriter`] with the topic's type and QoS, closes and flushes the
//! open chunk at least every [`RecordOptions::flush_interval`] (so a killed recorder loses at
//! most about that much), logs a progress line every [`RecordOptions::progress_period`], and
//! finishes the bag (summary and footer) when the stop future resolves or the duration ends.
//!
//! ros2-client 0.12 hands subscribers typed messages, so the bytes written are the message
//! re-encoded with [`RosMessage::encode_cdr`] (little-endian CDR, the same bytes a ROS 2
//! publisher sends up to alignment padding). The QoS recorded is the one the recorder
//! subscribes with, which is the QoS the node uses on that topic.

use crate::bag::{self, BagError, BagWriter};
use crate::config::ImageQos;
use crate::msgs::{
    BodyPose, BodyShape, CameraInfo, CompactAvatar, CompressedImage, GaussianAvatar, Image,
    ReconstructionStatus, RosMessage,
};
use crate::node::names::split_fully_qualified;
use crate::node::ros::{
    create_context, frame_output_qos, image_input_qos, latched_output_qos, reliable_input_qos,
    ParticipantOptions, ResolvedTopics, RosError,
};
use futures::StreamExt;
use ros2_client::dds::Node;
use ros2_client::qos::{Durability, History, QosProfile, Reliability};
use ros2_client::{MessageTypeName, Name, NodeName, NodeOptions};
use std::collections::BTreeMap;
use std::future::Future;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use tokio::sync::mpsc;

/// Errors of a recording; each names the topic or bag concerned.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// `--topics` named a topic the config does not use.
    #[error("topic `{topic}` is not one of the node's topics ({known})")]
    UnknownTopic {
        /// The requested topic.
        topic: String,
        /// The topics that can be recorded, comma separated.
        known: String,
    },
    /// Nothing to record.
    #[error("no topics to record")]
    NoTopics,
    /// Setting up DDS failed.
    #[error(transparent)]
    Ros(#[from] RosError),
    /// Writing the bag failed.
    #[error(transparent)]
    Bag(#[from] BagError),
}

/// Message types the recorder knows how to subscribe to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RecordType {
    /// `sensor_msgs/msg/Image` (camera images, masks, rendered frames).
    Image,
    /// `sensor_msgs/msg/CompressedImage`.
    CompressedImage,
    /// `sensor_msgs/msg/CameraInfo`.
    CameraInfo,
    /// `lhmpp_msgs/msg/BodyPose`.
    BodyPose,
    /// `lhmpp_msgs/msg/BodyShape`.
    BodyShape,
    /// `lhmpp_msgs/msg/GaussianAvatar`.
    GaussianAvatar,
    /// `lhmpp_msgs/msg/CompactAvatar`.
    CompactAvatar,
    /// `lhmpp_msgs/msg/ReconstructionStatus`.
    ReconstructionStatus,
}

impl RecordType {
    /// Full ROS 2 type name.
    pub fn type_name(self) -> &'static str {
        match self {
            Self::Image => Image::TYPE_NAME,
            Self::CompressedImage => CompressedImage::TYPE_NAME,
            Self::CameraInfo => CameraInfo::TYPE_NAME,
            Self::BodyPose => BodyPose::TYPE_NAME,
            Self::BodyShape => BodyShape::TYPE_NAME,
            Self::GaussianAvatar => GaussianAvatar::TYPE_NAME,
            Self::CompactAvatar => CompactAvatar::TYPE_NAME,
            Self::ReconstructionStatus => ReconstructionStatus::TYPE_NAME,
        }
    }
}

/// One topic to record: resolved name, type and the QoS to subscribe (and record) with.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordTopic {
    /// Fully qualified topic name.
    pub name: String,
    /// Message type.
    pub kind: RecordType,
    /// Subscription QoS (the node's QoS on this topic).
    pub qos: QosProfile,
}

impl RecordTopic {
    /// The QoS as rosbag2 records it in `offered_qos_profiles`.
    pub fn bag_qos(&self) -> bag::QosProfile {
        bag_qos(&self.qos)
    }
}

/// rosbag2's view of a ros2-client QoS profile.
fn bag_qos(qos: &QosProfile) -> bag::QosProfile {
    bag::QosProfile {
        reliability: match qos.reliability {
            Reliability::BestEffort => bag::Reliability::BestEffort,
            _ => bag::Reliability::Reliable,
        },
        durability: match qos.durability {
            Durability::Volatile => bag::Durability::Volatile,
            _ => bag::Durability::TransientLocal,
        },
        depth: match qos.history {
            History::KeepLast { depth } => depth.max(1) as u32,
            History::KeepAll => 1000,
        },
    }
}

/// Every topic the node uses, with the QoS the node uses on it: inputs first (images, compressed
/// images, camera infos, masks, pose, shape), then outputs (avatar, compact avatar, status, rendered frames).
pub fn plan(topics: &ResolvedTopics, image_qos: ImageQos) -> Vec<RecordTopic> {
    let topic = |name: &str, kind, qos| RecordTopic {
        name: name.to_owned(),
        kind,
        qos,
    };
    let mut out = Vec::new();
    for t in &topics.images {
        out.push(topic(t, RecordType::Image, image_input_qos(image_qos)));
    }
    for t in &topics.compressed_images {
        out.push(topic(
            t,
            RecordType::CompressedImage,
            image_input_qos(image_qos),
        ));
    }
    for t in &topics.camera_infos {
        out.push(topic(t, RecordType::CameraInfo, reliable_input_qos()));
    }
    if let Some(t) = &topics.mask {
        out.push(topic(t, RecordType::Image, image_input_qos(image_qos)));
    }
    for (t, _) in &topics.camera_masks {
        out.push(topic(t, RecordType::Image, image_input_qos(image_qos)));
    }
    if let Some(t) = &topics.pose {
        out.push(topic(t, RecordType::BodyPose, reliable_input_qos()));
    }
    if let Some(t) = &topics.shape {
        out.push(topic(t, RecordType::BodyShape, reliable_input_qos()));
    }
    out.push(topic(
        &topics.avatar,
        RecordType::GaussianAvatar,
        latched_output_qos(),
    ));
    out.push(topic(
        &topics.compact_avatar,
        RecordType::CompactAvatar,
        latched_output_qos(),
    ));
    out.push(topic(
        &topics.status,
        RecordType::ReconstructionStatus,
        latched_output_qos(),
    ));
    for t in &topics.frames {
        // A best-effort reader matches the frame writers whatever `outputs.frame_qos` is.
        out.push(topic(
            t,
            RecordType::Image,
            frame_output_qos(crate::config::FrameQos::BestEffort),
        ));
    }
    out
}

/// Keeps the planned topics named in `wanted` (fully qualified names; empty keeps all).
pub fn select(plan: Vec<RecordTopic>, wanted: &[String]) -> Result<Vec<RecordTopic>, RecordError> {
    if wanted.is_empty() {
        return Ok(plan);
    }
    for w in wanted {
        if !plan.iter().any(|t| &t.name == w) {
            return Err(RecordError::UnknownTopic {
                topic: w.clone(),
                known: plan
                    .iter()
                    .map(|t| t.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            });
        }
    }
    Ok(plan
        .into_iter()
        .filter(|t| wanted.contains(&t.name))
        .collect())
}

/// How a recording runs.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordOptions {
    /// Close and flush the open chunk at least this often while messages arrive.
    pub flush_interval: Duration,
    /// Log a progress line (messages per topic) this often.
    pub progress_period: Duration,
    /// Stop after this long; `None`: only when the stop future resolves.
    pub duration: Option<Duration>,
}

impl Default for RecordOptions {
    fn default() -> Self {
        Self {
            flush_interval: Duration::from_secs(1),
            progress_period: Duration::from_secs(5),
            duration: None,
        }
    }
}

/// What a finished recording wrote.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RecordSummary {
    /// Messages written per topic (every planned topic listed, zeros included).
    pub per_topic: BTreeMap<String, u64>,
    /// Messages written in all.
    pub total: u64,
    /// How long the recording ran.
    pub elapsed: Duration,
}

/// One received message on its way to the bag.
struct Received {
    topic: usize,
    time_ns: u64,
    cdr: Vec<u8>,
}

fn unix_now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

fn ros_name(topic: &str) -> Result<Name, RosError> {
    let (ns, base) = split_fully_qualified(topic);
    Name::new(ns, base).map_err(|e| RosError::Create(format!("topic name {topic}: {e:?}")))
}

fn type_name<M: RosMessage>() -> MessageTypeName {
    let full = M::TYPE_NAME;
    let package = full.split('/').next().unwrap_or(full);
    let name = full.rsplit('/').next().unwrap_or(full);
    MessageTypeName::new(package, name)
}

/// Subscribes to `topic` as `M` and spawns a task that forwards every message's CDR bytes.
fn spawn_reader<M: RosMessage + Send + Sync + 'static>(
    node: &mut Node,
    index: usize,
    topic: &RecordTopic,
    tx: mpsc::UnboundedSender<Received>,
) -> Result<tokio::task::JoinHandle<()>, RosError> {
    let name = topic.name.clone();
    let t = node
        .create_topic(&ros_name(&name)?, type_name::<M>(), &topic.qos)
        .map_err(|e| RosError::Create(format!("topic {name}: {e}")))?;
    let sub = node
        .create_subscription::<M>(&t, Some(topic.qos.clone()))
        .map_err(|e| RosError::Create(format!("subscription to {name}: {e}")))?;
    Ok(tokio::spawn(async move {
        let stream = sub.async_stream();
        futures::pin_mut!(stream);
        while let Some(item) = stream.next().await {
            match item {
                Ok((msg, _info)) => {
                    let received = Received {
                        topic: index,
                        time_ns: unix_now_ns(),
                        cdr: msg.encode_cdr(),
                    };
                    if tx.send(received).is_err() {
                        break;
                    }
                }
                Err(e) => tracing::warn!("{name}: undecodable message not recorded: {e}"),
            }
        }
    }))
}

/// Records `topics` into `bag` until `stop` resolves or `opts.duration` ends, then finishes
/// the bag. Must run inside a multi-threaded tokio runtime.
pub async fn record(
    participant: &ParticipantOptions,
    topics: &[RecordTopic],
    mut bag: BagWriter,
    opts: &RecordOptions,
    stop: impl Future<Output = ()>,
) -> Result<RecordSummary, RecordError> {
    if topics.is_empty() {
        return Err(RecordError::NoTopics);
    }
    for t in topics {
        bag.add_topic(&t.name, t.kind.type_name(), &t.bag_qos())?;
    }
    let context = create_context(participant)?;
    let node_name = NodeName::new("/", &format!("lhmpp_record_{}", std::process::id()))
        .map_err(|e| RosError::Create(format!("recorder node: {e:?}")))?;
    let mut node = context
        .new_node(node_name, NodeOptions::new().enable_rosout(false))
        .map_err(|e| RosError::Create(format!("recorder node: {e:?}")))?;
    let (tx, mut rx) = mpsc::unbounded_channel();
    let mut tasks = Vec::new();
    for (i, t) in topics.iter().enumerate() {
        let tx = tx.clone();
        let task = match t.kind {
            RecordType::Image => spawn_reader::<Image>(&mut node, i, t, tx),
            RecordType::CompressedImage => spawn_reader::<CompressedImage>(&mut node, i, t, tx),
            RecordType::CameraInfo => spawn_reader::<CameraInfo>(&mut node, i, t, tx),
            RecordType::BodyPose => spawn_reader::<BodyPose>(&mut node, i, t, tx),
            RecordType::BodyShape => spawn_reader::<BodyShape>(&mut node, i, t, tx),
            RecordType::GaussianAvatar => spawn_reader::<GaussianAvatar>(&mut node, i, t, tx),
            RecordType::CompactAvatar => spawn_reader::<CompactAvatar>(&mut node, i, t, tx),
            RecordType::ReconstructionStatus => {
                spawn_reader::<ReconstructionStatus>(&mut node, i, t, tx)
            }
        }?;
        tasks.push(task);
    }
    drop(tx);
    let spinner = node
        .spinner()
        .map_err(|e| RosError::Create(format!("recorder spinner: {e:?}")))?;
    let spinner = tokio::spawn(async move {
        if let Err(e) = spinner.spin().await {
            tracing::error!("recorder spinner stopped: {e:?}");
        }
    });
    tracing::info!(
        "recording {} topics into {}: {}",
        topics.len(),
        bag.path().display(),
        topics
            .iter()
            .map(|t| t.name.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    );

    let started = Instant::now();
    let mut counts = vec![0u64; topics.len()];
    let mut total = 0u64;
    let mut flushed = 0u64;
    let mut flush_tick = tokio::time::interval(opts.flush_interval);
    let mut progress_tick = tokio::time::interval(opts.progress_period);
    progress_tick.tick().await; // the first tick is immediate
    let deadline = async {
        match opts.duration {
            Some(d) => tokio::time::sleep(d).await,
            None => std::future::pending().await,
        }
    };
    futures::pin_mut!(stop, deadline);
    let result: Result<(), RecordError> = loop {
        tokio::select! {
            _ = &mut stop => break Ok(()),
            _ = &mut deadline => break Ok(()),
            received = rx.recv() => match received {
                Some(m) => {
                    if let Err(e) = write(&mut bag, topics, &m) {
                        break Err(e);
                    }
                    counts[m.topic] += 1;
                    total += 1;
                }
                None => break Ok(()),
            },
            _ = flush_tick.tick() => {
                if total > flushed {
                    if let Err(e) = bag.flush() {
                        break Err(e.into());
                    }
                    flushed = total;
                }
            }
            _ = progress_tick.tick() => {
                log_progress(topics, &counts, total, flushed, started.elapsed());
            }
        }
    };
    // Shutdown in the order RosNode::shutdown explains: the readers first (aborted and
    // awaited), then the node (its Drop stops the spinner; calling stop_spinner as well
    // overfilled the one-slot stop channel: "Cannot notify spin task to stop: Full"), then the
    // participant.
    for task in &tasks {
        task.abort();
    }
    for task in tasks {
        let _ = task.await;
    }
    drop(node);
    if tokio::time::timeout(Duration::from_secs(2), spinner)
        .await
        .is_err()
    {
        tracing::warn!("recorder spinner did not stop within 2 s");
    }
    drop(context);
    result?;
    // Messages already received when the stop came are kept.
    while let Ok(m) = rx.try_recv() {
        write(&mut bag, topics, &m)?;
        counts[m.topic] += 1;
        total += 1;
    }
    let written = bag.finish()?;
    debug_assert_eq!(written, total);
    log_progress(topics, &counts, total, total, started.elapsed());
    Ok(RecordSummary {
        per_topic: topics
            .iter()
            .zip(&counts)
            .map(|(t, n)| (t.name.clone(), *n))
            .collect(),
        total,
        elapsed: started.elapsed(),
    })
}

fn write(bag: &mut BagWriter, topics: &[RecordTopic], m: &Received) -> Result<(), RecordError> {
    let t = &topics[m.topic];
    bag.write_raw(&t.name, t.kind.type_name(), m.time_ns, &m.cdr)?;
    Ok(())
}

/// One progress line: `recorded 12 messages in 3.0 s (flushed 10): /a 8, /b 4`.
fn log_progress(
    topics: &[RecordTopic],
    counts: &[u64],
    total: u64,
    flushed: u64,
    elapsed: Duration,
) {
    let per_topic = topics
        .iter()
        .zip(counts)
        .map(|(t, n)| format!("{} {n}", t.name))
        .collect::<Vec<_>>()
        .join(", ");
    tracing::info!(
        "recorded {total} messages in {:.1} s (flushed {flushed}): {per_topic}",
        elapsed.as_secs_f64()
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    fn topics() -> ResolvedTopics {
        ResolvedTopics {
            images: vec!["/cam0/image_raw".into()],
            compressed_images: vec!["/cam1/image_raw/compressed".into()],
            camera_infos: vec!["/cam0/camera_info".into()],
            mask: Some("/mask".into()),
            camera_masks: vec![("/cam0/mask".into(), "/cam0/image_raw".into())],
            pose: Some("/pose".into()),
            tf_inputs: Vec::new(),
            person_masks: vec![("/cam0/image_raw".into(), "/cam0/person_mask".into())],
            shape: Some("/shape".into()),
            avatar: "/avatar".into(),
            compact_avatar: "/avatar/compact".into(),
            status: "/status".into(),
            frames: vec!["/render/cam0/image_raw".into()],
            preview: "/avatar/points".into(),
            tf: "/tf".into(),
        }
    }

    #[test]
    fn plan_covers_inputs_and_outputs_with_the_nodes_qos() {
        let p = plan(&topics(), ImageQos::SensorData);
        let names: Vec<_> = p.iter().map(|t| t.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "/cam0/image_raw",
                "/cam1/image_raw/compressed",
                "/cam0/camera_info",
                "/mask",
                "/cam0/mask",
                "/pose",
                "/shape",
                "/avatar",
                "/avatar/compact",
                "/status",
                "/render/cam0/image_raw"
            ]
        );
        assert_eq!(p[0].kind.type_name(), "sensor_msgs/msg/Image");
        assert_eq!(p[0].bag_qos().reliability, bag::Reliability::BestEffort);
        assert_eq!(p[4].kind, RecordType::Image);
        assert_eq!(p[5].kind, RecordType::BodyPose);
        assert_eq!(p[5].bag_qos().reliability, bag::Reliability::Reliable);
        assert_eq!(p[6].kind, RecordType::BodyShape);
        assert_eq!(p[6].bag_qos().reliability, bag::Reliability::Reliable);
        let avatar = p[7].bag_qos();
        assert_eq!(avatar.durability, bag::Durability::TransientLocal);
        assert_eq!(avatar.depth, 1);
        assert_eq!(p[8].kind, RecordType::CompactAvatar);
        assert_eq!(p[8].bag_qos().durability, bag::Durability::TransientLocal);
        assert_eq!(p[10].bag_qos().reliability, bag::Reliability::BestEffort);
    }

    #[test]
    fn selecting_an_unknown_topic_names_it_and_the_known_ones() {
        let p = plan(&topics(), ImageQos::Reliable);
        let kept = select(p.clone(), &["/pose".into(), "/avatar".into()]).unwrap();
        assert_eq!(kept.len(), 2);
        let e = select(p, &["/nope".into()]).unwrap_err().to_string();
        assert!(e.contains("/nope") && e.contains("/cam0/image_raw"), "{e}");
    }
}
