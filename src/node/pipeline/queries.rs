//! What the pipeline tells the node, its summary and the tests: counters, persons, avatars.

use super::perceive::Perception;
use super::{Person, Pipeline, PipelineStats};
use crate::avatar::Avatar;
use crate::node::outputs::{DiskUsage, Publisher};
use crate::node::rejections::Rejections;
use crate::reconstruct::ReconstructError;

impl Pipeline {
    /// Run counters so far.
    pub fn stats(&self) -> &PipelineStats {
        &self.stats
    }

    /// What the files under `outputs.dir` took and gave back so far (`None`: no files).
    pub fn disk_usage(&self) -> Option<DiskUsage> {
        self.outputs.disk_usage()
    }

    /// Every input message rejected so far, by reason: the pipeline's, the replay's and the
    /// live subscriptions'.
    pub fn rejections(&self) -> Rejections {
        self.stats.rejections.merged(&self.input_rejections)
    }

    /// Whether frames go through the network's neural renderer (`outputs.renderer` resolved
    /// to `neural`).
    pub fn neural_frames(&self) -> bool {
        self.frames.is_neural()
    }

    /// This node's `(cluster.index, cluster.members)`, when heartbeats are expected.
    pub fn heartbeat(&self) -> Option<(u32, u32)> {
        self.membership.live().then(|| self.membership.me())
    }

    /// Views currently held for the configured person (without tracking).
    pub fn views_held(&self) -> usize {
        self.views_held_by(&self.default_person)
    }

    /// Latest avatar revision of the configured person (0 before the first).
    pub fn revision(&self) -> u64 {
        self.revision_of(&self.default_person)
    }

    /// The configured person's latest avatar.
    pub fn avatar(&self) -> Option<&Avatar> {
        self.avatar_of(&self.default_person)
    }

    /// The person tracker's counters (`tracking.enabled` only): persons started, forgotten
    /// after `forget_after`, dropped past `max_persons`.
    pub fn tracking_stats(&self) -> Option<crate::tracking::TrackingStats> {
        self.perception
            .as_ref()
            .and_then(Perception::tracking_stats)
    }

    /// The persons followed now (the configured one without tracking, once seen), by id.
    pub fn persons(&self) -> Vec<String> {
        self.persons.keys().cloned().collect()
    }

    /// Whether this node reconstructs `person` (`cluster`); the others are only tracked.
    pub fn reconstructs(&self, person: &str) -> bool {
        self.persons.get(person).is_some_and(Person::owned)
    }

    /// Views held for `person`.
    pub fn views_held_by(&self, person: &str) -> usize {
        self.persons.get(person).map_or(0, Person::views_held)
    }

    /// `person`'s latest avatar revision (0 before the first).
    pub fn revision_of(&self, person: &str) -> u64 {
        self.persons.get(person).map_or(0, Person::revision)
    }

    /// `person`'s latest avatar.
    pub fn avatar_of(&self, person: &str) -> Option<&Avatar> {
        self.persons
            .get(person)
            .and_then(Person::current)
            .map(|c| &c.avatar)
    }

    /// Views the network has encoded (each held view once, thanks to the token cache).
    pub fn encoded_views(&self) -> usize {
        self.recon.encode_count()
    }

    /// Frames perception dropped unperceived (live: replaced by a newer frame of their camera
    /// before the worker took them).
    pub fn perception_dropped(&self) -> u64 {
        self.perception.as_ref().map_or(0, Perception::dropped)
    }

    /// The body shape in use, as `GaussianAvatar.shape_params` carries it (empty if none).
    pub fn shape_params(&self) -> Vec<f32> {
        self.recon.shape().map_or_else(Vec::new, |s| s.params())
    }

    /// Anchor positions the next reconstruction starts from (canonical frame, metres).
    pub fn anchor_positions(&self) -> Result<Vec<glam::Vec3>, ReconstructError> {
        self.recon.anchor_positions()
    }
}
