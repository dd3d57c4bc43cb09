//! Each person's due job, run on the network all persons share, beside the pose path: the
//! person lends the job a copy of what it reads (any [`PersonJob`]; today the
//! [`Reconstruction`](super::person::Reconstruction) of the views and shape they hold); the
//! job runs on the jobs lane
//! ([`lane`](super::lane): inline in a replay, on a thread of its own live), publishes its
//! avatar to the outputs itself, and sends back a [`JobDone`], which the pipeline takes on its
//! next step: the avatar becomes the person's latest, the status says it was published.
//!
//! The pipeline's thread never waits for the network: what it needs of it (the skeleton poses
//! are checked against, the body model shapes must name) is copied when the network is made,
//! and views that leave a frame store are forgotten by the network before its next job.

use super::lane::LaneFull;
use super::person::{Current, PersonJob};
use super::Pipeline;
use crate::avatar::Avatar;
use crate::body::Skeleton;
use crate::config::Delight;
use crate::msgs::ReconstructionStatus;
use crate::node::outputs::{AvatarUpdate, Fanout, Publisher};
use crate::node::scheduler::Job;
use crate::reconstruct::shape::AcceptedShape;
use crate::reconstruct::{ReconstructError, Reconstructor};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// Persons' jobs that may wait for the network at once; the scheduler starts one per person,
/// so more means persons released and made again while their job ran.
pub(super) const JOBS_WAITING: usize = 64;

/// The network all persons' jobs share, and what the pipeline's thread knows of it without
/// waiting for a job.
pub(super) struct SharedNetwork {
    recon: Arc<Mutex<Reconstructor>>,
    /// Views that left the frame stores, not yet forgotten by the network (it was busy).
    forgotten: Arc<Mutex<Vec<u64>>>,
    /// The body template's skeleton (poses are checked against its bone names, which every
    /// shape of the body keeps).
    skeleton: Skeleton,
    body_model: &'static str,
    rgb_display_ready: bool,
    neural_renderer_id: Arc<str>,
}

impl SharedNetwork {
    /// Shares `recon`.
    pub(super) fn new(recon: Reconstructor) -> Self {
        Self {
            skeleton: recon.template().skeleton.clone(),
            body_model: recon.body_model(),
            rgb_display_ready: recon.rgb_kind().display_ready(),
            neural_renderer_id: recon.neural_renderer_id().into(),
            recon: Arc::new(Mutex::new(recon)),
            forgotten: Arc::new(Mutex::new(Vec::new())),
        }
    }

    /// The skeleton poses are checked against.
    pub(super) fn skeleton(&self) -> &Skeleton {
        &self.skeleton
    }

