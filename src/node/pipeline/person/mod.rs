//! One person the pipeline follows (the configured `person_id` without tracking, each tracked
//! person with it): their frame store, body shape, pose path, schedule, latest avatar and last
//! status, and the steps that run for them: reconstructing their avatar ([`jobs`]) and
//! rendering it. The dispatcher around it routes inputs to persons and results to the outputs;
//! the shared network and renderers are lent to the steps that need them.

mod jobs;
mod pose;
mod refinement;
mod shape;
#[cfg(test)]
mod tests;

pub use jobs::{PersonJob, Reconstruction};
pub use pose::PosePath;
pub use refinement::Refinement;
pub use shape::ShapeState;

use super::render::VirtualCameras;
use super::render::{display_pose, render_frames, unix_now_ns, FrameRenderer, RenderedFrame};
use crate::avatar::Avatar;
use crate::body::{Pose, Skeleton};
use crate::msgs::ReconstructionStatus;
use crate::node::frame_store::{InsertOutcome, PersonViews, StoreLimits, View};
use crate::node::scheduler::{Completion, Job, Schedule, SchedulerConfig, SchedulerError};
use crate::reconstruct::shape::AcceptedShape;
use std::sync::Arc;
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

/// Their latest avatar at the pose their frames show at some moment: what rendering their
/// frames or posing their preview needs, shared with the lane that draws them.
pub struct PosedAvatar {
    /// The avatar (shared, not copied).
    pub current: Arc<Current>,
    /// The pose.
    pub pose: Pose,
    /// The stamp of frames rendered at it ([`Person::frame_stamp_ns`]).
    pub stamp_ns: i64,
}

impl PosedAvatar {
    /// The avatar from every virtual camera.
    pub fn render(
        &self,
        cameras: &VirtualCameras,
        frames: &mut FrameRenderer,
    ) -> Vec<RenderedFrame> {
        render_frames(
            &self.current.avatar,
            &self.current.skeleton,
            &self.pose,
            cameras,
            frames,
        )
    }

    /// The avatar's Gaussians posed (the preview).
    pub fn posed(&self) -> crate::splat::Gaussians {
        let matrices = self.current.skeleton.skinning_matrices(&self.pose);
        self.current.avatar.animate(&matrices)
    }
}

/// One person's state and steps.
pub struct Person {
    views: PersonViews,
    schedule: Schedule,
    /// The body shape their reconstructions use.
    pub shape: ShapeState,
    /// What drives their frames.
    pub pose: PosePath,
    current: Option<Arc<Current>>,
    /// The last status published for them.
    pub last_status: Option<ReconstructionStatus>,
    /// Whether this node reconstructs them (`cluster`); others are only followed.
    owned: bool,
    /// Their next job remakes the current avatar from the same views ([`Person::rerun`]).
    remake: bool,
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
            remake: false,
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
        self.current.as_deref()
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

    /// Reconstructs their views again (to refine the avatar at the end of a replay), when this
    /// node reconstructs them and they have an avatar and nothing pending.
    pub fn rerun(&mut self, now: Duration) {
        if self.owned && self.current.is_some() && !self.views.is_empty() && !self.busy() {
            let arrival = self.views.snapshot().last_arrival().unwrap_or(now);
            self.schedule.rerun(arrival, now);
            self.remake = self.schedule.next_deadline().is_some();
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
    /// views; the job is then failed); with `refine`, its avatar is then refined against the
    /// views under a revision of its own.
    pub fn start(&mut self, job: Job, refine: bool) -> Option<Reconstruction> {
        if self.views.is_empty() {
            let _ = self.schedule.failed(&job.person, job.revision);
            return None;
        }
        Some(Reconstruction {
            job,
            views: self.views.snapshot(),
            shape: self.shape.shape().cloned(),
            refined_revision: refine.then(|| self.schedule.reserve_revision()),
            remakes_current: std::mem::take(&mut self.remake),
        })
    }

    /// Their reconstruction `job` made `current`, published at `now`: it becomes their latest
    /// avatar (it was published, even if the job is no longer theirs to finish: handed to
    /// another cluster member while it ran, the `Err`).
    pub fn finished(
        &mut self,
        job: &Job,
        current: Current,
        now: Duration,
    ) -> Result<Completion, SchedulerError> {
        self.current = Some(Arc::new(current));
        self.schedule.finished(&job.person, job.revision, now)
    }

    /// Their reconstruction `job` ended without a new avatar (it remade the current one and
    /// its refinement did not beat it).
    pub fn finished_unchanged(
        &mut self,
        job: &Job,
        now: Duration,
    ) -> Result<Completion, SchedulerError> {
        self.schedule.finished(&job.person, job.revision, now)
    }

    /// Their reconstruction `job` failed (its revision is spent).
    pub fn failed(&mut self, job: &Job) {
        let _ = self.schedule.failed(&job.person, job.revision);
    }

    /// Their latest avatar at the pose their frames show at `now` (`None`: no avatar yet).
    pub fn posed_at(&self, now: Duration) -> Option<PosedAvatar> {
        let current = self.current.clone()?;
        Some(PosedAvatar {
            current,
            pose: display_pose(self.pose.pose(now), now.as_secs_f32()),
            stamp_ns: self.frame_stamp_ns(now),
        })
    }

    /// The stamp of their frames rendered at `now`: the header stamp of the pose message or
    /// camera frame their pose came from, so that a frame says which moment it shows; the
    /// time now (ns since the epoch) for the walk cycle or an unstamped pose.
    pub fn frame_stamp_ns(&self, now: Duration) -> i64 {
        match self.pose.stamped_pose(now) {
            Some((_, stamp)) if stamp > 0 => stamp,
            _ => unix_now_ns(),
        }
    }

    /// Their latest avatar at `pose` (`None`: no avatar yet), stamped now.
    pub fn posed_as(&self, pose: &Pose) -> Option<PosedAvatar> {
        Some(PosedAvatar {
            current: self.current.clone()?,
            pose: pose.clone(),
            stamp_ns: unix_now_ns(),
        })
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
}
