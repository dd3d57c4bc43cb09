//! The node's ROS 2 endpoint on ros2-client 0.12.1 (RustDDS) and tokio.
//!
//! [`RosNode::start`] creates the DDS participant in the resolved domain, resolves every topic
//! name (namespace, `~/`, remapping), subscribes to the configured image, compressed-image,
//! camera-info, mask, body-pose and body-shape topics, and returns the receiving end of ONE
//! bounded queue ([`LiveInputs`]), which decodes image messages as they are taken and yields
//! [`InputEvent`]s. Bad messages are counted and reported per topic at most once per period;
//! they never stop the node. Outputs (avatar, rendered frames, status) are published through
//! the node; a full reliable send window is [`PublishOutcome::BackPressure`], and a
//! transient-local output without a reader keeps only its newest message ([`PublishOutcome::Held`]).
//!
//! ros2-client supports `rosout`: with [`RosNodeOptions::rosout`] the node's input-error
//! reports also go to `/rosout` (and always to `tracing`).

mod context;
mod latched;
mod live_inputs;
mod person_frames;
pub(crate) mod ports;
mod silent_cameras;
mod sink;

pub use context::{
    create_context, frame_output_qos, image_input_qos, latched_output_qos, reliable_input_qos,
    resolve_domain_id, ParticipantOptions,
};
pub use live_inputs::LiveInputs;
pub use person_frames::person_frame_topic;
pub use ports::{rgb8_image, OutputTopics, PublishOutcome};
pub use silent_cameras::{silence_warning, SILENT_CAMERA_WARNING};
pub use sink::InputStats;

