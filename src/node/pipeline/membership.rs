//! Which cluster member reconstructs which person (`cluster.members`, `cluster.index`).
//!
//! Every member tracks every person; a person is reconstructed by the alive member at position
//! `FNV-1a(id) mod alive` in the sorted list of alive members. Live (ROS 2 up), each member
//! publishes a heartbeat every [`HEARTBEAT_PERIOD`]; a member not heard for [`MEMBER_TIMEOUT`]
//! is taken for gone and its persons go to the others, which already hold their views. At
//! start every member counts as alive, so nobody grabs everyone before the others are heard.
//! Without heartbeats (bag replay) the split is static.

use crate::config::{owner, ClusterConfig};
use std::time::Duration;

/// How often a member says it is alive.
pub const HEARTBEAT_PERIOD: Duration = Duration::from_millis(500);
/// A member not heard for this long is gone.
pub const MEMBER_TIMEOUT: Duration = Duration::from_secs(2);

/// The cluster as this member sees it.
#[derive(Debug, Clone)]
pub struct Membership {
    members: u32,
    index: u32,
    /// Heartbeats are expected: silent members drop out.
    live: bool,
    /// When each member was last heard (node clock; zero: the start).
    last_heard: Vec<Duration>,
    /// Alive members, sorted, after the last refresh.
    alive: Vec<u32>,
    /// Heartbeats of a cluster of another size were seen (warned once).
    size_warned: bool,
}

impl Membership {
    /// All members alive; heartbeats are not expected until [`Membership::expect_heartbeats`].
    pub fn new(cluster: &ClusterConfig) -> Self {
        let members = cluster.members.max(1);
        Self {
            members,
            index: cluster.index.min(members - 1),
            live: false,
            last_heard: vec![Duration::ZERO; members as usize],
            alive: (0..members).collect(),
            size_warned: false,
        }
    }

    /// Members silent for [`MEMBER_TIMEOUT`] from `now` on drop out (the live node).
    pub fn expect_heartbeats(&mut self, now: Duration) {
        self.live = true;
        self.last_heard.fill(now);
    }

    /// Whether heartbeats are expected and there are other members.
    pub fn live(&self) -> bool {
        self.live && self.members > 1
    }

    /// A heartbeat of member `index` of a `members`-member cluster.
    pub fn heartbeat(&mut self, index: u32, members: u32, arrival: Duration) {
        if members != self.members || index >= self.members {
            if !self.size_warned {
                self.size_warned = true;
                tracing::warn!(
                    "a cluster heartbeat says member {index} of {members}, but this node is \
                     member {} of {}: check cluster.members on every node",
                    self.index,
                    self.members
                );
            }
            return;
        }
        let heard = &mut self.last_heard[index as usize];
        *heard = (*heard).max(arrival);
    }

    /// Updates the alive members at `now`; whether they changed.
    pub fn refresh(&mut self, now: Duration) -> bool {
        let alive: Vec<u32> = (0..self.members)
            .filter(|&i| {
                i == self.index
                    || !self.live
                    || now.saturating_sub(self.last_heard[i as usize]) < MEMBER_TIMEOUT
            })
            .collect();
        if alive == self.alive {
            return false;
        }
        tracing::info!(alive = ?alive, "cluster members changed");
        self.alive = alive;
        true
    }

    /// Whether this member reconstructs `person`.
    pub fn owns(&self, person: &str) -> bool {
        let n = self.alive.len() as u32;
        n <= 1 || self.alive[owner(person, n) as usize] == self.index
    }

    /// This member's index and the cluster size (the heartbeat's content).
    pub fn me(&self) -> (u32, u32) {
        (self.index, self.members)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ids() -> Vec<String> {
        (0..12).map(|i| format!("person_{i}")).collect()
    }

    /// While both members beat, each person has one owner; when one falls silent, the other
    /// owns everyone within the timeout; when it comes back, the split returns.
    #[test]
    fn a_silent_member_hands_its_persons_over() {
        let s = Duration::from_secs_f64;
        let mut m: Vec<Membership> = (0..2)
            .map(|index| {
                let mut m = Membership::new(&ClusterConfig { members: 2, index });
                m.expect_heartbeats(s(0.0));
                m
            })
            .collect();
        let beat = |m: &mut Vec<Membership>, who: u32, t: f64| {
            for (i, x) in m.iter_mut().enumerate() {
                if i as u32 != who {
                    x.heartbeat(who, 2, s(t));
                }
            }
        };
        for t in [0.5, 1.0, 1.5, 2.0, 2.5] {
            beat(&mut m, 0, t);
            beat(&mut m, 1, t);
            m.iter_mut().for_each(|x| {
                x.refresh(s(t));
            });
        }
        for id in ids() {
            let owners = m.iter().filter(|x| x.owns(&id)).count();
            assert_eq!(owners, 1, "{id}");
        }
        assert!(ids().iter().any(|id| m[1].owns(id)));
        // Member 1 stops; member 0 keeps beating.
        beat(&mut m, 0, 3.0);
        assert!(!m[0].refresh(s(4.4)), "1.9 s of silence is not yet gone");
        assert!(m[0].refresh(s(4.6)));
        assert!(ids().iter().all(|id| m[0].owns(id)));
        // It comes back.
        beat(&mut m, 1, 5.0);
        assert!(m[0].refresh(s(5.0)));
        assert!(ids().iter().any(|id| !m[0].owns(id)));
        // Without heartbeats expected (bag replay) the split never changes.
        let mut replay = Membership::new(&ClusterConfig {
            members: 2,
            index: 0,
        });
        assert!(!replay.refresh(s(100.0)));
        assert!(!replay.live());
    }
}
