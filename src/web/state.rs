//! What the live page shows, kept for pages that connect later: each person's latest avatar,
//! status and pose, a broadcast of every avatar and status to the pages connected now, and a
//! watch of the newest pose (a page is sent each person's newest pose when it asks: one that
//! draws slower than poses arrive skips poses instead of falling behind). Bounded: at most
//! [`MAX_PERSONS`] persons (the least recently updated goes first) and a broadcast queue of
//! [`QUEUE`] updates (a page that falls behind is sent the latest state again).

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard};
use tokio::sync::{broadcast, watch};

/// Persons kept.
pub const MAX_PERSONS: usize = 64;
/// Updates queued per connected page before it counts as behind.
pub const QUEUE: usize = 256;

/// One WebSocket message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Payload {
    /// A JSON text frame (pose, status).
    Text(Arc<str>),
    /// A binary frame (an avatar).
    Binary(Arc<[u8]>),
}

#[derive(Default)]
struct Person {
    avatar: Option<Payload>,
    status: Option<Payload>,
    pose: Option<Payload>,
    /// Update counter at the last pose.
    pose_at: u64,
    /// Update counter at the last update (the oldest is dropped first).
    touched: u64,
}

#[derive(Default)]
struct Persons {
    by_id: BTreeMap<String, Person>,
    updates: u64,
}

/// The latest of everything, and the broadcast to connected pages.
pub struct LiveState {
    persons: Mutex<Persons>,
    tx: broadcast::Sender<Payload>,
    /// Update counter at the newest pose.
    poses: watch::Sender<u64>,
}

impl Default for LiveState {
    fn default() -> Self {
        Self {
            persons: Mutex::new(Persons::default()),
            tx: broadcast::channel(QUEUE).0,
            poses: watch::channel(0).0,
        }
    }
}

impl LiveState {
    fn lock(&self) -> MutexGuard<'_, Persons> {
        self.persons.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Keeps `payload` in `person`'s `slot`; returns the update counter.
    fn keep(
        &self,
        person: &str,
        payload: Payload,
        slot: fn(&mut Person) -> &mut Option<Payload>,
    ) -> u64 {
        let mut persons = self.lock();
        persons.updates += 1;
        let touched = persons.updates;
        if !persons.by_id.contains_key(person) && persons.by_id.len() >= MAX_PERSONS {
            if let Some(oldest) = persons
                .by_id
                .iter()
                .min_by_key(|(_, p)| p.touched)
                .map(|(id, _)| id.clone())
            {
                persons.by_id.remove(&oldest);
            }
        }
        let entry = persons.by_id.entry(person.to_owned()).or_default();
        entry.touched = touched;
        *slot(entry) = Some(payload);
        touched
    }

    /// Keeps `payload` and sends it to the pages connected now.
    fn update(
        &self,
        person: &str,
        payload: Payload,
        slot: fn(&mut Person) -> &mut Option<Payload>,
    ) {
        self.keep(person, payload.clone(), slot);
        // No page connected: nothing to do.
        let _ = self.tx.send(payload);
    }

    /// A person's new avatar (binary frame, [`super::protocol::avatar_frame`]).
    pub fn set_avatar(&self, person: &str, frame: Vec<u8>) {
        self.update(person, Payload::Binary(frame.into()), |p| &mut p.avatar);
    }

    /// A person's new status (JSON, [`super::protocol::status_json`]).
    pub fn set_status(&self, person: &str, json: String) {
        self.update(person, Payload::Text(json.into()), |p| &mut p.status);
    }

    /// A person's new pose (JSON, [`super::protocol::pose_json`]).
    pub fn set_pose(&self, person: &str, json: String) {
        let at = self.keep(person, Payload::Text(json.into()), |p| &mut p.pose);
        let mut persons = self.lock();
        if let Some(p) = persons.by_id.get_mut(person) {
            p.pose_at = at;
        }
        drop(persons);
        self.poses.send_replace(at);
    }

    /// The newest pose of each person whose pose changed after update `after`, and the update
    /// counter of the newest.
    pub fn poses_after(&self, after: u64) -> (Vec<Payload>, u64) {
        let persons = self.lock();
        let changed: Vec<&Person> = persons
            .by_id
            .values()
            .filter(|p| p.pose_at > after)
            .collect();
        let newest = changed.iter().map(|p| p.pose_at).max().unwrap_or(after);
        let poses = changed.iter().filter_map(|p| p.pose.clone()).collect();
        (poses, newest)
    }

    /// Wakes when a pose changes (its value: the update counter of the newest pose).
    pub fn watch_poses(&self) -> watch::Receiver<u64> {
        self.poses.subscribe()
    }

    /// Everything a page that connects now needs: each person's avatar, status and pose.
    pub fn snapshot(&self) -> Vec<Payload> {
        self.lock()
            .by_id
            .values()
            .flat_map(|p| [&p.avatar, &p.status, &p.pose])
            .flatten()
            .cloned()
            .collect()
    }

    /// The stream of updates from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<Payload> {
        self.tx.subscribe()
    }

    /// Persons kept.
    pub fn persons(&self) -> Vec<String> {
        self.lock().by_id.keys().cloned().collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_late_page_gets_the_latest_of_each_and_persons_stay_bounded() {
        let state = LiveState::default();
        let mut rx = state.subscribe();
        let mut poses = state.watch_poses();
        state.set_pose("a", "pose 1".into());
        state.set_pose("a", "pose 2".into());
        state.set_avatar("a", vec![1, 2, 3]);
        assert_eq!(
            rx.try_recv().unwrap(),
            Payload::Binary(vec![1, 2, 3].into())
        );
        // Poses are not queued: the newest is there when asked for.
        assert!(poses.has_changed().unwrap());
        let seen = *poses.borrow_and_update();
        let (newest, at) = state.poses_after(0);
        assert_eq!(newest, vec![Payload::Text("pose 2".into())]);
        assert_eq!(at, seen);
        assert!(state.poses_after(at).0.is_empty());
        state.set_pose("b", "pose b".into());
        assert_eq!(
            state.poses_after(at).0,
            vec![Payload::Text("pose b".into())]
        );
        let snapshot = state.snapshot();
        assert_eq!(
            snapshot,
            vec![
                Payload::Binary(vec![1, 2, 3].into()),
                Payload::Text("pose 2".into()),
                Payload::Text("pose b".into())
            ]
        );
        for i in 0..MAX_PERSONS + 5 {
            state.set_status(&format!("p{i:03}"), "s".into());
        }
        let persons = state.persons();
        assert_eq!(persons.len(), MAX_PERSONS);
        assert!(!persons.contains(&"a".to_string()), "the oldest went first");
        assert!(persons.contains(&format!("p{:03}", MAX_PERSONS + 4)));
    }
}