use crate::config::{FrameQos, ImageQos, NodeConfig, PoseSource};
use crate::msgs::{
    BodyPose, BodyShape, CameraInfo, CompactAvatar, CompressedImage, GaussianAvatar, Image,
    PointCloud2, ReconstructionStatus, RosMessage, StdString, TFMessage,
};
use crate::node::input_queue::{bounded, OverflowPolicy};
use crate::node::inputs::{EncodedImage, ImageMessage, Incoming, InputEvent};
use crate::node::names::{split_fully_qualified, NameError, NameResolver};
use crate::splat::Gaussians;
use latched::LatchedPort;
use person_frames::PersonFramePorts;
use ports::OutputPort;
use ros2_client::dds::Node;
use ros2_client::qos::QosProfile;
use ros2_client::{MessageTypeName, Name, NodeName, NodeOptions};
use serde::de::DeserializeOwned;
use serde::Serialize;
use sink::InputSink;
use std::collections::BTreeMap;
use std::net::IpAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// A failure to set up or use the ROS 2 endpoint; each names what it was about.
#[derive(Debug, thiserror::Error)]
pub enum RosError {
    /// The domain id (config or `ROS_DOMAIN_ID`) is invalid.
    #[error("domain id: {0}")]
    DomainId(String),
    /// A topic name, namespace or remapping rule is invalid.
    #[error(transparent)]
    Name(#[from] NameError),
    /// Creating the participant, node, topic or endpoint failed.
    #[error("cannot create {0}")]
    Create(String),
    /// Publishing failed for a reason other than back-pressure.
    #[error("publish on {topic}: {reason}")]
    Publish {
        /// Resolved topic.
        topic: String,
        /// Middleware message.
        reason: String,
    },
}

/// Everything needed to start the endpoint.
#[derive(Debug, Clone, PartialEq)]
pub struct RosNodeOptions {
    /// Node name (`lhmpp`).
    pub node_name: String,
    /// Namespace (`/` for none).
    pub namespace: String,
    /// Participant: domain id, interfaces, socket buffers.
    pub participant: ParticipantOptions,
    /// Remapping, original name → new name (both may be relative).
    pub remap: BTreeMap<String, String>,
    /// sensor_msgs/Image camera topics.
    pub image_topics: Vec<String>,
    /// sensor_msgs/CompressedImage camera topics.
    pub compressed_image_topics: Vec<String>,
    /// sensor_msgs/CameraInfo topics (paired with image topics by position).
    pub camera_info_topics: Vec<String>,
    /// Optional mono8 mask topic shared by every camera.
    pub mask_topic: Option<String>,
    /// Per-camera mono8 mask topics, by position over image then compressed-image topics.
    pub mask_topics: Vec<String>,
    /// Optional BodyPose topic.
    pub pose_topic: Option<String>,
    /// Optional BodyShape topic.
    pub shape_topic: Option<String>,
    /// Subscribe to `/tf` and `/tf_static` (camera poses for reading the body shape).
    pub tf_inputs: bool,
    /// QoS of image and mask subscriptions.
    pub image_qos: ImageQos,
    /// Largest accepted image side (pixels).
    pub max_image_side: u32,
    /// Most messages per second taken from one input topic (0: no limit).
    pub max_rate_hz: f64,
    /// Capacity of the input queue.
    pub queue_capacity: usize,
    /// What the input queue drops when full.
    pub overflow: OverflowPolicy,
    /// Bad inputs are reported at most once per topic per this period.
    pub error_report_period: Duration,
    /// Output topics.
    pub outputs: OutputTopics,
    /// Reliability of the rendered-frame publishers.
    pub frame_qos: FrameQos,
    /// Rendered frames per tracked person (`render/<person_id>/cam<i>/image_raw`, made at
    /// their first frame), keeping this many persons' publishers; `None`: one person, on
    /// `outputs.frames`.
    pub person_frames: Option<usize>,
    /// Cluster heartbeats on `cluster/heartbeat` (std_msgs/String): this node's `(index,
    /// members)`; `None` without a cluster.
    pub cluster: Option<(u32, u32)>,
    /// TF frame of the preview cloud and its parent on `/tf`; `None` disables both.
    pub preview_frames: Option<(String, String)>,
    /// Publish each camera's person mask on its `person_mask` topic.
    pub person_masks: bool,
    /// Publish the pose read from the cameras on the pose topic (the node's own pose
    /// messages are not taken as input).
    pub camera_pose: bool,
    /// Also send input-error reports to `/rosout`.
    pub rosout: bool,
}

impl RosNodeOptions {
    /// Options from the node config; `remap` from the command line (`from:=to` already split),
    /// `ros_domain_id_env` the value of `ROS_DOMAIN_ID` if set.
    pub fn from_config(
        cfg: &NodeConfig,
        remap: BTreeMap<String, String>,
        ros_domain_id_env: Option<&str>,
    ) -> Result<Self, RosError> {
        let non_empty = |s: &str| (!s.trim().is_empty()).then(|| s.to_owned());
        Ok(Self {
            node_name: crate::config::NODE_NAME.into(),
            namespace: cfg.namespace.clone(),
            participant: ParticipantOptions {
                domain_id: resolve_domain_id(cfg.domain_id, ros_domain_id_env)?,
                only_networks: cfg
                    .dds_interfaces
                    .iter()
                    .filter_map(|a| a.parse().ok())
                    .collect(),
                socket_receive_buffer: 0,
            },
            remap,
            image_topics: cfg.inputs.image_topics.clone(),
            compressed_image_topics: cfg.inputs.compressed_image_topics.clone(),
            camera_info_topics: cfg.inputs.camera_info_topics.clone(),
            mask_topic: non_empty(&cfg.inputs.mask_topic),
            mask_topics: cfg.inputs.mask_topics.clone(),
            pose_topic: non_empty(&cfg.inputs.pose_topic),
            shape_topic: non_empty(&cfg.inputs.shape_topic),
            tf_inputs: cfg.perception.estimate_shape
                && !cfg.inputs.camera_info_topics.is_empty()
                && cfg.runs_perception(),
            image_qos: cfg.inputs.image_qos,
            max_image_side: cfg.inputs.max_image_side,
            max_rate_hz: cfg.inputs.max_rate_hz,
            queue_capacity: 32,
            overflow: OverflowPolicy::DropOldest,
            error_report_period: Duration::from_secs(5),
            outputs: OutputTopics::for_virtual_cameras(cfg.outputs.virtual_cameras),
            frame_qos: cfg.outputs.frame_qos,
            person_frames: cfg.tracking.enabled.then_some(2 * cfg.tracking.max_persons),
            cluster: (cfg.tracking.enabled && cfg.cluster.members > 1)
                .then_some((cfg.cluster.index, cfg.cluster.members)),
            preview_frames: (cfg.outputs.preview_rate_hz > 0.0).then(|| {
                (
                    cfg.outputs.preview_frame.clone(),
                    cfg.outputs.world_frame.clone(),
                )
            }),
            person_masks: cfg.outputs.masks && cfg.perception_finds_people(),
            camera_pose: cfg.outputs.camera_pose && cfg.inputs.pose_source != PoseSource::Walk,
            rosout: true,
        })
    }

    /// Restricts DDS to loopback (tests and single-host set-ups).
    pub fn loopback_only(mut self) -> Self {
        self.participant.only_networks = vec![IpAddr::from([127, 0, 0, 1])];
        self
    }
}

/// Fully qualified names of every topic the node uses.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ResolvedTopics {
    /// Image topics.
    pub images: Vec<String>,
    /// CompressedImage topics.
    pub compressed_images: Vec<String>,
    /// CameraInfo topics.
    pub camera_infos: Vec<String>,
    /// Mask topic shared by every camera.
    pub mask: Option<String>,
    /// Per-camera mask topics and the camera topic each one masks.
    pub camera_masks: Vec<(String, String)>,
    /// BodyPose topic.
    pub pose: Option<String>,
    /// Each camera topic and the topic of its person mask as perceived by the node
    /// (`<camera namespace>/person_mask`).
    pub person_masks: Vec<(String, String)>,
    /// BodyShape topic.
    pub shape: Option<String>,
    /// TF topics read for the cameras' poses (`/tf`, `/tf_static`; empty when not needed).
    pub tf_inputs: Vec<String>,
    /// GaussianAvatar topic.
    pub avatar: String,
    /// CompactAvatar topic.
    pub compact_avatar: String,
    /// ReconstructionStatus topic.
    pub status: String,
    /// Rendered-frame topics, one per virtual camera.
    pub frames: Vec<String>,
    /// PointCloud2 preview topic.
    pub preview: String,
    /// TF topic.
    pub tf: String,
}

