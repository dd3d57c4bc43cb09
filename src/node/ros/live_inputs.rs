//! The receiving end of the endpoint's input queue: takes what the subscriptions queued and
//! decodes image messages as they are taken, counting those that do not decode with the
//! subscriptions' own counters (per topic and by reason, reported as they report theirs).

use super::sink::Rejecter;
use crate::node::input_queue::QueueReceiver;
use crate::node::inputs::{Incoming, InputEvent};
use crate::node::rejections::RejectReason;
use std::time::{Duration, Instant};

/// Decoded input events from the live subscriptions, in arrival order.
pub struct LiveInputs {
    queue: QueueReceiver<Incoming>,
    rejecter: Rejecter,
}

impl LiveInputs {
    pub(crate) fn new(queue: QueueReceiver<Incoming>, rejecter: Rejecter) -> Self {
        Self { queue, rejecter }
    }

    /// The next event, waiting for one (async); `None` once the queue is empty and the
    /// subscriptions are gone.
    pub async fn recv(&mut self) -> Option<InputEvent> {
        loop {
            let incoming = self.queue.recv().await?;
            if let Some(event) = self.decoded(incoming) {
                return Some(event);
            }
        }
    }

    /// The next event, waiting at most `timeout` on the calling thread; `None` on timeout or
    /// once the queue is empty and the subscriptions are gone.
    pub fn recv_timeout(&mut self, timeout: Duration) -> Option<InputEvent> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let incoming = self.queue.recv_timeout(left)?;
            if let Some(event) = self.decoded(incoming) {
                return Some(event);
            }
        }
    }

    /// Whether the subscriptions are gone (nothing more will arrive once the queue is empty).
    pub fn is_closed(&self) -> bool {
        self.queue.is_closed()
    }

    /// Whether nothing is queued.
    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }

    /// The event, with an image decoded; `None` (counted and reported) when it does not decode.
    fn decoded(&self, incoming: Incoming) -> Option<InputEvent> {
        match incoming {
            Incoming::Event(event) => Some(event),
            Incoming::Image(image) => {
                let topic = image.topic.clone();
                match image.decode() {
                    Ok(event) => Some(event),
                    Err(reason) => {
                        self.rejecter.reject(&topic, RejectReason::Image, &reason);
                        None
                    }
                }
            }
        }
    }
}