    /// Body-model id of the avatars (what a body shape must name).
    pub(super) fn body_model(&self) -> &'static str {
        self.body_model
    }

    /// Forgets a view that left a frame store: now when the network is free, else before its
    /// next job (never waiting for the job in flight).
    pub(super) fn forget(&self, frame_id: u64) {
        let mut forgotten = lock(&self.forgotten);
        forgotten.push(frame_id);
        if let Ok(mut recon) = self.recon.try_lock() {
            forget_all(&mut recon, &mut forgotten);
        }
    }

    /// The network, once the job in flight (if any) ends: for the run's summary and tests.
    pub(super) fn wait(&self) -> MutexGuard<'_, Reconstructor> {
        lock(&self.recon)
    }

    /// The task that runs `work` on the network, publishes its avatar to `outputs` and says
    /// how it went; `colours` recolours the avatar from the views (`perception.colours_from_views`).
    fn task(
        &self,
        work: impl PersonJob,
        outputs: Arc<Fanout>,
        colours: Option<Delight>,
    ) -> impl FnOnce() -> JobDone + Send + 'static {
        let recon = self.recon.clone();
        let forgotten = self.forgotten.clone();
        let rgb_display_ready = self.rgb_display_ready;
        let neural_renderer = self.neural_renderer_id.clone();
        move || {
            let mut recon = lock(&recon);
            forget_all(&mut recon, &mut lock(&forgotten));
            let outcome = work.run(&mut recon, colours).map(|avatar| {
                let skeleton = recon.template().skeleton.clone();
                let shape_params = recon.shape().map_or_else(Vec::new, AcceptedShape::params);
                outputs.avatar(&AvatarUpdate {
                    person: &work.job().person,
                    revision: work.job().revision,
                    views_used: work.view_count(),
                    stamp_ns: work.stamp_ns(),
                    avatar: &avatar,
                    template: recon.template(),
                    shape_params: &shape_params,
                    rgb_display_ready,
                    neural_renderer: &neural_renderer,
                    compact: Default::default(),
                });
                Built { avatar, skeleton }
            });
            JobDone {
                views: work.view_count(),
                job: work.job().clone(),
                outcome,
                ended: Instant::now(),
            }
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

fn forget_all(recon: &mut Reconstructor, forgotten: &mut Vec<u64>) {
    for id in forgotten.drain(..) {
        recon.forget(id);
    }
}

/// An avatar a job made (already published).
struct Built {
    avatar: Avatar,
    skeleton: Skeleton,
}

/// What a person's job sends back when it ends.
pub(super) struct JobDone {
    job: Job,
    views: usize,
    outcome: Result<Built, ReconstructError>,
    /// When it ended (its avatar was published just before).
    ended: Instant,
}

impl Pipeline {
    /// Starts `job` (a reconstruction of its person): on the jobs lane, beside the pose path.
    pub(super) fn start_job(&mut self, job: Job) {
        let Some(person) = self.persons.get_mut(&job.person) else {
            return;
        };
        let Some(work) = person.start(job) else {
            return;
        };
        let (id, revision) = (work.job().person.clone(), work.job().revision);
        self.publish_status(
            &id,
            revision.saturating_sub(1),
            0.0,
            ReconstructionStatus::STATE_RECONSTRUCTING,
            "reconstructing",
        );
        let job = work.job().clone();
        let colours = self.colours_from_views.then_some(self.delight);
        let task = self.network.task(work, self.outputs.clone(), colours);
        if let Err(LaneFull) = self.jobs.submit(task) {
            self.job_failed(&job, "too many jobs wait for the network".into());
        }
    }

    /// Takes the jobs that ended: each avatar becomes its person's latest, and their status
    /// says so (or why it failed). `clock` is the node clock now.
    pub(super) fn take_finished_jobs(&mut self, clock: &impl Fn() -> Duration) {
        for done in self.jobs.take() {
            let JobDone {
                job,
                views,
                outcome,
                ended,
            } = done;
            let built = match outcome {
                Ok(built) => built,
                Err(e) => {
                    self.job_failed(&job, e.to_string());
                    continue;
                }
            };
            let id = job.person.clone();
            let Some(person) = self.persons.get_mut(&id) else {
                // Released while the job ran: its avatar was published, nobody keeps it.
                continue;
            };
            let published = clock().saturating_sub(ended.elapsed());
            let current = Current {
                revision: job.revision,
                avatar: built.avatar,
                skeleton: built.skeleton,
            };
            match person.finished(&job, current, published) {
                Ok(done) => {
                    self.stats.reconstructed(done.latency, done.run_time);
                    let latency = done.latency.as_secs_f64() * 1e3;
                    tracing::info!(
                        person = %id,
                        revision = job.revision,
                        views,
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
                // Handed to another cluster member while it ran: it is theirs now.
                Err(e) => tracing::debug!("scheduler: {e}"),
            }
        }
    }

    /// `job` failed because of `reason`: its revision is spent, the status says why.
    fn job_failed(&mut self, job: &Job, reason: String) {
        self.stats.failures += 1;
        tracing::error!(person = %job.person, revision = job.revision, "reconstruction failed: {reason}");
        if let Some(person) = self.persons.get_mut(&job.person) {
            person.failed(job);
        }
        self.publish_status(
            &job.person,
            job.revision,
            0.0,
            ReconstructionStatus::STATE_ERROR,
            reason,
        );
    }
}