impl ResolvedTopics {
    /// Resolves every configured topic against the namespace and remapping of `opts`
    /// (what the node subscribes to and publishes on; bag replay uses the same names).
    pub fn from_options(opts: &RosNodeOptions) -> Result<Self, RosError> {
        let names = NameResolver::new(&opts.namespace, &opts.node_name)?.with_map(&opts.remap)?;
        Self::resolve(opts, &names)
    }

    fn resolve(opts: &RosNodeOptions, names: &NameResolver) -> Result<Self, RosError> {
        let all = |v: &[String]| {
            v.iter()
                .map(|t| names.resolve(t))
                .collect::<Result<Vec<_>, _>>()
        };
        Ok(Self {
            images: all(&opts.image_topics)?,
            compressed_images: all(&opts.compressed_image_topics)?,
            camera_infos: all(&opts.camera_info_topics)?,
            camera_masks: all(&opts.mask_topics)?
                .into_iter()
                .zip(
                    all(&opts.image_topics)?
                        .into_iter()
                        .chain(all(&opts.compressed_image_topics)?),
                )
                .collect(),
            mask: opts
                .mask_topic
                .as_deref()
                .map(|t| names.resolve(t))
                .transpose()?,
            pose: opts
                .pose_topic
                .as_deref()
                .map(|t| names.resolve(t))
                .transpose()?,
            shape: opts
                .shape_topic
                .as_deref()
                .map(|t| names.resolve(t))
                .transpose()?,
            tf_inputs: if opts.tf_inputs {
                vec![names.resolve("/tf")?, names.resolve("/tf_static")?]
            } else {
                Vec::new()
            },
            person_masks: person_mask_topics(
                &all(&opts.image_topics)?
                    .into_iter()
                    .chain(all(&opts.compressed_image_topics)?)
                    .collect::<Vec<_>>(),
            ),
            avatar: names.resolve(&opts.outputs.avatar)?,
            compact_avatar: names.resolve(&opts.outputs.compact_avatar)?,
            status: names.resolve(&opts.outputs.status)?,
            frames: all(&opts.outputs.frames)?,
            preview: names.resolve(&opts.outputs.preview)?,
            tf: names.resolve(&opts.outputs.tf)?,
        })
    }
}

/// The running ROS 2 endpoint.
pub struct RosNode {
    /// Held so the DDS participant outlives the node's own endpoints (see `shutdown`).
    context: ros2_client::Context,
    node: Arc<Mutex<Node>>,
    topics: ResolvedTopics,
    sink: InputSink<Incoming>,
    avatar: LatchedPort<GaussianAvatar>,
    compact_avatar: LatchedPort<CompactAvatar>,
    status: LatchedPort<ReconstructionStatus>,
    frames: Vec<OutputPort<Image>>,
    person_frames: Option<PersonFramePorts>,
    /// The cluster heartbeat publisher and this node's `(index, members)`.
    heartbeat: Option<(OutputPort<StdString>, u32, u32)>,
    preview: Option<Preview>,
    /// Person-mask publishers by camera topic.
    masks: BTreeMap<String, OutputPort<Image>>,
    pose: Option<OutputPort<BodyPose>>,
    tasks: Vec<tokio::task::JoinHandle<()>>,
    spinner: tokio::task::JoinHandle<()>,
    start: Instant,
    domain_id: u16,
}

/// The preview cloud's publisher and its `/tf` publisher.
struct Preview {
    cloud: LatchedPort<PointCloud2>,
    tf: OutputPort<TFMessage>,
    frame: String,
    world: String,
}

/// `pkg/msg/Type` → ros2-client's (package, type) name.
pub fn type_name<M: RosMessage>() -> MessageTypeName {
    let full = M::TYPE_NAME;
    let package = full.split('/').next().unwrap_or(full);
    let name = full.rsplit('/').next().unwrap_or(full);
    MessageTypeName::new(package, name)
}

impl RosNode {
    /// Starts the endpoint; must be called inside a tokio runtime. Returns the node and the
    /// receiving end of its input queue (decoded events). Its clock ([`RosNode::clock`]) starts now.
    pub fn start(opts: &RosNodeOptions) -> Result<(Self, LiveInputs), RosError> {
        Self::start_with_clock(opts, Instant::now())
    }

