//! The receiving end shared by all subscription tasks: converts each message into an
//! [`InputEvent`](crate::node::inputs::InputEvent), pushes it into the one bounded input
//! queue, and counts and reports (rate-limited, per topic) the messages that could not be used.

use crate::node::input_errors::InputErrors;
use crate::node::input_queue::QueueSender;
use crate::node::rejections::{RejectReason, Rejections};
use futures::StreamExt;
use ros2_client::dds::{NodeLoggingHandle, RosoutRaw, Subscription};
use ros2_client::gid::Gid;
use ros2_client::log::LogLevel;
use serde::de::DeserializeOwned;
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, Weak};
use std::time::{Duration, Instant};

/// Per-topic counters of the input side.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct InputStats {
    /// Messages taken into the input queue, per resolved topic. An image message is decoded
    /// when the pipeline takes it; one that does not decode then also counts in `rejected`.
    pub accepted: BTreeMap<String, u64>,
    /// Messages rejected (malformed or undecodable), per resolved topic.
    pub rejected: BTreeMap<String, u64>,
    /// The same rejections by reason (`cdr`: does not deserialize; `image`: unusable image).
    pub rejections: Rejections,
    /// Events dropped because the input queue was full.
    pub queue_dropped: u64,
    /// Messages dropped by the per-topic rate limit (`inputs.max_rate_hz`) before they were
    /// decoded, per resolved topic.
    pub rate_limited: BTreeMap<String, u64>,
}

#[derive(Debug)]
struct Counters {
    accepted: BTreeMap<String, u64>,
    errors: InputErrors,
    rejections: Rejections,
    rate_limited: BTreeMap<String, u64>,
}

/// Shared by the subscription tasks of one node.
pub(crate) struct InputSink<E> {
    queue: QueueSender<E>,
    rejecter: Rejecter,
    min_interval: Option<Duration>,
}

impl<E> Clone for InputSink<E> {
    fn clone(&self) -> Self {
        Self {
            queue: self.queue.clone(),
            rejecter: self.rejecter.clone(),
            min_interval: self.min_interval,
        }
    }
}

/// Counts and reports the input messages that could not be used, with the subscriptions'
/// counters: for the subscription tasks and for the queue's receiving end, which decodes
/// images as they are taken.
#[derive(Clone)]
pub(crate) struct Rejecter {
    counters: Arc<Mutex<Counters>>,
    start: Instant,
    rosout: Option<Rosout>,
}

/// The node's `/rosout` writer: held by the subscription tasks; only referred to by the
/// queue's receiving end, which may outlive the node (a held writer would then be removed
/// after the DDS participant, which RustDDS logs as an error).
#[derive(Clone)]
enum Rosout {
    Held(Arc<NodeLoggingHandle>),
    Referred(Weak<NodeLoggingHandle>),
}

impl Rosout {
    fn handle(&self) -> Option<Arc<NodeLoggingHandle>> {
        match self {
            Rosout::Held(h) => Some(h.clone()),
            Rosout::Referred(w) => w.upgrade(),
        }
    }
}

impl Rejecter {
    /// Counts a message of `topic` that could not be used, and reports it (rate-limited per
    /// topic, to `tracing` and, while the node lives and has it enabled, `/rosout`).
    pub(crate) fn reject(&self, topic: &str, kind: RejectReason, reason: &str) {
        let now = self.start.elapsed();
        let line = {
            let mut counters = self.counters.lock().expect("input counters poisoned");
            counters.rejections.add(kind);
            counters.errors.record(topic, reason, now)
        };
        if let Some(line) = line {
            match self.rosout.as_ref().and_then(Rosout::handle) {
                // rosout_raw also forwards the line to `tracing`.
                Some(handle) => handle.rosout_raw(
                    ros2_client::builtin_interfaces::Time::now(),
                    LogLevel::Warn,
                    handle.base_name(),
                    &line,
                    file!(),
                    "Rejecter::reject",
                    line!(),
                ),
                None => tracing::warn!("{line}"),
            }
        }
    }
}

