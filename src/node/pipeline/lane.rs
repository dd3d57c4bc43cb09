//! Lanes of work that run beside the pose path: each person's jobs (reconstruction; refinement
//! between reruns goes the same way) and the rendering of their frames. A lane runs its tasks
//! one at a time, in the order given, and hands back each task's result as a message that the
//! pipeline takes when it likes:
//!
//! - **inline** (bag replay, tests): a task runs at once on the caller's thread, so a replay
//!   gives the same avatars as ever, whatever the machine's speed;
//! - **on a thread of its own** (live): the caller never waits for a task. The lane's thread and
//!   the CPU threads its tasks use (a [`Background`] rayon pool of its own) run at a lower
//!   priority than the pipeline's thread and perception, so on a busy machine the pose path
//!   goes first.
//!
//! Bounded: at most `capacity` tasks wait (a task offered beyond is handed back to the caller),
//! and every task sends back one result.

use std::collections::VecDeque;
use std::sync::mpsc::{self, Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;

/// How much lower the reconstructions' threads' priority is than the thread that starts them
/// (Linux niceness, capped at 19, the lowest).
pub const JOBS_NICENESS: i32 = 10;
/// The same for drawing frames: short work that users see, between the pose path and the
/// reconstructions.
pub const DRAWING_NICENESS: i32 = 5;

/// A task of a lane.
type Task<R> = Box<dyn FnOnce() -> R + Send>;

/// The CPU threads background work computes on: a rayon pool of its own at a lower priority.
/// The network and the rasteriser use rayon, so a task run inside [`Background::install`]
/// computes on these threads, not on the global pool (nor on another lane's: frames are not
/// drawn behind a reconstruction's work).
#[derive(Clone)]
pub struct Background {
    pool: Arc<rayon::ThreadPool>,
    niceness: i32,
}

impl Background {
    /// A pool of `threads` threads (`lhmpp-<name>-<i>`; 0: one per core), each `niceness`
    /// lower in priority than the caller.
    pub fn new(name: &str, threads: usize, niceness: i32) -> Self {
        let threads = match threads {
            0 => std::thread::available_parallelism().map_or(2, |n| n.get()),
            n => n,
        };
        let name = name.to_owned();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(move |i| format!("lhmpp-{name}-{i}"))
            .start_handler(move |_| lower_this_threads_priority(niceness))
            .build()
            .expect("building a background thread pool");
        Self {
            pool: Arc::new(pool),
            niceness,
        }
    }

    /// Runs `f` with this pool as rayon's pool.
    pub fn install<R: Send>(&self, f: impl FnOnce() -> R + Send) -> R {
        self.pool.install(f)
    }
}

/// Lowers the calling thread's CPU priority by `niceness` (Linux: niceness is per thread, and a
/// new thread starts with its creator's; elsewhere nothing changes).
pub fn lower_this_threads_priority(niceness: i32) {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: gettid, getpriority and setpriority only read their arguments; raising
        // one's own niceness needs no privilege.
        let done = unsafe {
            let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
            let now = libc::getpriority(libc::PRIO_PROCESS, tid);
            libc::setpriority(libc::PRIO_PROCESS, tid, (now + niceness).min(19))
        };
        if done != 0 {
            tracing::debug!(
                "lowering a background thread's priority: {}",
                std::io::Error::last_os_error()
            );
        }
    }
}

/// Where a lane's tasks run.
enum Runner<R> {
    /// On the caller's thread, when submitted.
    Inline { done: VecDeque<R> },
    /// On the lane's thread.
    Thread {
        tasks: Option<SyncSender<Task<R>>>,
        results: Receiver<R>,
        thread: Option<JoinHandle<()>>,
    },
}

/// One lane: its tasks in order, inline or on a thread of its own.
pub struct Lane<R> {
    runner: Runner<R>,
    /// Tasks submitted whose result was not taken yet.
    in_flight: usize,
}

/// A task the lane could not take: `capacity` tasks already wait.
pub struct LaneFull;

