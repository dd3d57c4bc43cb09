//! One bounded multi-producer, single-consumer queue for all decoded inputs, with a policy for
//! overflow: drop the oldest queued item (keep the freshest frames) or drop the newest one.
//! Dropped items are counted.
//!
//! `tokio::sync::mpsc` cannot evict its oldest item from the sending side, so this is a small
//! `Mutex<VecDeque>` plus a `tokio::sync::Notify` with the same `recv().await` shape, and a
//! `Condvar` for a synchronous consumer ([`QueueReceiver::recv_timeout`]).

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::Notify;

/// What to do when the queue is full.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum OverflowPolicy {
    /// Evict the oldest queued item to make room (live streams: keep the freshest).
    #[default]
    DropOldest,
    /// Refuse the new item.
    DropNewest,
}

#[derive(Debug)]
struct Shared<T> {
    items: Mutex<VecDeque<T>>,
    capacity: usize,
    policy: OverflowPolicy,
    notify: Notify,
    ready: Condvar,
    dropped: AtomicU64,
    senders: AtomicUsize,
}

/// Sending half; clone one per producer.
#[derive(Debug)]
pub struct QueueSender<T> {
    shared: Arc<Shared<T>>,
}

/// Receiving half.
#[derive(Debug)]
pub struct QueueReceiver<T> {
    shared: Arc<Shared<T>>,
}

/// A new queue holding at most `capacity` (≥ 1) items.
pub fn bounded<T>(capacity: usize, policy: OverflowPolicy) -> (QueueSender<T>, QueueReceiver<T>) {
    let capacity = capacity.max(1);
    let shared = Arc::new(Shared {
        items: Mutex::new(VecDeque::with_capacity(capacity)),
        capacity,
        policy,
        notify: Notify::new(),
        ready: Condvar::new(),
        dropped: AtomicU64::new(0),
        senders: AtomicUsize::new(1),
    });
    (
        QueueSender {
            shared: shared.clone(),
        },
        QueueReceiver { shared },
    )
}

impl<T> QueueSender<T> {
    /// Enqueues `item`, applying the overflow policy; returns `false` if an item was dropped.
    pub fn send(&self, item: T) -> bool {
        let mut items = self.shared.items.lock().expect("queue lock poisoned");
        let mut kept_all = true;
        if items.len() >= self.shared.capacity {
            kept_all = false;
            self.shared.dropped.fetch_add(1, Ordering::Relaxed);
            match self.shared.policy {
                OverflowPolicy::DropOldest => {
                    items.pop_front();
                }
                OverflowPolicy::DropNewest => return false,
            }
        }
        items.push_back(item);
        drop(items);
        self.shared.notify.notify_one();
        self.shared.ready.notify_one();
        kept_all
    }

    /// Items dropped on overflow so far.
    pub fn dropped(&self) -> u64 {
        self.shared.dropped.load(Ordering::Relaxed)
    }
}

impl<T> Clone for QueueSender<T> {
    fn clone(&self) -> Self {
        self.shared.senders.fetch_add(1, Ordering::AcqRel);
        Self {
            shared: self.shared.clone(),
        }
    }
}

impl<T> Drop for QueueSender<T> {
    fn drop(&mut self) {
        if self.shared.senders.fetch_sub(1, Ordering::AcqRel) == 1 {
            self.shared.notify.notify_one();
            // Taking the lock orders this wake-up after a waiter's last look at the count.
            drop(self.shared.items.lock());
            self.shared.ready.notify_all();
        }
    }
}

impl<T> QueueReceiver<T> {
    /// The next item, or `None` once the queue is empty and every sender is gone.
    pub async fn recv(&mut self) -> Option<T> {
        let shared = self.shared.clone();
        loop {
            let notified = shared.notify.notified();
            if let Some(item) = self.try_recv() {
                return Some(item);
            }
            if shared.senders.load(Ordering::Acquire) == 0 {
                return self.try_recv();
            }
            notified.await;
        }
    }

