//! A person's due job, run on the network all persons share: the person lends it the views and
//! shape they hold ([`Reconstruction`](super::person::Reconstruction)), the result goes to the
//! outputs and back to the person as their latest avatar.

use super::Pipeline;
use crate::avatar::Avatar;
use crate::msgs::ReconstructionStatus;
use crate::node::outputs::{AvatarUpdate, Publisher};
use crate::node::scheduler::Job;
use std::time::Duration;

impl Pipeline {
    /// Runs `job` (a reconstruction of its person) now; `clock` times it.
    pub(super) fn reconstruct(&mut self, job: Job, clock: &impl Fn() -> Duration) {
        let Some(person) = self.persons.get_mut(&job.person) else {
            return;
        };
        let Some(work) = person.start(job) else {
            return;
        };
        let job = &work.job;
        let id = job.person.clone();
        self.publish_status(
            &id,
            job.revision.saturating_sub(1),
            0.0,
            ReconstructionStatus::STATE_RECONSTRUCTING,
            "reconstructing",
        );
        let colours = self.colours_from_views.then_some(self.delight);
        match work.run(&mut self.recon, colours) {
            Ok(avatar) => {
                self.publish_avatar(job, &avatar, work.view_count(), work.stamp_ns());
                let skeleton = self.recon.template().skeleton.clone();
                let Some(person) = self.persons.get_mut(&id) else {
                    return;
                };
                match person.finished(job, avatar, skeleton, clock()) {
                    Ok(done) => {
                        self.stats.reconstructed(done.latency, done.run_time);
                        let latency = done.latency.as_secs_f64() * 1e3;
                        tracing::info!(
                            person = %id,
                            revision = job.revision,
                            views = work.view_count(),
                            latency_ms = format!("{latency:.0}"),
                            run_ms = format!("{:.0}", done.run_time.as_secs_f64() * 1e3),
                            "avatar published"
                        );
                        self.publish_status(
                            &id,
                            job.revision,
                            latency,
                            ReconstructionStatus::STATE_IDLE,
                            "avatar published",
                        );
                    }
                    Err(e) => tracing::error!("scheduler: {e}"),
                }
            }
            Err(e) => {
                self.stats.failures += 1;
                tracing::error!(person = %id, revision = job.revision, "reconstruction failed: {e}");
                if let Some(person) = self.persons.get_mut(&id) {
                    person.failed(job);
                }
                self.publish_status(
                    &id,
                    job.revision,
                    0.0,
                    ReconstructionStatus::STATE_ERROR,
                    e.to_string(),
                );
            }
        }
    }

    /// Hands a new avatar revision to the outputs (the files first, then the live publishers).
    fn publish_avatar(&mut self, job: &Job, avatar: &Avatar, views: usize, stamp: i64) {
        let shape_params = self.shape_params();
        self.outputs.avatar(&AvatarUpdate {
            person: &job.person,
            revision: job.revision,
            views_used: views,
            stamp_ns: stamp,
            avatar,
            template: self.recon.template(),
            shape_params: &shape_params,
            rgb_display_ready: self.recon.rgb_kind().display_ready(),
            neural_renderer: &self.neural_renderer_id,
            compact: Default::default(),
        });
    }
}
