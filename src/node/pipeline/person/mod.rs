//! One person the pipeline follows (the configured `person_id` without tracking, each tracked
//! person with it): their frame store, body shape, pose path, schedule, latest avatar and last
//! status, and the steps that run for them: reconstructing their avatar ([`jobs`]) and
//! rendering it. The dispatcher around it routes inputs to persons and results to the outputs;
//! the shared network and renderers are lent to the steps that need them.

mod jobs;
mod pose;
mod shape;

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::PoseSource;
    use crate::reconstruct::preprocess::{BBox, Preprocessed};
    use std::sync::Arc;

    /// A view from `camera` with an embedding of its own (no two are duplicates).
    fn view(frame_id: u64, camera: &str) -> View {
        let mut embedding = vec![0.0; 8];
        embedding[frame_id as usize % 8] = 1.0;
        View {
            frame_id,
            camera: camera.into(),
            stamp_ns: frame_id as i64,
            arrival: Duration::from_millis(frame_id * 100),
            image: Arc::new(Preprocessed {
                height: 2,
                width: 2,
                chw: vec![0.5; 12],
                region: BBox {
                    x0: 0,
                    y0: 0,
                    x1: 2,
                    y1: 2,
                },
            }),
            embedding,
            evidence: None,
            hidden: 0.0,
        }
    }

    fn person() -> Person {
        Person::new(
            StoreLimits::default(),
            SchedulerConfig::from_debounce_ms(100),
            PosePath::new(PoseSource::Walk, None),
            true,
        )
    }

    #[test]
    fn a_camera_that_takes_up_someone_else_loses_its_views_and_the_rest_are_rebuilt() {
        let mut p = person();
        for (id, camera) in [(1, "/cam0"), (2, "/cam1"), (3, "/cam0"), (4, "/cam1")] {
            assert!(p
                .add_view(view(id, camera), Duration::from_millis(id * 100))
                .changed());
        }
        // Their first avatar is made of the four views.
        let (_, job) = p
            .poll("p", Duration::from_secs(2))
            .expect("a job after the debounce");
        let first = p.start(job.clone()).expect("views held");
        assert_eq!(first.views.views.len(), 4);
        p.failed(&job);

        let dropped = p.drop_camera("/cam0", Duration::from_secs(3));
        assert_eq!(dropped, vec![1, 3]);
        assert_eq!(p.frame_ids().collect::<Vec<_>>(), vec![2, 4]);
        assert!(p.drop_camera("/cam2", Duration::from_secs(3)).is_empty());
        // The next avatar is made of the other camera's views alone.
        let (_, job) = p
            .poll("p", Duration::from_secs(5))
            .expect("the view set changed: a job");
        let next = p.start(job).expect("views held");
        let cameras: Vec<&str> = next.views.views.iter().map(|v| v.camera.as_str()).collect();
        assert_eq!(cameras, ["/cam1", "/cam1"]);
    }

    #[test]
    fn when_only_that_camera_gave_views_the_store_is_empty_until_the_new_persons_come() {
        let mut p = person();
        for id in 1..=3 {
            p.add_view(view(id, "/cam0"), Duration::from_millis(id * 100));
        }
        assert_eq!(
            p.drop_camera("/cam0", Duration::from_secs(1)),
            vec![1, 2, 3]
        );
        assert_eq!(p.views_held(), 0);
        // A job due for the views before finds none: it fails, nothing is made of them.
        if let Some((_, job)) = p.poll("p", Duration::from_secs(2)) {
            assert!(p.start(job).is_none());
        }
        p.add_view(view(4, "/cam0"), Duration::from_secs(3));
        let (_, job) = p
            .poll("p", Duration::from_secs(5))
            .expect("a job for the new views");
        let next = p.start(job).expect("views held");
        assert_eq!(next.views.views.len(), 1);
        assert_eq!(next.views.views[0].frame_id, 4);
    }
}