    /// [`RosNode::start`] with the clock of the `arrival` fields counting from `origin`, so
    /// they compare with the caller's own clock of the same origin.
    pub fn start_with_clock(
        opts: &RosNodeOptions,
        origin: Instant,
    ) -> Result<(Self, LiveInputs), RosError> {
        let names = NameResolver::new(&opts.namespace, &opts.node_name)?.with_map(&opts.remap)?;
        let topics = ResolvedTopics::resolve(opts, &names)?;
        let context = create_context(&opts.participant)?;
        let node_name = NodeName::new(names.namespace(), &opts.node_name)
            .map_err(|e| RosError::Create(format!("node {}: {e:?}", opts.node_name)))?;
        let mut node = context
            .new_node(node_name, NodeOptions::new().enable_rosout(opts.rosout))
            .map_err(|e| RosError::Create(format!("node {}: {e:?}", opts.node_name)))?;
        let (tx, rx) = bounded(opts.queue_capacity, opts.overflow);
        let rosout = opts.rosout.then(|| node.logging_handle());
        let min_interval =
            (opts.max_rate_hz > 0.0).then(|| Duration::from_secs_f64(1.0 / opts.max_rate_hz));
        let sink = InputSink::new(tx, opts.error_report_period, origin, rosout, min_interval);
        let inputs = LiveInputs::new(rx, sink.rejecter());

        let mut tasks = Vec::new();
        let max_side = opts.max_image_side;
        let image_qos = image_input_qos(opts.image_qos);
        let mut cameras = silent_cameras::CameraWatch::default();
        for topic in &topics.images {
            let sub = subscribe::<Image>(&mut node, topic, image_qos.clone())?;
            let seen = cameras.watch(topic, "sensor_msgs/msg/Image");
            tasks.push(sink.spawn(topic.clone(), sub, move |t, m, a| {
                seen.store(true, std::sync::atomic::Ordering::Relaxed);
                Ok(encoded(t, a, max_side, ImageMessage::Raw(m)))
            }));
        }
        for topic in &topics.compressed_images {
            let sub = subscribe::<CompressedImage>(&mut node, topic, image_qos.clone())?;
            let seen = cameras.watch(topic, "sensor_msgs/msg/CompressedImage");
            tasks.push(sink.spawn(topic.clone(), sub, move |t, m, a| {
                seen.store(true, std::sync::atomic::Ordering::Relaxed);
                Ok(encoded(t, a, max_side, ImageMessage::Compressed(m)))
            }));
        }
        tasks.push(cameras.spawn(SILENT_CAMERA_WARNING, opts.image_qos));
        for (camera_index, topic) in topics.camera_infos.iter().enumerate() {
            let sub = subscribe::<CameraInfo>(&mut node, topic, reliable_input_qos())?;
            tasks.push(sink.spawn(topic.clone(), sub, move |t, info, arrival| {
                Ok(Incoming::Event(InputEvent::CameraInfo {
                    topic: t.to_owned(),
                    camera_index,
                    arrival,
                    info: Box::new(info),
                }))
            }));
        }
        if let Some(topic) = &topics.mask {
            let sub = subscribe::<Image>(&mut node, topic, image_qos.clone())?;
            tasks.push(sink.spawn(topic.clone(), sub, move |t, image, a| {
                let message = ImageMessage::Mask {
                    camera: None,
                    image,
                };
                Ok(encoded(t, a, max_side, message))
            }));
        }
        for (topic, camera) in &topics.camera_masks {
            let sub = subscribe::<Image>(&mut node, topic, image_qos.clone())?;
            let camera = camera.clone();
            tasks.push(sink.spawn(topic.clone(), sub, move |t, image, a| {
                let message = ImageMessage::Mask {
                    camera: Some(camera.clone()),
                    image,
                };
                Ok(encoded(t, a, max_side, message))
            }));
        }
        // The pose read from the cameras goes out on the pose topic; created before the
        // subscription so that the subscription can skip the node's own messages.
        let pose_out = match (&topics.pose, opts.camera_pose) {
            (Some(topic), true) => Some(advertise::<BodyPose>(
                &mut node,
                topic,
                frame_output_qos(FrameQos::Reliable),
            )?),
            _ => None,
        };
        if let Some(topic) = &topics.pose {
            let sub = subscribe::<BodyPose>(&mut node, topic, reliable_input_qos())?;
            let convert = |t: &str, pose, arrival| {
                Ok(Incoming::Event(InputEvent::BodyPose {
                    topic: t.to_owned(),
                    arrival,
                    pose: Box::new(pose),
                }))
            };
            tasks.push(match &pose_out {
                Some(own) => {
                    sink.spawn_from_others(topic.clone(), sub, own.publisher.gid(), convert)
                }
                None => sink.spawn(topic.clone(), sub, convert),
            });
        }
        let heartbeat = match opts.cluster {
            Some((index, members)) => {
                let topic = names.resolve(HEARTBEAT_TOPIC)?;
                let port = advertise::<StdString>(&mut node, &topic, reliable_input_qos())?;
                let sub = subscribe::<StdString>(&mut node, &topic, reliable_input_qos())?;
                tasks.push(sink.spawn_from_others(
                    topic.clone(),
                    sub,
                    port.publisher.gid(),
                    |_, msg: StdString, arrival| {
                        let (index, members) = parse_heartbeat(&msg.data)?;
                        Ok(Incoming::Event(InputEvent::ClusterHeartbeat {
                            index,
                            members,
                            arrival,
                        }))
                    },
                ));
                Some((port, index, members))
            }
            None => None,
        };
        for topic in &topics.tf_inputs {
            // `/tf_static` is latched: a transient-local reader gets the transforms sent before
            // it started.
            let qos = if topic.ends_with("_static") {
                latched_output_qos()
            } else {
                reliable_input_qos()
            };
            let sub = subscribe::<TFMessage>(&mut node, topic, qos)?;
            tasks.push(sink.spawn(topic.clone(), sub, |t, msg: TFMessage, _| {
                Ok(Incoming::Event(InputEvent::Transforms {
                    topic: t.to_owned(),
                    transforms: msg.transforms,
                }))
            }));
        }
        if let Some(topic) = &topics.shape {
            let sub = subscribe::<BodyShape>(&mut node, topic, reliable_input_qos())?;
            tasks.push(sink.spawn(topic.clone(), sub, |t, shape, arrival| {
                Ok(Incoming::Event(InputEvent::BodyShape {
                    topic: t.to_owned(),
                    arrival,
                    shape: Box::new(shape),
                }))
            }));
        }

        let avatar = advertise(&mut node, &topics.avatar, latched_output_qos())?;
        let compact_avatar = advertise(&mut node, &topics.compact_avatar, latched_output_qos())?;
        let status = advertise(&mut node, &topics.status, latched_output_qos())?;
        let frames = topics
            .frames
            .iter()
            .map(|t| advertise(&mut node, t, frame_output_qos(opts.frame_qos)))
            .collect::<Result<Vec<_>, _>>()?;
        // Transient local: RViz2 / Foxglove opened later get the last cloud at once;
        // a reliable + transient-local writer matches every kind of subscriber.
        let preview = match &opts.preview_frames {
            Some((frame, world)) => Some((
                advertise(&mut node, &topics.preview, latched_output_qos())?,
                advertise(&mut node, &topics.tf, frame_output_qos(FrameQos::Reliable))?,
                frame.clone(),
                world.clone(),
            )),
            None => None,
        };

        let masks = if opts.person_masks {
            topics
                .person_masks
                .iter()
                .map(|(camera, topic)| {
                    let port = advertise(&mut node, topic, frame_output_qos(FrameQos::Reliable))?;
                    Ok((camera.clone(), port))
                })
                .collect::<Result<BTreeMap<_, _>, RosError>>()?
        } else {
            BTreeMap::new()
        };

        let spinner = node
            .spinner()
            .map_err(|e| RosError::Create(format!("spinner: {e:?}")))?;
        let spinner = tokio::spawn(async move {
            if let Err(e) = spinner.spin().await {
                tracing::error!("ROS 2 spinner stopped: {e:?}");
            }
        });
        let node = Arc::new(Mutex::new(node));
        let person_frames = opts.person_frames.map(|kept| {
            PersonFramePorts::new(
                names.clone(),
                opts.frame_qos,
                opts.outputs.frames.len() as u32,
                kept,
            )
        });
        let runtime = tokio::runtime::Handle::current();
        let avatar = LatchedPort::new(avatar, Arc::clone(&node), runtime.clone());
        let compact_avatar = LatchedPort::new(compact_avatar, Arc::clone(&node), runtime.clone());
        let status = LatchedPort::new(status, Arc::clone(&node), runtime.clone());
        let preview = preview.map(|(cloud, tf, frame, world)| Preview {
            cloud: LatchedPort::new(cloud, Arc::clone(&node), runtime),
            tf,
            frame,
            world,
        });
        tracing::info!(
            domain_id = opts.participant.domain_id,
            namespace = names.namespace(),
            ?topics,
            "ROS 2 node started"
        );
        Ok((
            Self {
                context,
                node,
                topics,
                sink,
                avatar,
                compact_avatar,
                status,
                frames,
                person_frames,
                heartbeat,
                preview,
                masks,
                pose: pose_out,
                tasks,
                spinner,
                start: origin,
                domain_id: opts.participant.domain_id,
            },
            inputs,
        ))
    }

