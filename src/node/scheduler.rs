//! When to (re)reconstruct each person: a pure state machine driven by events and a clock
//! value the caller passes in (time since node start).
//!
//! Rules:
//! - a change of the person's view set arms a debounce; the job starts `debounce` after the
//!   last change, but never later than `max_delay` after the first unhandled change (so a
//!   steady stream of changes cannot starve reconstruction);
//! - at most one reconstruction per person is in flight;
//! - changes that arrive while a job runs are coalesced: when it finishes, only the newest set
//!   runs next (intermediate versions are skipped);
//! - revision numbers strictly increase per person;
//! - a finished job reports its latency: arrival of the newest frame in its set → publish.

use std::collections::BTreeMap;
use std::time::Duration;

/// Scheduler parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct SchedulerConfig {
    /// Quiet time after the last view-set change before a job starts.
    pub debounce: Duration,
    /// Longest wait after the first unhandled change, however often the set keeps changing.
    pub max_delay: Duration,
}

impl Default for SchedulerConfig {
    /// The node's default `frame_store.debounce_ms`.
    fn default() -> Self {
        Self::from_debounce_ms(crate::config::FrameStoreConfig::default().debounce_ms)
    }
}

impl SchedulerConfig {
    /// From the node config's debounce (max delay = 5 × debounce, at least 1 s).
    pub fn from_debounce_ms(debounce_ms: u64) -> Self {
        let debounce = Duration::from_millis(debounce_ms);
        Self {
            debounce,
            max_delay: (debounce * 5).max(Duration::from_secs(1)),
        }
    }
}

/// A reconstruction the caller should start now.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Job {
    /// Person to reconstruct.
    pub person: String,
    /// Revision the result will carry (strictly increasing per person).
    pub revision: u64,
    /// Frame-store version of the view set to use.
    pub set_version: u64,
    /// Arrival of the newest frame in that set.
    pub last_arrival: Duration,
    /// When the job was started.
    pub started: Duration,
}

/// What the caller learns when a job ends.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Completion {
    /// Person reconstructed.
    pub person: String,
    /// Revision published.
    pub revision: u64,
    /// Newest-frame arrival → publish.
    pub latency: Duration,
    /// Job start → publish.
    pub run_time: Duration,
}

/// A scheduler misuse by the caller.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SchedulerError {
    /// `finished`/`failed` for a job that is not in flight.
    #[error("person {person}: revision {revision} is not in flight")]
    NotInFlight {
        /// Person named.
        person: String,
        /// Revision named.
        revision: u64,
    },
}

/// One person's schedule: the [`Scheduler`]'s state for a person, also held on its own by the
/// pipeline's per-person state.
#[derive(Debug, Clone, Default)]
pub struct Schedule {
    cfg: SchedulerConfig,
    /// Newest unhandled change: (set version, newest arrival in it).
    pending: Option<(u64, Duration)>,
    first_change: Duration,
    last_change: Duration,
    in_flight: Option<Job>,
    last_revision: u64,
    started_version: u64,
}

impl Schedule {
    /// Nothing to do yet.
    pub fn new(cfg: SchedulerConfig) -> Self {
        Self {
            cfg,
            ..Self::default()
        }
    }

    /// Forgets everything but the parameters (revisions start again from 1).
    pub fn reset(&mut self) {
        *self = Self::new(self.cfg.clone());
    }

    /// The view set changed to `set_version`, whose newest frame arrived at `last_arrival`;
    /// `now` is the current clock. Older versions than one already seen are ignored.
    pub fn view_set_changed(&mut self, set_version: u64, last_arrival: Duration, now: Duration) {
        if set_version <= self.started_version {
            return;
        }
        match self.pending {
            Some((v, _)) if v >= set_version => return,
            Some(_) => {}
            None => self.first_change = now,
        }
        self.pending = Some((set_version, last_arrival));
        self.last_change = now;
    }

    /// The job for `person` to start at `now`, if one is due (none while one is in flight),
    /// with when its first unhandled change came (the longest waiting goes first).
    pub fn poll(&mut self, person: &str, now: Duration) -> Option<(Duration, Job)> {
        if self.in_flight.is_some() {
            return None;
        }
        let (set_version, last_arrival) = self.pending?;
        if now < self.due() {
            return None;
        }
        self.pending = None;
        self.last_revision += 1;
        self.started_version = set_version;
        let job = Job {
            person: person.to_owned(),
            revision: self.last_revision,
            set_version,
            last_arrival,
            started: now,
        };
        self.in_flight = Some(job.clone());
        Some((self.first_change, job))
    }

    /// Whether a job is in flight.
    pub fn busy(&self) -> bool {
        self.in_flight.is_some()
    }

    /// Earliest clock value at which [`poll`](Self::poll) may start a job, if one is pending.
    pub fn next_deadline(&self) -> Option<Duration> {
        (self.in_flight.is_none() && self.pending.is_some()).then(|| self.due())
    }

