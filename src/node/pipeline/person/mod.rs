//! One person the pipeline follows (the configured `person_id` without tracking, each tracked
//! person with it): their frame store, body shape, pose path, schedule, latest avatar and last
//! status, and the steps that run for them: reconstructing their avatar ([`jobs`]) and
//! rendering it. The dispatcher around it routes inputs to persons and results to the outputs;
//! the shared network and renderers are lent to the steps that need them.

mod jobs;
mod pose;
mod shape;
#[cfg(test)]
mod tests;

pub use jobs::Reconstruction;
pub use pose::PosePath;
pub use shape::ShapeState;

use super::render::{display_pose, render_frames, FrameRenderer, RenderedFrame, VirtualCameras};
use crate::avatar::Avatar;
use crate::body::{Pose, Skeleton};
use crate::msgs::ReconstructionStatus;
use crate::node::frame_store::{InsertOutcome, PersonViews, StoreLimits, View};
use crate::node::scheduler::{Completion, Job, Schedule, SchedulerConfig, SchedulerError};
use crate::reconstruct::shape::AcceptedShape;
use std::time::Duration;

/// The latest avatar, its revision and the skeleton of the body it was built on.
pub struct Current {
    /// Revision number.
    pub revision: u64,
    /// The avatar.
    pub avatar: Avatar,
    /// The skeleton its skinning refers to.
    pub skeleton: Skeleton,
}

/// One person's state and steps.
pub struct Person {
    views: PersonViews,
    schedule: Schedule,
    /// The body shape their reconstructions use.
    pub shape: ShapeState,
    /// What drives their frames.
    pub pose: PosePath,
    current: Option<Current>,
    /// The last status published for them.
    pub last_status: Option<ReconstructionStatus>,
    /// Whether this node reconstructs them (`cluster`); others are only followed.
    owned: bool,
}

impl Person {
    /// A person just seen.
    pub fn new(
        limits: StoreLimits,
        schedule: SchedulerConfig,
        pose: PosePath,
        owned: bool,
    ) -> Self {
        Self {
            views: PersonViews::new(limits),
            schedule: Schedule::new(schedule),
            shape: ShapeState::default(),
            pose,
            current: None,
            last_status: None,
            owned,
        }
    }

    /// Whether this node reconstructs them.
    pub fn owned(&self) -> bool {
        self.owned
    }

    /// Views held.
    pub fn views_held(&self) -> usize {
        self.views.len()
    }

