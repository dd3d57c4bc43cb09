//! Hands the heap's free pages back to the operating system now and then, on a thread of its
//! own, while the node runs live.
//!
//! A long run frees as much as it allocates (heaptrack: the live heap stays flat), but glibc's
//! allocator returns a free page to the system only when it lies at the top of its arena. The
//! node's threads (perception, the jobs lane, DDS) each allocate in an arena of their own, and
//! the pages freed in the middle of those arenas stay resident: resident memory crept about
//! 1 MB a minute in a 10-minute soak with a flat heap. `malloc_trim` releases them.

use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

/// How often the free pages go back: a minute of creep is about 1 MB.
pub const TRIM_PERIOD: Duration = Duration::from_secs(30);

/// Environment variable that sets the period in seconds (`0`: no trimming, for comparison).
pub const TRIM_PERIOD_ENV: &str = "LHMPP_HEAP_TRIM_S";

/// The trimming period: [`TRIM_PERIOD_ENV`] when set to a number of seconds (`None` for 0),
/// else [`TRIM_PERIOD`].
pub fn trim_period() -> Option<Duration> {
    match std::env::var(TRIM_PERIOD_ENV)
        .ok()
        .map(|v| v.trim().parse::<f64>())
    {
        Some(Ok(s)) if s.is_finite() && s > 0.0 => Some(Duration::from_secs_f64(s)),
        Some(Ok(0.0)) => None,
        Some(_) => {
            tracing::warn!("{TRIM_PERIOD_ENV}: not a number of seconds; trimming every 30 s");
            Some(TRIM_PERIOD)
        }
        None => Some(TRIM_PERIOD),
    }
}

/// The thread that trims the heap every period until dropped.
pub struct MemoryTrimmer {
    stop: Arc<(Mutex<bool>, Condvar)>,
    thread: Option<JoinHandle<()>>,
}

impl MemoryTrimmer {
    /// Starts trimming every `period` (the first after one period).
    pub fn start(period: Duration) -> Self {
        let stop = Arc::new((Mutex::new(false), Condvar::new()));
        let theirs = stop.clone();
        let thread = std::thread::Builder::new()
            .name("lhmpp-trim".into())
            .spawn(move || {
                let (lock, wake) = &*theirs;
                let mut stopped = lock.lock().expect("trimmer lock poisoned");
                loop {
                    let (guard, timeout) = wake
                        .wait_timeout(stopped, period)
                        .expect("trimmer lock poisoned");
                    stopped = guard;
                    if *stopped {
                        return;
                    }
                    if timeout.timed_out() {
                        let released = trim();
                        tracing::trace!(released, "heap trimmed");
                    }
                }
            })
            .ok();
        if thread.is_none() {
            tracing::warn!("could not start the heap trimmer: resident memory may creep");
        }
        Self { stop, thread }
    }
}

impl Drop for MemoryTrimmer {
    fn drop(&mut self) {
        *self.stop.0.lock().expect("trimmer lock poisoned") = true;
        self.stop.1.notify_all();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Returns the heap's free pages to the system; whether any were released.
pub fn trim() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: malloc_trim only walks the allocator's own free lists under its locks.
        unsafe { libc::malloc_trim(0) != 0 }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_trimmer_stops_when_dropped() {
        let t = MemoryTrimmer::start(Duration::from_millis(5));
        std::thread::sleep(Duration::from_millis(20));
        let started = std::time::Instant::now();
        drop(t);
        assert!(started.elapsed() < Duration::from_secs(1));
    }
}