    /// Resolved topic names.
    pub fn topics(&self) -> &ResolvedTopics {
        &self.topics
    }

    /// DDS domain in use.
    pub fn domain_id(&self) -> u16 {
        self.domain_id
    }

    /// Node clock: time since start (the clock of `arrival` fields).
    pub fn clock(&self) -> Duration {
        self.start.elapsed()
    }

    /// Input counters: accepted and rejected messages per topic, queue overflow drops.
    pub fn input_stats(&self) -> InputStats {
        self.sink.stats()
    }

    /// Publishes a GaussianAvatar (reliable, transient-local).
    pub fn publish_avatar(&self, msg: GaussianAvatar) -> Result<PublishOutcome, RosError> {
        self.avatar.publish(msg)
    }

    /// Publishes a CompactAvatar (reliable, transient-local).
    pub fn publish_compact_avatar(&self, msg: CompactAvatar) -> Result<PublishOutcome, RosError> {
        self.compact_avatar.publish(msg)
    }

    /// Publishes a ReconstructionStatus (reliable, transient-local).
    pub fn publish_status(&self, msg: ReconstructionStatus) -> Result<PublishOutcome, RosError> {
        self.status.publish(msg)
    }

    /// Says this cluster member is alive (nothing without a cluster).
    pub fn publish_heartbeat(&self) -> Result<(), RosError> {
        if let Some((port, index, members)) = &self.heartbeat {
            port.publish(StdString {
                data: heartbeat_text(*index, *members),
            })?;
        }
        Ok(())
    }

