//! The receiving end shared by all subscription tasks: converts each message into an
//! [`InputEvent`](super::InputEvent), pushes it into the one bounded input queue, and counts and
//! reports (rate-limited, per topic) the messages that could not be used.

use crate::node::input_errors::InputErrors;
use crate::node::input_queue::QueueSender;
use futures::StreamExt;
use ros2_client::dds::{NodeLoggingHandle, RosoutRaw, Subscription};
use ros2_client::log::LogLevel;
use serde::de::DeserializeOwned;
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Per-topic counters of the input side.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct InputStats {
    /// Messages turned into events, per resolved topic.
    pub accepted: BTreeMap<String, u64>,
    /// Messages rejected (malformed or undecodable), per resolved topic.
    pub rejected: BTreeMap<String, u64>,
    /// Events dropped because the input queue was full.
    pub queue_dropped: u64,
}

#[derive(Debug)]
struct Counters {
    accepted: BTreeMap<String, u64>,
    errors: InputErrors,
}

/// Shared by the subscription tasks of one node.
pub(crate) struct InputSink<E> {
    queue: QueueSender<E>,
    counters: Arc<Mutex<Counters>>,
    start: Instant,
    rosout: Option<Arc<NodeLoggingHandle>>,
}

impl<E> Clone for InputSink<E> {
    fn clone(&self) -> Self {
        Self {
            queue: self.queue.clone(),
            counters: self.counters.clone(),
            start: self.start,
            rosout: self.rosout.clone(),
        }
    }
}

impl<E: Send + 'static> InputSink<E> {
    pub(crate) fn new(
        queue: QueueSender<E>,
        report_period: Duration,
        start: Instant,
        rosout: Option<NodeLoggingHandle>,
    ) -> Self {
        Self {
            queue,
            counters: Arc::new(Mutex::new(Counters {
                accepted: BTreeMap::new(),
                errors: InputErrors::new(report_period),
            })),
            start,
            rosout: rosout.map(Arc::new),
        }
    }

    /// Node clock: time since the node started.
    pub(crate) fn now(&self) -> Duration {
        self.start.elapsed()
    }

    fn accept(&self, topic: &str, event: E) {
        *self
            .counters
            .lock()
            .expect("input counters poisoned")
            .accepted
            .entry(topic.to_owned())
            .or_default() += 1;
        self.queue.send(event);
    }

    fn reject(&self, topic: &str, reason: &str) {
        let now = self.now();
        let line = self
            .counters
            .lock()
            .expect("input counters poisoned")
            .errors
            .record(topic, reason, now);
        if let Some(line) = line {
            match &self.rosout {
                // rosout_raw also forwards the line to `tracing`.
                Some(handle) => handle.rosout_raw(
                    ros2_client::builtin_interfaces::Time::now(),
                    LogLevel::Warn,
                    handle.base_name(),
                    &line,
                    file!(),
                    "InputSink::reject",
                    line!(),
                ),
                None => tracing::warn!("{line}"),
            }
        }
    }

    /// Snapshot of the counters.
    pub(crate) fn stats(&self) -> InputStats {
        let c = self.counters.lock().expect("input counters poisoned");
        InputStats {
            accepted: c.accepted.clone(),
            rejected: c.errors.counts().map(|(t, n)| (t.to_owned(), n)).collect(),
            queue_dropped: self.queue.dropped(),
        }
    }

    /// Spawns a task that reads `sub` until the node stops, converting each message with
    /// `convert(topic, message, arrival)`.
    pub(crate) fn spawn<M, F>(
        &self,
        topic: String,
        sub: Subscription<M>,
        convert: F,
    ) -> tokio::task::JoinHandle<()>
    where
        M: DeserializeOwned + Send + Sync + 'static,
        F: Fn(&str, M, Duration) -> Result<E, String> + Send + 'static,
    {
        tokio::spawn(read_subscription(self.clone(), topic, sub, convert))
    }
}

/// Reads `sub` until its stream ends or the task is aborted, feeding `sink`.
async fn read_subscription<E, M, F>(
    sink: InputSink<E>,
    topic: String,
    sub: Subscription<M>,
    convert: F,
) where
    E: Send + 'static,
    M: DeserializeOwned + Send + Sync + 'static,
    F: Fn(&str, M, Duration) -> Result<E, String> + Send + 'static,
{
    let stream = sub.async_stream();
    futures::pin_mut!(stream);
    while let Some(item) = stream.next().await {
        match item {
            Ok((msg, _info)) => match convert(&topic, msg, sink.now()) {
                Ok(event) => sink.accept(&topic, event),
                Err(reason) => sink.reject(&topic, &reason),
            },
            Err(e) => sink.reject(&topic, &format!("malformed message: {e}")),
        }
    }
    tracing::debug!(topic, "subscription stream ended");
}