    /// `person`'s job finished and its result was published at `now`.
    pub fn finished(
        &mut self,
        person: &str,
        revision: u64,
        now: Duration,
    ) -> Result<Completion, SchedulerError> {
        let job = self.take_in_flight(person, revision)?;
        Ok(Completion {
            person: job.person,
            revision,
            latency: now.saturating_sub(job.last_arrival),
            run_time: now.saturating_sub(job.started),
        })
    }

    /// `person`'s job failed; its revision is spent. A change that came in meanwhile still
    /// runs next; the failed set itself is not retried.
    pub fn failed(&mut self, person: &str, revision: u64) -> Result<(), SchedulerError> {
        self.take_in_flight(person, revision).map(|_| ())
    }

    /// The job in flight, if any.
    pub fn in_flight(&self) -> Option<&Job> {
        self.in_flight.as_ref()
    }

    /// Last revision handed out (0 before the first).
    pub fn last_revision(&self) -> u64 {
        self.last_revision
    }

    fn take_in_flight(&mut self, person: &str, revision: u64) -> Result<Job, SchedulerError> {
        match &self.in_flight {
            Some(job) if job.revision == revision => Ok(self.in_flight.take().expect("checked")),
            _ => Err(SchedulerError::NotInFlight {
                person: person.into(),
                revision,
            }),
        }
    }

    /// When a pending change becomes due.
    fn due(&self) -> Duration {
        (self.last_change + self.cfg.debounce).min(self.first_change + self.cfg.max_delay)
    }
}

/// Decides when each person is reconstructed.
#[derive(Debug, Default)]
pub struct Scheduler {
    cfg: SchedulerConfig,
    persons: BTreeMap<String, Schedule>,
}

impl Scheduler {
    /// An idle scheduler.
    pub fn new(cfg: SchedulerConfig) -> Self {
        Self {
            cfg,
            persons: BTreeMap::new(),
        }
    }

    /// The person's view set changed to `set_version`, whose newest frame arrived at
    /// `last_arrival`; `now` is the current clock. Older versions than one already seen are ignored.
    pub fn view_set_changed(
        &mut self,
        person: &str,
        set_version: u64,
        last_arrival: Duration,
        now: Duration,
    ) {
        self.persons
            .entry(person.to_owned())
            .or_insert_with(|| Schedule::new(self.cfg.clone()))
            .view_set_changed(set_version, last_arrival, now);
    }

    /// Jobs to start at `now` (each person at most one, none while one is in flight), the
    /// person whose view set changed longest ago first.
    pub fn poll(&mut self, now: Duration) -> Vec<Job> {
        first_waiting_first(
            self.persons
                .iter_mut()
                .filter_map(|(person, p)| p.poll(person, now))
                .collect(),
        )
    }

    /// Forgets `person` (no longer tracked): a pending change is dropped; returns whether the
    /// person was known.
    pub fn forget(&mut self, person: &str) -> bool {
        self.persons.remove(person).is_some()
    }

    /// Whether a job is in flight for anyone.
    pub fn busy(&self) -> bool {
        self.persons.values().any(Schedule::busy)
    }

    /// Earliest clock value at which [`poll`](Self::poll) may start a job, if any is pending.
    pub fn next_deadline(&self) -> Option<Duration> {
        self.persons
            .values()
            .filter_map(Schedule::next_deadline)
            .min()
    }

    /// The job finished and its result was published at `now`.
    pub fn finished(
        &mut self,
        person: &str,
        revision: u64,
        now: Duration,
    ) -> Result<Completion, SchedulerError> {
        self.schedule(person, revision)?
            .finished(person, revision, now)
    }

    /// The job failed; its revision is spent. A change that came in meanwhile still runs next;
    /// the failed set itself is not retried.
    pub fn failed(&mut self, person: &str, revision: u64) -> Result<(), SchedulerError> {
        self.schedule(person, revision)?.failed(person, revision)
    }

    /// The job in flight for `person`, if any.
    pub fn in_flight(&self, person: &str) -> Option<&Job> {
        self.persons.get(person).and_then(Schedule::in_flight)
    }

    /// Last revision handed out for `person` (0 before the first).
    pub fn last_revision(&self, person: &str) -> u64 {
        self.persons.get(person).map_or(0, Schedule::last_revision)
    }

    fn schedule(&mut self, person: &str, revision: u64) -> Result<&mut Schedule, SchedulerError> {
        self.persons
            .get_mut(person)
            .ok_or_else(|| SchedulerError::NotInFlight {
                person: person.into(),
                revision,
            })
    }
}