impl<E: Send + 'static> InputSink<E> {
    pub(crate) fn new(
        queue: QueueSender<E>,
        report_period: Duration,
        start: Instant,
        rosout: Option<NodeLoggingHandle>,
        min_interval: Option<Duration>,
    ) -> Self {
        Self {
            queue,
            rejecter: Rejecter {
                counters: Arc::new(Mutex::new(Counters {
                    accepted: BTreeMap::new(),
                    errors: InputErrors::new(report_period),
                    rejections: Rejections::default(),
                    rate_limited: BTreeMap::new(),
                })),
                start,
                rosout: rosout.map(|h| Rosout::Held(Arc::new(h))),
            },
            min_interval,
        }
    }

    /// The rejecter for the queue's receiving end, which may outlive the node: it only refers
    /// to the `/rosout` writer, so once the node is gone its reports go to `tracing` only.
    pub(crate) fn rejecter(&self) -> Rejecter {
        let rosout = self.rejecter.rosout.as_ref().map(|r| match r {
            Rosout::Held(h) => Rosout::Referred(Arc::downgrade(h)),
            referred => referred.clone(),
        });
        Rejecter {
            rosout,
            ..self.rejecter.clone()
        }
    }

    /// Node clock: time since the node started.
    pub(crate) fn now(&self) -> Duration {
        self.rejecter.start.elapsed()
    }

    fn accept(&self, topic: &str, event: E) {
        *self
            .rejecter
            .counters
            .lock()
            .expect("input counters poisoned")
            .accepted
            .entry(topic.to_owned())
            .or_default() += 1;
        self.queue.send(event);
    }

    fn reject(&self, topic: &str, kind: RejectReason, reason: &str) {
        self.rejecter.reject(topic, kind, reason);
    }

    /// The per-topic rate limit: whether a message of `topic` arriving at `now` comes sooner
    /// than the minimum interval after the last one taken (`last`), and is dropped (counted)
    /// before it is decoded; otherwise it is taken and `last` moves to `now`.
    fn over_rate(&self, topic: &str, last: &mut Option<Duration>, now: Duration) -> bool {
        let too_soon = match (self.min_interval, *last) {
            (Some(min), Some(prev)) => now.saturating_sub(prev) < min,
            _ => false,
        };
        if too_soon {
            let mut counters = self
                .rejecter
                .counters
                .lock()
                .expect("input counters poisoned");
            *counters.rate_limited.entry(topic.to_owned()).or_default() += 1;
        } else {
            *last = Some(now);
        }
        too_soon
    }

    /// Snapshot of the counters.
    pub(crate) fn stats(&self) -> InputStats {
        let c = self
            .rejecter
            .counters
            .lock()
            .expect("input counters poisoned");
        InputStats {
            accepted: c.accepted.clone(),
            rejected: c.errors.counts().map(|(t, n)| (t.to_owned(), n)).collect(),
            rejections: c.rejections,
            queue_dropped: self.queue.dropped(),
            rate_limited: c.rate_limited.clone(),
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
        tokio::spawn(read_subscription(self.clone(), topic, sub, None, convert))
    }

    /// [`InputSink::spawn`] that skips the messages written by `own` (the node's own
    /// publisher on the same topic), uncounted.
    pub(crate) fn spawn_from_others<M, F>(
        &self,
        topic: String,
        sub: Subscription<M>,
        own: Gid,
        convert: F,
    ) -> tokio::task::JoinHandle<()>
    where
        M: DeserializeOwned + Send + Sync + 'static,
        F: Fn(&str, M, Duration) -> Result<E, String> + Send + 'static,
    {
        tokio::spawn(read_subscription(
            self.clone(),
            topic,
            sub,
            Some(own),
            convert,
        ))
    }
}

/// Reads `sub` until its stream ends or the task is aborted, feeding `sink`.
async fn read_subscription<E, M, F>(
    sink: InputSink<E>,
    topic: String,
    sub: Subscription<M>,
    ignore: Option<Gid>,
    convert: F,
) where
    E: Send + 'static,
    M: DeserializeOwned + Send + Sync + 'static,
    F: Fn(&str, M, Duration) -> Result<E, String> + Send + 'static,
{
    let stream = sub.async_stream();
    futures::pin_mut!(stream);
    let mut last_taken = None;
    while let Some(item) = stream.next().await {
        if let (Ok((_, info)), Some(own)) = (&item, ignore) {
            if info.publisher_gid() == own {
                continue;
            }
        }
        if sink.over_rate(&topic, &mut last_taken, sink.now()) {
            continue;
        }
        match item {
            Ok((msg, _info)) => match convert(&topic, msg, sink.now()) {
                Ok(event) => sink.accept(&topic, event),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::node::input_queue::{bounded, OverflowPolicy};

    #[test]
    fn messages_sooner_than_the_rate_allows_are_dropped_and_counted_per_topic() {
        let (tx, _rx) = bounded::<u32>(4, OverflowPolicy::DropOldest);
        let sink = InputSink::new(
            tx,
            Duration::from_secs(1),
            Instant::now(),
            None,
            Some(Duration::from_millis(100)),
        );
        let ms = Duration::from_millis;
        let mut last = None;
        let taken: Vec<u64> = [0, 50, 100, 150, 199, 250, 400]
            .into_iter()
            .filter(|&t| !sink.over_rate("/cam0", &mut last, ms(t)))
            .collect();
        assert_eq!(taken, [0, 100, 250, 400]);
        // Another topic has its own budget.
        let mut other = None;
        assert!(!sink.over_rate("/pose", &mut other, ms(260)));
        let stats = sink.stats();
        assert_eq!(stats.rate_limited.get("/cam0"), Some(&3));
        assert_eq!(stats.rate_limited.get("/pose"), None);
    }

    #[test]
    fn no_limit_takes_everything() {
        let (tx, _rx) = bounded::<u32>(4, OverflowPolicy::DropOldest);
        let sink = InputSink::new(tx, Duration::from_secs(1), Instant::now(), None, None);
        let mut last = None;
        assert!((0..100).all(|_| !sink.over_rate("/cam0", &mut last, Duration::ZERO)));
        assert!(sink.stats().rate_limited.is_empty());
    }
}