impl<R: Send + 'static> Lane<R> {
    /// A lane that runs each task on the caller's thread when it is submitted.
    pub fn inline() -> Self {
        Self {
            runner: Runner::Inline {
                done: VecDeque::new(),
            },
            in_flight: 0,
        }
    }

    /// A lane with a thread of its own, `name`, at `background`'s priority, computing on
    /// `background`; at most `capacity` tasks wait.
    pub fn thread(name: &str, capacity: usize, background: Background) -> Self {
        let (tasks, queue) = mpsc::sync_channel::<Task<R>>(capacity.max(1));
        let (done, results) = mpsc::channel();
        let thread = std::thread::Builder::new()
            .name(name.to_owned())
            .spawn(move || {
                lower_this_threads_priority(background.niceness);
                // Ends when the lane is dropped (its sender with it).
                while let Ok(task) = queue.recv() {
                    if done.send(background.install(task)).is_err() {
                        return;
                    }
                }
            })
            .expect("spawning a lane thread");
        Self {
            runner: Runner::Thread {
                tasks: Some(tasks),
                results,
                thread: Some(thread),
            },
            in_flight: 0,
        }
    }

    /// Whether tasks run on a thread of their own.
    pub fn threaded(&self) -> bool {
        matches!(self.runner, Runner::Thread { .. })
    }

    /// Runs `task` (inline: now; else once the tasks before it are done). `Err`: the lane
    /// already holds its capacity of waiting tasks; the task was not taken.
    pub fn submit(&mut self, task: impl FnOnce() -> R + Send + 'static) -> Result<(), LaneFull> {
        match &mut self.runner {
            Runner::Inline { done } => done.push_back(task()),
            Runner::Thread { tasks, .. } => {
                let sender = tasks.as_ref().ok_or(LaneFull)?;
                match sender.try_send(Box::new(task)) {
                    Ok(()) => {}
                    Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                        return Err(LaneFull)
                    }
                }
            }
        }
        self.in_flight += 1;
        Ok(())
    }

    /// The results of the tasks that ended since the last call, in order.
    pub fn take(&mut self) -> Vec<R> {
        let taken: Vec<R> = match &mut self.runner {
            Runner::Inline { done } => done.drain(..).collect(),
            Runner::Thread { results, .. } => results.try_iter().collect(),
        };
        self.in_flight -= taken.len().min(self.in_flight);
        taken
    }

    /// Tasks submitted whose result was not taken yet.
    pub fn in_flight(&self) -> usize {
        self.in_flight
    }
}

impl<R> Drop for Lane<R> {
    /// Lets the running task end (tasks still waiting are dropped unrun), then joins the thread.
    fn drop(&mut self) {
        if let Runner::Thread {
            tasks,
            results,
            thread,
        } = &mut self.runner
        {
            drop(tasks.take());
            // Drain what is queued so that the thread sees the end after its current task.
            while results.try_recv().is_ok() {}
            if let Some(t) = thread.take() {
                let _ = t.join();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::time::{Duration, Instant};

    #[test]
    fn an_inline_lane_runs_each_task_when_submitted() {
        let mut lane = Lane::inline();
        assert!(!lane.threaded());
        lane.submit(|| 1).ok().unwrap();
        lane.submit(|| 2).ok().unwrap();
        assert_eq!(lane.in_flight(), 2);
        assert_eq!(lane.take(), vec![1, 2]);
        assert_eq!(lane.in_flight(), 0);
    }

    /// A slow task on a threaded lane does not hold the caller; the tasks after it run in
    /// order once it ends; a full lane refuses a task instead of blocking.
    #[test]
    fn a_threaded_lane_runs_beside_the_caller_in_order_and_stays_bounded() {
        let release = Arc::new(AtomicBool::new(false));
        let mut lane = Lane::thread("test-lane", 1, Background::new("test", 0, JOBS_NICENESS));
        assert!(lane.threaded());
        let r = release.clone();
        let submitted = Instant::now();
        lane.submit(move || {
            while !r.load(Ordering::SeqCst) {
                std::thread::sleep(Duration::from_millis(1));
            }
            "slow"
        })
        .ok()
        .unwrap();
        assert!(submitted.elapsed() < Duration::from_millis(100));
        // The slow task may or may not have been taken off the queue yet: fill the queue.
        let mut queued = 0;
        while lane.submit(|| "next").is_ok() {
            queued += 1;
            assert!(queued <= 2, "a lane of capacity 1 took {queued} more tasks");
        }
        assert!(
            lane.take().is_empty(),
            "nothing ends while the slow task runs"
        );
        release.store(true, Ordering::SeqCst);
        let mut results = Vec::new();
        let deadline = Instant::now() + Duration::from_secs(10);
        while results.len() < 1 + queued && Instant::now() < deadline {
            results.extend(lane.take());
            std::thread::sleep(Duration::from_millis(1));
        }
        let mut expected = vec!["slow"];
        expected.extend(std::iter::repeat_n("next", queued));
        assert_eq!(results, expected);
        assert_eq!(lane.in_flight(), 0);
    }

    /// Background threads run at a lower priority than the thread that made them.
    #[cfg(target_os = "linux")]
    #[test]
    fn background_threads_run_at_a_lower_priority() {
        let niceness = || unsafe {
            libc::getpriority(
                libc::PRIO_PROCESS,
                libc::syscall(libc::SYS_gettid) as libc::id_t,
            )
        };
        let mine = niceness();
        let mut lane = Lane::thread("test-nice", 1, Background::new("test", 0, JOBS_NICENESS));
        lane.submit(niceness).ok().unwrap();
        let deadline = Instant::now() + Duration::from_secs(10);
        let pool_thread = loop {
            if let Some(r) = lane.take().pop() {
                break r;
            }
            assert!(Instant::now() < deadline);
            std::thread::sleep(Duration::from_millis(1));
        };
        assert_eq!(
            pool_thread,
            (mine + JOBS_NICENESS).min(19),
            "the background pool's niceness (the caller's: {mine})"
        );
    }
}