/// Due jobs with when each one's first unhandled change came, ordered the longest waiting
/// first (ties keep their order).
pub fn first_waiting_first(mut jobs: Vec<(Duration, Job)>) -> Vec<Job> {
    jobs.sort_by_key(|(first_change, _)| *first_change);
    jobs.into_iter().map(|(_, job)| job).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(v: u64) -> Duration {
        Duration::from_millis(v)
    }

    fn sched() -> Scheduler {
        Scheduler::new(SchedulerConfig {
            debounce: ms(100),
            max_delay: ms(500),
        })
    }

    #[test]
    fn job_waits_for_the_debounce() {
        let mut s = sched();
        s.view_set_changed("p", 1, ms(0), ms(0));
        assert!(s.poll(ms(99)).is_empty());
        assert_eq!(s.next_deadline(), Some(ms(100)));
        let jobs = s.poll(ms(100));
        assert_eq!(jobs.len(), 1);
        assert_eq!((jobs[0].revision, jobs[0].set_version), (1, 1));
    }

    /// Several persons due at once: the one whose view set changed longest ago goes first,
    /// whatever the ids' order; a forgotten person's pending change never runs.
    #[test]
    fn the_longest_waiting_person_goes_first() {
        let mut s = sched();
        s.view_set_changed("person_9", 1, ms(0), ms(0));
        s.view_set_changed("person_1", 1, ms(40), ms(40));
        s.view_set_changed("person_5", 1, ms(20), ms(20));
        s.view_set_changed("person_7", 1, ms(10), ms(10));
        assert!(s.forget("person_7"));
        let order: Vec<String> = s.poll(ms(200)).into_iter().map(|j| j.person).collect();
        assert_eq!(order, ["person_9", "person_5", "person_1"]);
        assert!(s.busy());
        assert!(!s.forget("nobody"));
    }

    #[test]
    fn steady_changes_cannot_starve_reconstruction() {
        let mut s = sched();
        let mut started = None;
        for t in (0..2000).step_by(50) {
            s.view_set_changed("p", t / 50 + 1, ms(t), ms(t));
            if let Some(job) = s.poll(ms(t)).pop() {
                started = Some(job.started);
                break;
            }
        }
        assert_eq!(started, Some(ms(500)));
    }

    #[test]
    fn one_job_in_flight_and_only_the_newest_set_runs_next() {
        let mut s = sched();
        s.view_set_changed("p", 1, ms(0), ms(0));
        let first = s.poll(ms(100)).pop().unwrap();
        // Versions 2..=5 arrive while job 1 runs: nothing starts.
        for v in 2..=5 {
            s.view_set_changed("p", v, ms(100 + v * 10), ms(100 + v * 10));
            assert!(s.poll(ms(400 + v)).is_empty());
        }
        assert_eq!(s.in_flight("p").map(|j| j.revision), Some(1));
        let done = s.finished("p", first.revision, ms(600)).unwrap();
        assert_eq!(done.latency, ms(600));
        assert_eq!(done.run_time, ms(500));
        let next = s.poll(ms(600)).pop().unwrap();
        assert_eq!((next.revision, next.set_version), (2, 5));
        assert_eq!(next.last_arrival, ms(150));
    }

    #[test]
    fn stale_or_repeated_versions_do_not_rerun() {
        let mut s = sched();
        s.view_set_changed("p", 3, ms(0), ms(0));
        let job = s.poll(ms(100)).pop().unwrap();
        s.finished("p", job.revision, ms(200)).unwrap();
        s.view_set_changed("p", 3, ms(0), ms(250));
        s.view_set_changed("p", 2, ms(0), ms(250));
        assert!(s.poll(ms(10_000)).is_empty());
        assert_eq!(s.next_deadline(), None);
    }

    #[test]
    fn finishing_a_job_that_is_not_in_flight_is_an_error() {
        let mut s = sched();
        assert!(s.finished("p", 1, ms(0)).is_err());
        s.view_set_changed("p", 1, ms(0), ms(0));
        let job = s.poll(ms(100)).pop().unwrap();
        assert!(s.finished("p", job.revision + 1, ms(0)).is_err());
        s.failed("p", job.revision).unwrap();
        assert!(s.in_flight("p").is_none());
        // The failed set is not retried, a newer one runs with a new revision.
        assert!(s.poll(ms(1000)).is_empty());
        s.view_set_changed("p", 2, ms(1000), ms(1000));
        assert_eq!(s.poll(ms(1100)).pop().unwrap().revision, 2);
    }

    #[test]
    fn persons_are_scheduled_independently() {
        let mut s = sched();
        s.view_set_changed("a", 1, ms(0), ms(0));
        s.view_set_changed("b", 1, ms(50), ms(50));
        let jobs = s.poll(ms(100));
        assert_eq!(
            jobs.iter().map(|j| j.person.as_str()).collect::<Vec<_>>(),
            vec!["a"]
        );
        let jobs = s.poll(ms(150));
        assert_eq!(
            jobs.iter().map(|j| j.person.as_str()).collect::<Vec<_>>(),
            vec!["b"]
        );
    }
}