    /// The next item, waiting at most `timeout` for one on the calling thread (no runtime
    /// needed); `None` on timeout or once the queue is empty and every sender is gone.
    pub fn recv_timeout(&mut self, timeout: Duration) -> Option<T> {
        let deadline = Instant::now() + timeout;
        let mut items = self.shared.items.lock().expect("queue lock poisoned");
        loop {
            if let Some(item) = items.pop_front() {
                return Some(item);
            }
            let now = Instant::now();
            if now >= deadline || self.shared.senders.load(Ordering::Acquire) == 0 {
                return None;
            }
            items = self
                .shared
                .ready
                .wait_timeout(items, deadline - now)
                .expect("queue lock poisoned")
                .0;
        }
    }

    /// Whether every sender is gone (nothing more will arrive once the queue is empty).
    pub fn is_closed(&self) -> bool {
        self.shared.senders.load(Ordering::Acquire) == 0
    }

    /// The next item if one is queued.
    pub fn try_recv(&mut self) -> Option<T> {
        self.shared
            .items
            .lock()
            .expect("queue lock poisoned")
            .pop_front()
    }

    /// Items currently queued.
    pub fn len(&self) -> usize {
        self.shared.items.lock().expect("queue lock poisoned").len()
    }

    /// Whether nothing is queued.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Items dropped on overflow so far.
    pub fn dropped(&self) -> u64 {
        self.shared.dropped.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drop_oldest_keeps_the_freshest_items_and_counts() {
        let (tx, mut rx) = bounded(3, OverflowPolicy::DropOldest);
        for i in 0..5 {
            tx.send(i);
        }
        assert_eq!(rx.dropped(), 2);
        let got: Vec<i32> = std::iter::from_fn(|| rx.try_recv()).collect();
        assert_eq!(got, vec![2, 3, 4]);
    }

    #[test]
    fn drop_newest_keeps_the_first_items_and_counts() {
        let (tx, mut rx) = bounded(3, OverflowPolicy::DropNewest);
        let kept: Vec<bool> = (0..5).map(|i| tx.send(i)).collect();
        assert_eq!(kept, vec![true, true, true, false, false]);
        assert_eq!(tx.dropped(), 2);
        let got: Vec<i32> = std::iter::from_fn(|| rx.try_recv()).collect();
        assert_eq!(got, vec![0, 1, 2]);
    }

    #[test]
    fn recv_timeout_wakes_on_send_times_out_and_ends_when_senders_are_gone() {
        let (tx, mut rx) = bounded(4, OverflowPolicy::DropOldest);
        let start = Instant::now();
        assert_eq!(rx.recv_timeout(Duration::from_millis(30)), None::<i32>);
        assert!(start.elapsed() >= Duration::from_millis(30));
        let producer = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(20));
            tx.send(7);
        });
        assert_eq!(rx.recv_timeout(Duration::from_secs(5)), Some(7));
        producer.join().unwrap();
        let start = Instant::now();
        assert_eq!(rx.recv_timeout(Duration::from_secs(5)), None);
        assert!(rx.is_closed());
        assert!(
            start.elapsed() < Duration::from_secs(1),
            "a closed queue does not wait"
        );
    }

    #[tokio::test]
    async fn recv_wakes_on_send_and_ends_when_senders_are_gone() {
        let (tx, mut rx) = bounded(4, OverflowPolicy::DropOldest);
        let tx2 = tx.clone();
        let producer = tokio::spawn(async move {
            for i in 0..3 {
                tokio::time::sleep(std::time::Duration::from_millis(5)).await;
                tx2.send(i);
            }
        });
        drop(tx);
        let mut got = Vec::new();
        while let Some(v) = tokio::time::timeout(std::time::Duration::from_secs(5), rx.recv())
            .await
            .expect("recv hung")
        {
            got.push(v);
        }
        producer.await.unwrap();
        assert_eq!(got, vec![0, 1, 2]);
    }
}