    /// Publishes a rendered frame of `person` from virtual camera `camera` (`outputs.frame_qos`):
    /// on `render/<person>/cam<i>/image_raw` when persons are tracked, else on the camera's
    /// topic.
    pub fn publish_person_frame(
        &self,
        person: &str,
        camera: usize,
        msg: Image,
    ) -> Result<PublishOutcome, RosError> {
        match &self.person_frames {
            Some(ports) => ports.publish(&self.node, person, camera, msg),
            None => self.publish_frame(camera, msg),
        }
    }

    /// Publishes a rendered frame on virtual camera `camera`'s topic (`outputs.frame_qos`).
    pub fn publish_frame(&self, camera: usize, msg: Image) -> Result<PublishOutcome, RosError> {
        let port = self.frames.get(camera).ok_or_else(|| RosError::Publish {
            topic: format!("render camera {camera}"),
            reason: format!("only {} virtual cameras are configured", self.frames.len()),
        })?;
        port.publish(msg)
    }

    /// Publishes the avatar preview cloud of `posed` Gaussians and its `/tf` transform
    /// (nothing when the preview is disabled).
    pub fn publish_preview(&self, posed: &Gaussians, stamp_ns: i64) -> Result<(), RosError> {
        let Some(p) = &self.preview else {
            return Ok(());
        };
        p.tf.publish(crate::node::preview::preview_transform(
            stamp_ns, &p.world, &p.frame,
        ))?;
        p.cloud.publish(crate::node::preview::preview_cloud(
            posed, stamp_ns, &p.frame,
        ))?;
        Ok(())
    }

    /// Publishes camera `camera`'s (resolved topic) person mask when a reader is matched to
    /// its `person_mask` topic; whether it was handed to DDS.
    pub fn publish_mask(&self, camera: &str, msg: Image) -> Result<bool, RosError> {
        let Some(port) = self.masks.get(camera) else {
            return Ok(false);
        };
        if port.matched_readers(&self.node) == 0 {
            return Ok(false);
        }
        Ok(port.publish(msg)? == PublishOutcome::Sent)
    }

    /// Publishes the pose read from the cameras on the pose topic (nothing when
    /// `outputs.camera_pose` is off).
    pub fn publish_pose(&self, msg: BodyPose) -> Result<(), RosError> {
        if let Some(port) = &self.pose {
            port.publish(msg)?;
        }
        Ok(())
    }

    /// Matched readers of the avatar topic.
    pub fn avatar_subscribers(&self) -> usize {
        self.avatar.subscribers()
    }

    /// Matched readers of virtual camera `camera`'s frame topic.
    pub fn frame_subscribers(&self, camera: usize) -> usize {
        self.frames
            .get(camera)
            .map_or(0, |p| p.matched_readers(&self.node))
    }

    /// Publishes refused by a full send window so far (all outputs).
    pub fn back_pressure_count(&self) -> u64 {
        self.avatar.port().back_pressure()
            + self.compact_avatar.port().back_pressure()
            + self.status.port().back_pressure()
            + self.frames.iter().map(|p| p.back_pressure()).sum::<u64>()
    }

