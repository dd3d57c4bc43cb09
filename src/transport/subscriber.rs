//! `ShmSubscriber`: receives a person's avatar and frame samples without copying, and waits
//! for them on the person's event listener, either blocking or from tokio through the
//! listener's file descriptor (`AsyncFd`), never by polling.

use std::os::fd::{AsRawFd, RawFd};
use std::sync::Arc;
use std::time::Duration;

use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use tokio::io::unix::AsyncFd;
use tokio::io::Interest;

use super::error::{iceoryx, ShmError};
use super::factory::{ShmNode, Svc};
use super::layout::{decode, Decoded, LayoutError, PayloadKind};

/// One received payload, still in shared memory; released when dropped.
#[derive(Debug)]
pub struct ShmSample {
    service: Arc<str>,
    kind: PayloadKind,
    sample: Sample<Svc, [u64], ()>,
}

impl ShmSample {
    /// The service it came from.
    pub fn service(&self) -> &str {
        &self.service
    }

    /// The kind of the service it came from.
    pub fn kind(&self) -> PayloadKind {
        self.kind
    }

    /// The raw payload bytes (header + arrays).
    pub fn bytes(&self) -> &[u8] {
        bytemuck::cast_slice(self.sample.payload())
    }

    /// Header fields and arrays borrowed from shared memory.
    pub fn decode(&self) -> Result<Decoded<'_>, LayoutError> {
        decode(self.bytes())
    }
}

struct Stream {
    service: Arc<str>,
    kind: PayloadKind,
    subscriber: Subscriber<Svc, [u64], ()>,
}

impl std::fmt::Debug for Stream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Stream")
            .field("service", &self.service)
            .field("kind", &self.kind)
            .finish_non_exhaustive()
    }
}

/// The listener's descriptor, borrowed for tokio's reactor (the listener owns it).
#[derive(Debug)]
struct ListenerFd(RawFd);

impl AsRawFd for ListenerFd {
    fn as_raw_fd(&self) -> RawFd {
        self.0
    }
}

/// Subscriber to the streams of one person, woken by that person's event service.
#[derive(Debug)]
pub struct ShmSubscriber {
    // Declared before `listener` so it deregisters before the descriptor closes.
    async_fd: Option<AsyncFd<ListenerFd>>,
    events: String,
    listener: Listener<Svc>,
    streams: Vec<Stream>,
    next: usize,
}

impl ShmSubscriber {
    pub(crate) fn create(
        node: &ShmNode,
        events: &str,
        services: &[(String, PayloadKind)],
    ) -> Result<Self, ShmError> {
        let listener = node
            .events(events)?
            .listener_builder()
            .create()
            .map_err(iceoryx(events, "create listener"))?;
        let mut streams = Vec::with_capacity(services.len());
        for (service, kind) in services {
            let subscriber = node
                .pubsub(service, *kind)?
                .subscriber_builder()
                .create()
                .map_err(iceoryx(service, "create subscriber"))?;
            streams.push(Stream {
                service: service.as_str().into(),
                kind: *kind,
                subscriber,
            });
        }
        Ok(Self {
            async_fd: None,
            events: events.to_owned(),
            listener,
            streams,
            next: 0,
        })
    }

    /// The services this subscriber reads, in order.
    pub fn services(&self) -> impl Iterator<Item = &str> {
        self.streams.iter().map(|s| &*s.service)
    }

    /// Takes the next waiting sample of any stream (round robin), or `None` if all are empty.
    pub fn try_receive(&mut self) -> Result<Option<ShmSample>, ShmError> {
        for _ in 0..self.streams.len() {
            let stream = &self.streams[self.next];
            self.next = (self.next + 1) % self.streams.len();
            let received = stream
                .subscriber
                .receive()
                .map_err(iceoryx(&stream.service, "receive"))?;
            if let Some(sample) = received {
                return Ok(Some(ShmSample {
                    service: stream.service.clone(),
                    kind: stream.kind,
                    sample,
                }));
            }
        }
        Ok(None)
    }

    /// Blocks until a publisher of this person notifies or `timeout` passes; true when woken
    /// by a notification. Drain with [`ShmSubscriber::try_receive`] before waiting again.
    pub fn wait(&self, timeout: Duration) -> Result<bool, ShmError> {
        let count = self
            .listener
            .timed_wait(|_| {}, timeout)
            .map_err(iceoryx(&self.events, "wait"))?;
        Ok(count > 0)
    }

    /// Waits without blocking the tokio runtime: the listener's socket is registered with the
    /// reactor, and the task sleeps until a notification arrives. Must be called inside a
    /// tokio runtime with I/O enabled. Drain with [`ShmSubscriber::try_receive`] afterwards.
    pub async fn wait_async(&mut self) -> Result<(), ShmError> {
        if self.async_fd.is_none() {
            // SAFETY: the descriptor stays open while `self.listener` lives, and `async_fd`
            // is dropped first (field order), so tokio never sees a closed or reused descriptor.
            let registered = unsafe {
                let fd = self.listener.file_descriptor().native_handle();
                AsyncFd::register_with_interest(ListenerFd(fd), Interest::READABLE)
            };
            let async_fd = registered.map_err(|e| self.io(e.into()))?;
            self.async_fd = Some(async_fd);
        }
        let Self {
            async_fd,
            listener,
            events,
            ..
        } = self;
        let async_fd = async_fd.as_ref().expect("registered above");
        loop {
            let mut guard = async_fd.readable().await.map_err(|source| ShmError::Io {
                service: events.clone(),
                source,
            })?;
            // Drains the socket, so clearing readiness afterwards loses no wake-up.
            let count = listener.try_wait(|_| {}).map_err(iceoryx(events, "wait"))?;
            guard.clear_ready();
            if count > 0 {
                return Ok(());
            }
        }
    }

    fn io(&self, source: std::io::Error) -> ShmError {
        ShmError::Io {
            service: self.events.clone(),
            source,
        }
    }
}