    /// Frame ids of the views held (the network's token cache keys).
    pub fn frame_ids(&self) -> impl Iterator<Item = u64> + '_ {
        self.views.views().iter().map(|v| v.frame_id)
    }

    /// The latest avatar.
    pub fn current(&self) -> Option<&Current> {
        self.current.as_ref()
    }

    /// The latest avatar revision (0 before the first).
    pub fn revision(&self) -> u64 {
        self.current.as_ref().map_or(0, |c| c.revision)
    }

    /// Version of everything their reconstruction depends on: grows with every view-set change
    /// and every body-shape change.
    fn input_version(&self) -> u64 {
        self.views.version() + self.shape.changes()
    }

    /// Offers a view to their frame store; a change of the set reruns their reconstruction
    /// (when this node reconstructs them).
    pub fn add_view(&mut self, view: View, now: Duration) -> InsertOutcome {
        let arrival = view.arrival;
        let outcome = self.views.insert(view);
        if outcome.changed() && self.owned {
            self.schedule
                .view_set_changed(self.input_version(), arrival, now);
        }
        outcome
    }

    /// Drops the views `camera` gave: it follows someone else now. Their reconstruction reruns
    /// on the views left, if any (when this node reconstructs them); the avatar made so far
    /// stays until then. The frame ids dropped.
    pub fn drop_camera(&mut self, camera: &str, now: Duration) -> Vec<u64> {
        let dropped = self.views.remove_camera(camera);
        if !dropped.is_empty() && self.owned {
            if let Some(arrival) = self.views.snapshot().last_arrival() {
                self.schedule
                    .view_set_changed(self.input_version(), arrival, now);
            }
        }
        dropped
    }

    /// Uses `shape` from their next reconstruction on; a change reruns it (when views are held
    /// and this node reconstructs them). Whether the shape changed.
    pub fn use_shape(&mut self, shape: AcceptedShape, arrival: Duration, now: Duration) -> bool {
        if !self.shape.set(shape) {
            return false;
        }
        if !self.views.is_empty() && self.owned {
            self.schedule
                .view_set_changed(self.input_version(), arrival, now);
        }
        true
    }

    /// The cluster hands them to this node (`owned`: their views are already held, so their
    /// reconstruction is scheduled) or away from it (nothing pending or in flight is kept).
    pub fn hand_over(&mut self, owned: bool, now: Duration) {
        self.owned = owned;
        if !owned {
            self.schedule.reset();
        } else if !self.views.is_empty() {
            let arrival = self.views.snapshot().last_arrival().unwrap_or(now);
            self.schedule
                .view_set_changed(self.input_version(), arrival, now);
        }
    }

    /// Their job due at `now`, if any, with when its first unhandled change came.
    pub fn poll(&mut self, id: &str, now: Duration) -> Option<(Duration, Job)> {
        self.schedule.poll(id, now)
    }

    /// When their next job is due, if one is pending.
    pub fn next_deadline(&self) -> Option<Duration> {
        self.schedule.next_deadline()
    }

    /// Whether a job of theirs is in flight.
    pub fn busy(&self) -> bool {
        self.schedule.busy()
    }

    /// The reconstruction `job` asks for, on the views and shape they hold now (`None`: no
    /// views; the job is then failed).
    pub fn start(&mut self, job: Job) -> Option<Reconstruction> {
        if self.views.is_empty() {
            let _ = self.schedule.failed(&job.person, job.revision);
            return None;
        }
        Some(Reconstruction {
            job,
            views: self.views.snapshot(),
            shape: self.shape.shape().cloned(),
        })
    }

    /// Their reconstruction `job` made `avatar` (built on `skeleton`), published at `now`.
    pub fn finished(
        &mut self,
        job: &Job,
        avatar: Avatar,
        skeleton: Skeleton,
        now: Duration,
    ) -> Result<Completion, SchedulerError> {
        self.current = Some(Current {
            revision: job.revision,
            avatar,
            skeleton,
        });
        self.schedule.finished(&job.person, job.revision, now)
    }

    /// Their reconstruction `job` failed (its revision is spent).
    pub fn failed(&mut self, job: &Job) {
        let _ = self.schedule.failed(&job.person, job.revision);
    }

    /// Their latest avatar from every virtual camera, at the pose their frames use at `now`
    /// (`None`: no avatar yet).
    pub fn render(
        &self,
        now: Duration,
        cameras: &VirtualCameras,
        frames: &mut FrameRenderer,
    ) -> Option<Vec<RenderedFrame>> {
        let current = self.current.as_ref()?;
        let pose = display_pose(self.pose.pose(now), now.as_secs_f32());
        Some(render_frames(
            &current.avatar,
            &current.skeleton,
            &pose,
            cameras,
            frames,
        ))
    }

    /// Their latest avatar from every virtual camera at `pose`.
    pub fn render_at(
        &self,
        pose: &Pose,
        cameras: &VirtualCameras,
        frames: &mut FrameRenderer,
    ) -> Option<Vec<RenderedFrame>> {
        let current = self.current.as_ref()?;
        Some(render_frames(
            &current.avatar,
            &current.skeleton,
            pose,
            cameras,
            frames,
        ))
    }

    /// The poses of their end-of-replay animation: the poses read from the cameras when they
    /// drove the avatar, else `frames` frames of the built-in walk cycle.
    pub fn animation(&self, frames: usize) -> Vec<Pose> {
        let track = self.pose.animation_track();
        if track.is_empty() {
            (0..frames)
                .map(|f| display_pose(None, f as f32 / 24.0))
                .collect()
        } else {
            track
        }
    }

    /// Their latest avatar posed as their frames are at `now`, for the preview.
    pub fn posed(&self, now: Duration) -> Option<crate::splat::Gaussians> {
        let current = self.current.as_ref()?;
        let pose = display_pose(self.pose.pose(now), now.as_secs_f32());
        let matrices = current.skeleton.skinning_matrices(&pose);
        Some(current.avatar.animate(&matrices))
    }
}