    /// Stops the subscription tasks and the spinner, in the order that lets RustDDS remove
    /// every reader and writer while its event loop still runs: subscriptions (awaited), then
    /// publishers, then the node, whose `Drop` signals the spinner to stop, which is awaited.
    ///
    /// Calling `Node::stop_spinner` first, as this did before, logged "ERROR ros2_client::node:
    /// Cannot notify spin task to stop: Full(..)": the stop channel holds one message, and
    /// `Node::drop` sends a second before the spinner has taken the first. Dropping endpoints
    /// after the participant logged "Cannot remove Reader/Writer ... Disconnected" (the node's
    /// own rosout and parameter-event writers are dropped after its context field, so the
    /// participant must be held here until the node is gone).
    /// Call it outside async code, or from a multi-threaded runtime's task (it waits up to 2 s
    /// with blocking sleeps for the runtime's other workers to finish the tasks).
    pub fn shutdown(self) {
        let Self {
            context,
            node,
            sink,
            avatar,
            compact_avatar,
            status,
            frames,
            preview,
            masks,
            pose,
            tasks,
            spinner,
            ..
        } = self;
        let deadline = Instant::now() + Duration::from_secs(2);
        let wait = |task: &tokio::task::JoinHandle<()>| {
            while !task.is_finished() && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(5));
            }
        };
        for task in &tasks {
            task.abort();
        }
        tasks.iter().for_each(wait);
        let waiters = [avatar.stop(), compact_avatar.stop(), status.stop()]
            .into_iter()
            .chain(preview.as_ref().map(|p| p.cloud.stop()))
            .flatten()
            .collect::<Vec<_>>();
        waiters.iter().for_each(wait);
        drop((
            sink,
            avatar,
            compact_avatar,
            status,
            frames,
            preview,
            masks,
            pose,
        ));
        drop(node);
        wait(&spinner);
        if !spinner.is_finished() {
            tracing::warn!("ROS 2 spinner did not stop within 2 s");
            spinner.abort();
        }
        // Last: the participant, once nothing of the node needs its event loop.
        drop(context);
    }
}

/// `<camera namespace>/person_mask` for each resolved camera topic (a trailing `/compressed`
/// is dropped first: `/cam0/image_raw/compressed` → `/cam0/person_mask`); cameras that would
/// share one take `<camera topic>/person_mask` instead.
fn person_mask_topics(cameras: &[String]) -> Vec<(String, String)> {
    let by_namespace = |camera: &str| {
        let base = camera.strip_suffix("/compressed").unwrap_or(camera);
        let parent = base.rsplit_once('/').map_or("", |(p, _)| p);
        format!("{parent}/person_mask")
    };
    let names: Vec<String> = cameras.iter().map(|c| by_namespace(c)).collect();
    cameras
        .iter()
        .zip(&names)
        .map(|(camera, name)| {
            let shared = names.iter().filter(|n| *n == name).count() > 1;
            let topic = if shared {
                format!("{camera}/person_mask")
            } else {
                name.clone()
            };
            (camera.clone(), topic)
        })
        .collect()
}

/// An image message of topic `t` queued for decoding when taken.
fn encoded(t: &str, arrival: Duration, max_side: u32, message: ImageMessage) -> Incoming {
    Incoming::Image(Box::new(EncodedImage {
        topic: t.to_owned(),
        arrival,
        max_side,
        message,
    }))
}

fn ros_name(topic: &str) -> Result<Name, RosError> {
    let (ns, base) = split_fully_qualified(topic);
    Name::new(ns, base).map_err(|e| RosError::Create(format!("topic name {topic}: {e:?}")))
}

fn subscribe<M: RosMessage + DeserializeOwned + 'static>(
    node: &mut Node,
    topic: &str,
    qos: QosProfile,
) -> Result<ros2_client::dds::Subscription<M>, RosError> {
    let t = node
        .create_topic(&ros_name(topic)?, type_name::<M>(), &qos)
        .map_err(|e| RosError::Create(format!("topic {topic}: {e}")))?;
    node.create_subscription::<M>(&t, Some(qos))
        .map_err(|e| RosError::Create(format!("subscription to {topic}: {e}")))
}

/// The cluster members' heartbeat topic (std_msgs/String), relative to the namespace.
pub const HEARTBEAT_TOPIC: &str = "cluster/heartbeat";

/// A heartbeat's text: `lhmpp cluster member <index> of <members>`.
pub fn heartbeat_text(index: u32, members: u32) -> String {
    format!("lhmpp cluster member {index} of {members}")
}

/// `(index, members)` of a heartbeat's text.
pub fn parse_heartbeat(text: &str) -> Result<(u32, u32), String> {
    let bad = || format!("`{text}` is not `lhmpp cluster member <index> of <members>`");
    let rest = text.strip_prefix("lhmpp cluster member ").ok_or_else(bad)?;
    let (index, members) = rest.split_once(" of ").ok_or_else(bad)?;
    let (index, members): (u32, u32) = (
        index.trim().parse().map_err(|_| bad())?,
        members.trim().parse().map_err(|_| bad())?,
    );
    if index >= members {
        return Err(bad());
    }
    Ok((index, members))
}

