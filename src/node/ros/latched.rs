//! Transient-local ("latched") outputs that stay bounded while nobody listens.
//!
//! RustDDS 0.15 keeps every sample of a reliable transient-local writer that has no matched
//! reader (up to its 8,192-sample backstop): with no reader, "acknowledged by all readers" is
//! sequence number zero, so its KeepLast trim never runs. A node publishing avatars (~700 KB
//! each), statuses and preview clouds with no subscriber grew by ~35 MB/min under load
//! (heaptrack: the retained CDR buffers of `GaussianAvatar` and `PointCloud2`).
//!
//! A [`LatchedPort`] therefore hands a message to DDS only while a reader is matched. While
//! none is, it keeps just the newest message itself, and a task checks every
//! [`MATCH_POLL`] for a reader; the held message is then published, so a late subscriber
//! still gets the latest avatar, status and cloud, as transient-local promises.

use super::ports::{OutputPort, PublishOutcome};
use super::RosError;
use ros2_client::dds::Node;
use serde::Serialize;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;
use tokio::runtime::Handle;
use tokio::task::JoinHandle;

/// How often a held message's task looks for a matched reader.
pub(crate) const MATCH_POLL: Duration = Duration::from_millis(100);

/// A transient-local output port that holds its newest message while no reader is matched.
pub(crate) struct LatchedPort<M: Serialize> {
    port: Arc<OutputPort<M>>,
    /// The node that created `port` (its matched-reader counts).
    node: Arc<std::sync::Mutex<Node>>,
    /// The newest message not yet handed to DDS (no reader was matched). Locked around every
    /// hand-off, so the waiter never publishes an older message after a newer one.
    held: Arc<Mutex<Option<M>>>,
    /// The task waiting for a reader to match, while a message is held.
    waiter: Mutex<Option<JoinHandle<()>>>,
    runtime: Handle,
}

/// Locks `m`, recovering the data of a poisoned lock (a panicked publisher leaves it valid).
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl<M: Serialize + Send + Sync + 'static> LatchedPort<M> {
    /// Wraps `port`, created by `node`; the waiting tasks run on `runtime`.
    pub(crate) fn new(
        port: OutputPort<M>,
        node: Arc<std::sync::Mutex<Node>>,
        runtime: Handle,
    ) -> Self {
        Self {
            port: Arc::new(port),
            node,
            held: Arc::new(Mutex::new(None)),
            waiter: Mutex::new(None),
            runtime,
        }
    }

    /// The port (topic, publisher, back-pressure count).
    pub(crate) fn port(&self) -> &OutputPort<M> {
        &self.port
    }

    /// Matched readers of the port's topic.
    pub(crate) fn subscribers(&self) -> usize {
        self.port.matched_readers(&self.node)
    }

    /// Publishes `msg` when a reader is matched; otherwise keeps it (replacing any older one)
    /// until one matches, and says so with [`PublishOutcome::Held`].
    pub(crate) fn publish(&self, msg: M) -> Result<PublishOutcome, RosError> {
        let mut held = lock(&self.held);
        if self.subscribers() > 0 {
            *held = None;
            return self.port.publish(msg);
        }
        *held = Some(msg);
        drop(held);
        let mut waiter = lock(&self.waiter);
        if waiter.as_ref().is_none_or(|w| w.is_finished()) {
            let (port, node) = (Arc::clone(&self.port), Arc::clone(&self.node));
            let held = Arc::clone(&self.held);
            *waiter = Some(self.runtime.spawn(async move {
                while port.matched_readers(&node) == 0 {
                    tokio::time::sleep(MATCH_POLL).await;
                }
                // Under the lock, so a newer message published meanwhile cannot go first.
                let mut held = lock(&held);
                if let Some(Err(e)) = held.take().map(|m| port.publish(m)) {
                    tracing::warn!("{e}");
                }
            }));
        }
        Ok(PublishOutcome::Held)
    }

    /// Stops the waiting task (before the node's endpoints are dropped); returns it so the
    /// caller can wait until it has ended and released the node.
    pub(crate) fn stop(&self) -> Option<JoinHandle<()>> {
        let waiter = lock(&self.waiter).take();
        if let Some(w) = &waiter {
            w.abort();
        }
        waiter
    }
}
