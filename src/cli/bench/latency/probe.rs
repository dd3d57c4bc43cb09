//! The bench's ROS 2 subscriber, in a DDS participant of its own on loopback: the pose topic
//! and the rendered frames (each stamped with the camera frame it shows) become latency
//! samples as they arrive, the statuses tell the avatar revisions published.

use super::unix_ns;
use anyhow::{anyhow, Context, Result};
use futures::StreamExt;
use lhmpp::msgs::{BodyPose, Image, ReconstructionStatus, RosMessage};
use lhmpp::node::ros::ParticipantOptions;
use lhmpp::node::ros::{create_context, person_frame_topic, type_name, ResolvedTopics};
use ros2_client::qos::{History, QosProfile, Reliability};
use ros2_client::{Name, NodeName, NodeOptions};
use serde::de::DeserializeOwned;
use std::net::IpAddr;
use std::sync::mpsc;

/// Tracked persons whose frame topics are subscribed to (`person_0` ... ).
const TRACKED_IDS: usize = 16;

/// Where a latency was measured.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Stage {
    /// The pose read from the camera, received on the pose topic.
    Pose,
    /// A frame rendered in that pose, received on its frame topic.
    Frame,
    /// The live page's first frame drawn in that pose.
    Page,
}

impl Stage {
    /// Every stage, in the table's order.
    pub const ALL: [Stage; 3] = [Stage::Pose, Stage::Frame, Stage::Page];

    /// Its row label.
    pub fn label(self) -> &'static str {
        match self {
            Stage::Pose => "camera → pose received",
            Stage::Frame => "camera → rendered frame received",
            Stage::Page => "camera → page frame drawn",
        }
    }
}

/// One latency.
#[derive(Debug, Clone)]
pub struct Sample {
    /// Where.
    pub stage: Stage,
    /// Whose pose.
    pub person: String,
    /// The camera frame's stamp (ns since the epoch).
    pub stamp_ns: i64,
    /// Stamp → arrival (or draw), ms.
    pub latency_ms: f64,
}

/// What the subscriber saw.
pub enum Item {
    /// A latency.
    Sample(Sample),
    /// A status naming an avatar revision, received at `at_ns`.
    Revision {
        /// Person.
        person: String,
        /// Revision.
        revision: u32,
        /// Arrival, ns since the epoch.
        at_ns: i64,
    },
}

/// The subscriptions and the runtime their readers run on.
pub struct Probe {
    rx: mpsc::Receiver<Item>,
    /// Dropped before the runtime its spinner runs on.
    node: Option<ros2_client::Node>,
    runtime: Option<tokio::runtime::Runtime>,
}

/// Best effort (it matches reliable and best-effort writers alike), the last 16 kept.
fn qos() -> QosProfile {
    QosProfile::subscription_default()
        .history(History::KeepLast { depth: 16 })
        .reliability(Reliability::BestEffort)
}

impl Probe {
    /// Subscribes in `domain` to the pose, status and frame topics of `topics` (with several
    /// people, the frames of `person_0` to `person_15`).
    pub fn start(domain: u16, topics: &ResolvedTopics, people: u8) -> Result<Self> {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .context("tokio runtime")?;
        let context = create_context(&ParticipantOptions {
            domain_id: domain,
            only_networks: vec![IpAddr::from([127, 0, 0, 1])],
            socket_receive_buffer: 0,
        })?;
        let mut node = context
            .new_node(
                NodeName::new("/", "lhmpp_bench_latency").map_err(|e| anyhow!("{e:?}"))?,
                NodeOptions::new().enable_rosout(false),
            )
            .context("ROS 2 node lhmpp_bench_latency")?;
        let spinner = node.spinner().context("node spinner")?;
        runtime.spawn(async move {
            if let Err(e) = spinner.spin().await {
                tracing::warn!("bench spinner stopped: {e:?}");
            }
        });
        let (tx, rx) = mpsc::channel();
        let pose = topics
            .pose
            .clone()
            .ok_or_else(|| anyhow!("the node's config has no pose topic"))?;
        let poses = subscribe::<BodyPose>(&mut node, &pose)?;
        let t = tx.clone();
        runtime.spawn(read(poses, move |msg: BodyPose| {
            let stamp_ns = msg.header.stamp.as_nanos();
            let _ = t.send(Item::Sample(Sample {
                stage: Stage::Pose,
                person: msg.person_id,
                stamp_ns,
                latency_ms: (unix_ns() - stamp_ns) as f64 * 1e-6,
            }));
        }));
        let statuses = subscribe::<ReconstructionStatus>(&mut node, &topics.status)?;
        let t = tx.clone();
        runtime.spawn(read(statuses, move |msg: ReconstructionStatus| {
            if msg.revision > 0 {
                let _ = t.send(Item::Revision {
                    person: msg.person_id,
                    revision: msg.revision,
                    at_ns: unix_ns(),
                });
            }
        }));
        let frames: Vec<(String, String)> = if people > 1 {
            let prefix = topics.status.trim_end_matches("status");
            (0..TRACKED_IDS)
                .map(|k| {
                    let person = format!("person_{k}");
                    (
                        format!("{prefix}{}", person_frame_topic(&person, 0)),
                        person,
                    )
                })
                .collect()
        } else {
            let topic = topics
                .frames
                .first()
                .cloned()
                .ok_or_else(|| anyhow!("the node's config renders no frames"))?;
            vec![(topic, String::new())]
        };
        for (topic, person) in frames {
            let sub = subscribe::<Image>(&mut node, &topic)?;
            let t = tx.clone();
            runtime.spawn(read(sub, move |msg: Image| {
                let stamp_ns = msg.header.stamp.as_nanos();
                let _ = t.send(Item::Sample(Sample {
                    stage: Stage::Frame,
                    person: person.clone(),
                    stamp_ns,
                    latency_ms: (unix_ns() - stamp_ns) as f64 * 1e-6,
                }));
            }));
        }
        Ok(Self {
            rx,
            node: Some(node),
            runtime: Some(runtime),
        })
    }

    /// What arrived since the last call.
    pub fn drain(&self) -> Vec<Item> {
        self.rx.try_iter().collect()
    }
}

impl Drop for Probe {
    fn drop(&mut self) {
        drop(self.node.take());
        if let Some(r) = self.runtime.take() {
            r.shutdown_timeout(std::time::Duration::from_secs(2));
        }
    }
}

fn subscribe<M: RosMessage + DeserializeOwned + 'static>(
    node: &mut ros2_client::Node,
    topic: &str,
) -> Result<ros2_client::Subscription<M>> {
    let name = Name::parse(topic).map_err(|e| anyhow!("topic {topic}: {e:?}"))?;
    let t = node
        .create_topic(&name, type_name::<M>(), &qos())
        .with_context(|| format!("topic {topic}"))?;
    node.create_subscription::<M>(&t, Some(qos()))
        .with_context(|| format!("subscription to {topic}"))
}

/// Hands every message of `sub` to `each` until the subscription ends.
async fn read<M: RosMessage + DeserializeOwned + 'static>(
    sub: ros2_client::Subscription<M>,
    mut each: impl FnMut(M),
) {
    let stream = sub.async_stream();
    futures::pin_mut!(stream);
    while let Some(item) = stream.next().await {
        if let Ok((msg, _)) = item {
            each(msg);
        }
    }
}
