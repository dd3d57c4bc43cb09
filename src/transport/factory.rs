//! One iceoryx2 node per process: the factory of publishers and subscribers.

use iceoryx2::prelude::*;

use super::error::{iceoryx, ShmError};
use super::layout::PayloadKind;
use super::options::{avatar_service, event_service, frame_service, ShmOptions};
use super::publisher::ShmPublisher;
use super::subscriber::ShmSubscriber;

/// The iceoryx2 service flavour used throughout: inter-process, ports usable from any thread.
pub(crate) type Svc = ipc_threadsafe::Service;

/// An iceoryx2 node. Creating one also removes resources left by processes that died
/// (SIGKILL) without cleaning up, so a restarted publisher starts cleanly.
#[derive(Debug)]
pub struct ShmNode {
    node: Node<Svc>,
    name: String,
    options: ShmOptions,
}

impl ShmNode {
    /// Creates a node called `name` with the service sizing `options`. iceoryx2 installs no
    /// signal handlers (the embedding application owns SIGINT/SIGTERM). The first node of a
    /// process sets iceoryx2's own log level from `IOX2_LOG_LEVEL`, else to errors only.
    pub fn new(name: &str, options: ShmOptions) -> Result<Self, ShmError> {
        static LOG_LEVEL: std::sync::Once = std::sync::Once::new();
        LOG_LEVEL.call_once(|| set_log_level_from_env_or(LogLevel::Error));
        let node_name = NodeName::new(name).map_err(iceoryx(name, "node name"))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<Svc>()
            .map_err(iceoryx(name, "create node"))?;
        Ok(Self {
            node,
            name: name.to_owned(),
            options,
        })
    }

    /// The node name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The service sizing used by this node's ports.
    pub fn options(&self) -> &ShmOptions {
        &self.options
    }

    /// A publisher on `lhmpp/<person>/avatar`.
    pub fn avatar_publisher(&self, person: &str) -> Result<ShmPublisher, ShmError> {
        ShmPublisher::create(self, person, &avatar_service(person)?, PayloadKind::Avatar)
    }

    /// A publisher on `lhmpp/<person>/frame/<camera>`.
    pub fn frame_publisher(&self, person: &str, camera: &str) -> Result<ShmPublisher, ShmError> {
        ShmPublisher::create(
            self,
            person,
            &frame_service(person, camera)?,
            PayloadKind::Frame,
        )
    }

    /// A subscriber to `person`'s avatar and to the frames of each camera in `cameras`.
    pub fn subscriber(&self, person: &str, cameras: &[&str]) -> Result<ShmSubscriber, ShmError> {
        let mut services = vec![(avatar_service(person)?, PayloadKind::Avatar)];
        for camera in cameras {
            services.push((frame_service(person, camera)?, PayloadKind::Frame));
        }
        ShmSubscriber::create(self, &event_service(person)?, &services)
    }

    /// Opens (or creates) the publish-subscribe service `name` of `u64` slices.
    pub(crate) fn pubsub(
        &self,
        name: &str,
        kind: PayloadKind,
    ) -> Result<
        iceoryx2::service::port_factory::publish_subscribe::PortFactory<Svc, [u64], ()>,
        ShmError,
    > {
        let o = &self.options;
        let service_name = ServiceName::new(name).map_err(iceoryx(name, "service name"))?;
        self.node
            .service_builder(&service_name)
            // u64 elements give 8-byte alignment at 1 byte of memory per payload byte
            // (`payload_alignment(8)` on `[u8]` would reserve 8 bytes per byte).
            .publish_subscribe::<[u64]>()
            .enable_safe_overflow(true)
            .max_subscribers(o.max_subscribers)
            .max_publishers(o.max_publishers)
            .max_nodes(o.max_nodes)
            .subscriber_max_buffer_size(o.subscriber_buffer)
            .subscriber_max_borrowed_samples(o.subscriber_max_borrowed)
            .history_size(o.history(kind))
            .open_or_create()
            .map_err(iceoryx(name, "open publish-subscribe service"))
    }

    /// Opens (or creates) the event service `name`.
    pub(crate) fn events(
        &self,
        name: &str,
    ) -> Result<iceoryx2::service::port_factory::event::PortFactory<Svc>, ShmError> {
        let o = &self.options;
        let service_name = ServiceName::new(name).map_err(iceoryx(name, "service name"))?;
        self.node
            .service_builder(&service_name)
            .event()
            .max_listeners(o.max_subscribers)
            .max_notifiers(16)
            .max_nodes(o.max_nodes)
            .open_or_create()
            .map_err(iceoryx(name, "open event service"))
    }
}
