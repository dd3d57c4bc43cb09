//! The receiving end shared by all subscription tasks: converts each message into an
//! [`InputEvent`](crate::node::inputs::InputEvent), pushes it into the one bounded input
//! queue, and counts and reports (rate-limited, per topic) the messages that could not be used.

use crate::node::input_errors::InputErrors;
use crate::node::input_queue::QueueSender;
use crate::node::rejections::{RejectReason, Rejections};
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
    /// The same rejections by reason (`cdr`: does not deserialize; `image`: unusable image).
    pub rejections: Rejections,
    /// Events dropped because the input queue was full.
    pub queue_dropped: u64,
}

#[derive(Debug)]
struct Counters {
    accepted: BTreeMap<String, u64>,
    errors: InputErrors,
    rejections: Rejections,
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
                rejections: Rejections::default(),
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

    fn reject(&self, topic: &str, kind: RejectReason, reason: &str) {
        let now = self.now();
        let line = {
            let mut counters = self.counters.lock().expect("input counters poisoned");
            counters.rejections.add(kind);
            counters.errors.record(topic, reason, now)
        };
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
            rejections: c.rejections,
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
                // Conversions fail only on image contents (size, encoding, JPEG/PNG data).
                Err(reason) => sink.reject(&topic, RejectReason::Image, &reason),
            },
            Err(e) => sink.reject(
                &topic,
                RejectReason::Cdr,
                &format!("malformed message: {e}"),
            ),
        }
    }
    tracing::debug!(topic, "subscription stream ended");
}