fn advertise<M: RosMessage + Serialize>(
    node: &mut Node,
    topic: &str,
    qos: QosProfile,
) -> Result<OutputPort<M>, RosError> {
    let t = node
        .create_topic(&ros_name(topic)?, type_name::<M>(), &qos)
        .map_err(|e| RosError::Create(format!("topic {topic}: {e}")))?;
    let publisher = node
        .create_publisher::<M>(&t, Some(qos))
        .map_err(|e| RosError::Create(format!("publisher on {topic}: {e}")))?;
    Ok(OutputPort::new(topic.to_owned(), publisher))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> NodeConfig {
        let mut cfg = NodeConfig {
            namespace: "/robot".into(),
            domain_id: 12,
            ..NodeConfig::default()
        };
        cfg.inputs.image_topics = vec!["front/image_raw".into(), "/abs/cam".into()];
        cfg.inputs.camera_info_topics = vec!["front/camera_info".into()];
        cfg.inputs.mask_topic = String::new();
        cfg.outputs.virtual_cameras = 2;
        cfg
    }

    #[test]
    fn topics_resolve_in_the_namespace_and_follow_remapping() {
        let remap = BTreeMap::from([
            (
                "front/image_raw".to_string(),
                "/cameras/front/color".to_string(),
            ),
            ("avatar".to_string(), "/avatars/person_0".to_string()),
        ]);
        let opts = RosNodeOptions::from_config(&config(), remap, None).unwrap();
        assert_eq!(opts.participant.domain_id, 12);
        let names = NameResolver::new(&opts.namespace, &opts.node_name)
            .unwrap()
            .with_map(&opts.remap)
            .unwrap();
        let t = ResolvedTopics::resolve(&opts, &names).unwrap();
        assert_eq!(t.images, vec!["/cameras/front/color", "/abs/cam"]);
        assert_eq!(t.camera_infos, vec!["/robot/front/camera_info"]);
        assert_eq!(t.mask, None);
        assert!(t.camera_masks.is_empty());
        assert_eq!(t.pose.as_deref(), Some("/lhmpp/body_pose"));
        assert_eq!(t.shape, None, "the shape topic is off by default");
        assert_eq!(t.avatar, "/avatars/person_0");
        assert_eq!(t.compact_avatar, "/robot/avatar/compact");
        assert_eq!(t.status, "/robot/status");
        assert_eq!(
            t.frames,
            vec![
                "/robot/render/cam0/image_raw",
                "/robot/render/cam1/image_raw"
            ]
        );
    }

    #[test]
    fn person_masks_go_next_to_their_camera_unless_two_would_share_a_topic() {
        let t = |v: &[&str]| {
            person_mask_topics(&v.iter().map(|s| s.to_string()).collect::<Vec<_>>())
                .into_iter()
                .map(|(_, m)| m)
                .collect::<Vec<_>>()
        };
        assert_eq!(
            t(&["/cam0/image_raw", "/cam1/image_raw/compressed"]),
            ["/cam0/person_mask", "/cam1/person_mask"]
        );
        assert_eq!(
            t(&["/image", "/image2"]),
            ["/image/person_mask", "/image2/person_mask"]
        );
    }

    #[test]
    fn per_camera_masks_pair_with_cameras_by_position() {
        let mut cfg = config();
        cfg.inputs.compressed_image_topics = vec!["side/compressed".into()];
        cfg.inputs.mask_topics = vec!["front/mask".into(), "/abs/mask".into(), "side/mask".into()];
        let opts = RosNodeOptions::from_config(&cfg, BTreeMap::new(), None).unwrap();
        let names = NameResolver::new(&opts.namespace, &opts.node_name).unwrap();
        let t = ResolvedTopics::resolve(&opts, &names).unwrap();
        let pair = |m: &str, c: &str| (m.to_string(), c.to_string());
        assert_eq!(
            t.camera_masks,
            vec![
                pair("/robot/front/mask", "/robot/front/image_raw"),
                pair("/abs/mask", "/abs/cam"),
                pair("/robot/side/mask", "/robot/side/compressed"),
            ]
        );
    }

    #[test]
    fn domain_minus_one_reads_ros_domain_id() {
        let cfg = NodeConfig {
            domain_id: -1,
            ..config()
        };
        let opts = RosNodeOptions::from_config(&cfg, BTreeMap::new(), Some("42")).unwrap();
        assert_eq!(opts.participant.domain_id, 42);
        let e = RosNodeOptions::from_config(&cfg, BTreeMap::new(), Some("x")).unwrap_err();
        assert!(e.to_string().contains("ROS_DOMAIN_ID"), "{e}");
    }

    #[test]
    fn bad_topic_names_fail_before_any_dds_entity_is_created() {
        let mut cfg = config();
        cfg.inputs.image_topics = vec!["bad topic".into()];
        let opts = RosNodeOptions::from_config(&cfg, BTreeMap::new(), None).unwrap();
        let names = NameResolver::new(&opts.namespace, &opts.node_name).unwrap();
        let e = ResolvedTopics::resolve(&opts, &names).unwrap_err();
        assert!(e.to_string().contains("bad topic"), "{e}");
    }

    #[test]
    fn message_type_names_split_into_package_and_type() {
        let t = type_name::<Image>();
        assert_eq!((t.package_name(), t.type_name()), ("sensor_msgs", "Image"));
        let t = type_name::<GaussianAvatar>();
        assert_eq!(
            (t.package_name(), t.type_name()),
            ("lhmpp_msgs", "GaussianAvatar")
        );
    }
}
