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
use super::person::{Current, PersonJob, Refinement};
use super::Pipeline;
use crate::avatar::Avatar;
use crate::body::Skeleton;
use crate::config::Delight;
use crate::msgs::ReconstructionStatus;
use crate::node::outputs::{AvatarUpdate, Fanout, Publisher};
use crate::node::scheduler::Job;
use crate::reconstruct::shape::AcceptedShape;
use crate::reconstruct::{ReconstructError, Reconstructor};
use crate::refine::{RefineConfig, RefineReport};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// Persons' jobs that may wait for the network at once; the scheduler starts one per person,
/// so more means persons released and made again while their job ran.
pub(super) const JOBS_WAITING: usize = 64;

/// How each job's avatar is refined against its views after the network made it
/// (`refine.*`), and what stops a fit early.
#[derive(Clone)]
pub(super) struct RefinePlan {
    /// The fit's settings.
    pub config: RefineConfig,
    /// Grows with every change of any person's view set and every job started: a fit stops
    /// at its next check when it moved (keeping its best so far), so that new views and other
    /// persons' reconstructions never wait behind it.
    pub news: Arc<AtomicU64>,
    /// `news` when the job was started: anything after it stops the job's fit.
    pub since: u64,
}

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
    /// how it went; `colours` recolours the avatar from the views (`perception.colours_from_views`);
    /// with `refine` (and a revision reserved by `work`), the avatar is then fitted to the
    /// views and published again when the fit improved it.
    fn task(
        &self,
        work: impl PersonJob,
        outputs: Arc<Fanout>,
        colours: Option<Delight>,
        refine: Option<RefinePlan>,
    ) -> impl FnOnce() -> JobDone + Send + 'static {
        let recon = self.recon.clone();
        let forgotten = self.forgotten.clone();
        let rgb_display_ready = self.rgb_display_ready;
        let neural_renderer = self.neural_renderer_id.clone();
        move || {
            let mut recon = lock(&recon);
            forget_all(&mut recon, &mut lock(&forgotten));
            let outcome = work.run(&mut recon, colours).map(|made| {
                let skeleton = recon.template().skeleton.clone();
                let shape_params = recon.shape().map_or_else(Vec::new, AcceptedShape::params);
                let publish = |avatar: &Avatar, revision: u64| {
                    outputs.avatar(&AvatarUpdate {
                        person: &work.job().person,
                        revision,
                        views_used: work.view_count(),
                        stamp_ns: work.stamp_ns(),
                        avatar,
                        template: recon.template(),
                        shape_params: &shape_params,
                        rgb_display_ready,
                        neural_renderer: &neural_renderer,
                        compact: Default::default(),
                    })
                };
                // A remake of the current avatar is not published again: only its refinement.
                let remake = work.remakes_current() && work.refined_revision().is_some();
                if !remake {
                    publish(&made.avatar, work.job().revision);
                }
                let mut built = Built {
                    avatar: made.avatar,
                    skeleton,
                    revision: (!remake).then_some(work.job().revision),
                    refined: None,
                    made: Instant::now(),
                };
                let (Some(plan), Some(revision)) = (&refine, work.refined_revision()) else {
                    return built;
                };
                let Some(fit) = Refinement::prepare(
                    &built.avatar,
                    recon.template(),
                    work.views(),
                    made.light.as_ref(),
                    &plan.config,
                ) else {
                    return built;
                };
                match fit.run(&built.avatar, || {
                    plan.news.load(Ordering::Relaxed) != plan.since
                }) {
                    Ok(refined) => {
                        if refined.report.improved {
                            publish(&refined.avatar, revision);
                            built.avatar = refined.avatar;
                            built.revision = Some(revision);
                        }
                        built.refined = Some(refined.report);
                    }
                    Err(e) => tracing::warn!(person = %work.job().person, "refinement: {e}"),
                }
                built
            });
            JobDone {
                views: work.view_count(),
                job: work.job().clone(),
                outcome,
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
    /// The revision it was published under (the job's, or the refinement's; `None`: not
    /// published, a remake of the current avatar that refinement did not improve).
    revision: Option<u64>,
    /// What the refinement did, when it ran.
    refined: Option<RefineReport>,
    /// When the network's avatar was made (and published): the job's latency ends there,
    /// the refinement after it is reported on its own.
    made: Instant,
}

/// What a person's job sends back when it ends.
pub(super) struct JobDone {
    job: Job,
    views: usize,
    outcome: Result<Built, ReconstructError>,
}

impl Pipeline {
    /// Starts `job` (a reconstruction of its person): on the jobs lane, beside the pose path.
    pub(super) fn start_job(&mut self, job: Job) {
        let Some(person) = self.persons.get_mut(&job.person) else {
            return;
        };
        // Live, every job's avatar is refined between reruns; a replay refines only at its end
        // (`refine_at_end`), so that its avatars do not depend on the machine's speed.
        let plan = self
            .refine
            .clone()
            .filter(|_| self.jobs.threaded() || self.refine_inline);
        let Some(work) = person.start(job, plan.is_some()) else {
            return;
        };
        let plan = plan.map(|mut plan| {
            // A fit in flight (another person's) gives the network to this job; a view that
            // comes while this job runs stops its own fit.
            plan.since = plan.news.fetch_add(1, Ordering::Relaxed) + 1;
            plan
        });
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
        let task = self.network.task(work, self.outputs.clone(), colours, plan);
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
            let published = clock().saturating_sub(built.made.elapsed());
            let refined = match &built.refined {
                Some(r) => {
                    let message = refinement_summary(r);
                    tracing::info!(person = %id, revision = built.revision, "{message}");
                    self.stats.refined(r);
                    format!("avatar published; {message}")
                }
                None => "avatar published".to_owned(),
            };
            let Some(revision) = built.revision else {
                let _ = person.finished_unchanged(&job, published);
                let latest = person.revision();
                self.publish_status(&id, latest, 0.0, ReconstructionStatus::STATE_IDLE, refined);
                continue;
            };
            let current = Current {
                revision,
                avatar: built.avatar,
                skeleton: built.skeleton,
            };
            match person.finished(&job, current, published) {
                Ok(done) => {
                    self.stats.reconstructed(done.latency, done.run_time);
                    let latency = done.latency.as_secs_f64() * 1e3;
                    tracing::info!(
                        person = %id,
                        revision,
                        views,
                        latency_ms = format!("{latency:.0}"),
                        run_ms = format!("{:.0}", done.run_time.as_secs_f64() * 1e3),
                        "avatar published"
                    );
                    self.publish_status(
                        &id,
                        revision,
                        latency,
                        ReconstructionStatus::STATE_IDLE,
                        refined,
                    );
                }
                // Handed to another cluster member while it ran: it is theirs now.
                Err(e) => tracing::debug!("scheduler: {e}"),
            }
        }
    }

    /// At the end of a replay: reconstructs every person's views once more with refinement on
    /// (a replay's own jobs are not refined, so that its avatars do not depend on the
    /// machine's speed); the jobs run as the pipeline steps. Whether any was scheduled
    /// (refinement off: none).
    pub fn refine_at_end(&mut self, now: Duration) -> bool {
        if self.refine.is_none() {
            return false;
        }
        self.refine_inline = true;
        for person in self.persons.values_mut() {
            person.rerun(now);
        }
        self.persons.values().any(|p| p.next_deadline().is_some())
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

/// One line on how far a fit went (for the status and the log).
fn refinement_summary(r: &RefineReport) -> String {
    let outcome = if r.improved { "kept" } else { "not kept" };
    format!(
        "refined: {} steps over {} views in {:.1} s ({:?}), held-out loss {:.4} → {:.4}, {} → {} Gaussians, {outcome}",
        r.iterations,
        r.views_fitted,
        r.elapsed.as_secs_f64(),
        r.stop,
        r.held.0,
        r.held.1,
        r.gaussians.0,
        r.gaussians.1,
    )
}
