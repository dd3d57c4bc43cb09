//! Parallel loops for graphs of many small layers: a *team* of the current rayon pool's
//! threads that stays together for a whole network run.
//!
//! A rayon parallel loop per layer pays for waking the pool's other threads and for its task
//! tree on every layer; BlazePose's layers take 10–500 µs each, so at two threads most of the
//! second thread's time went into waiting to be woken. [`with_team`] instead starts one helper
//! job per other pool thread for the length of a closure; the helpers spin between loops, and
//! every [`for_each`] inside the closure (on the calling thread) hands its indices to the
//! team: each thread claims the next index with one atomic add until none are left, and the
//! caller returns when every claimed index is done (pthreadpool's model, as XNNPACK runs).
//! The caller never waits for a helper that has not started — a helper that starts late
//! joins the loops still to come, or finds the team finished — so two networks running at once
//! on one pool cannot deadlock. Outside a team, [`for_each`] runs on rayon.

use std::cell::{Cell, UnsafeCell};
use std::panic::{catch_unwind, resume_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};

use rayon::prelude::*;

/// Bits of the ticket's index and count fields.
const FIELD_BITS: u32 = 20;
const FIELD_MASK: u64 = (1 << FIELD_BITS) - 1;

/// Spins of a waiting thread between yields of its time slice.
const SPINS_PER_YIELD: u32 = 1 << 12;

/// A loop body with its lifetime erased (see [`Team::run`]).
type Job = *const (dyn Fn(usize) + Sync);

/// The shared state of one team.
struct Team {
    /// `generation << 40 | count << 20 | next index` of the current loop.
    ticket: AtomicU64,
    /// Indices of the current loop finished.
    done: AtomicUsize,
    /// The current loop's body; written by the caller only while no index is claimable.
    job: UnsafeCell<Option<Job>>,
    /// Set when the closure of [`with_team`] has returned.
    stop: AtomicBool,
    /// A panic of a helper, re-raised by the caller.
    panic: std::sync::Mutex<Option<Box<dyn std::any::Any + Send>>>,
    /// Threads in the team (the caller included).
    threads: usize,
    /// The generation of the current loop (caller only).
    generation: Cell<u64>,
}

// SAFETY: `job` and `generation` are written only by the thread that owns the team (the
// caller of `with_team`); `job` is read by helpers only between a successful claim of an index
// of the current loop and the matching `done` increment, during which the caller does not
// write it (it waits for `done` to reach the count first).
unsafe impl Sync for Team {}

fn unpack(t: u64) -> (u64, usize, usize) {
    (
        t >> (2 * FIELD_BITS),
        ((t >> FIELD_BITS) & FIELD_MASK) as usize,
        (t & FIELD_MASK) as usize,
    )
}

/// Waits a little, yielding the time slice now and then (the other thread may share a core).
#[inline]
fn pause(spins: &mut u32) {
    *spins += 1;
    if *spins % SPINS_PER_YIELD == 0 {
        std::thread::yield_now();
    } else {
        std::hint::spin_loop();
    }
}

impl Team {
    /// Claims the next index of the current loop, if any is left.
    #[inline]
    fn claim(&self) -> Option<usize> {
        let (_, count, next) = unpack(self.ticket.fetch_add(1, Ordering::AcqRel));
        (next < count).then_some(next)
    }

    /// Runs `f(i)` for `i < count` on the team; returns when every index is done.
    fn run(&self, count: usize, f: &(dyn Fn(usize) + Sync)) {
        assert!(
            count < (1 << FIELD_BITS) - 1024,
            "team loop: too many indices"
        );
        let generation = self.generation.get() + 1;
        self.generation.set(generation);
        self.done.store(0, Ordering::Relaxed);
        // SAFETY: every index of the previous loop is done, so no helper reads `job` now; the
        // pointer is cleared again below before `f` goes out of scope.
        unsafe {
            let erased: &'static (dyn Fn(usize) + Sync) = std::mem::transmute(f);
            *self.job.get() = Some(erased as Job);
        }
        self.ticket.store(
            generation << (2 * FIELD_BITS) | (count as u64) << FIELD_BITS,
            Ordering::Release,
        );
        let mut caught = None;
        while let Some(i) = self.claim() {
            if caught.is_none() {
                if let Err(p) = catch_unwind(AssertUnwindSafe(|| f(i))) {
                    caught = Some(p);
                }
            }
            self.done.fetch_add(1, Ordering::Release);
        }
        let mut spins = 0;
        while self.done.load(Ordering::Acquire) < count {
            pause(&mut spins);
        }
        // SAFETY: every index is done: no helper reads `job` until the next loop.
        unsafe { *self.job.get() = None };
        if let Some(p) = caught.or_else(|| self.panic.lock().ok().and_then(|mut p| p.take())) {
            resume_unwind(p);
        }
    }

    /// A helper's life: claim indices of each loop as it comes until the team stops.
    fn help(&self) {
        let mut spins = 0;
        loop {
            let (_, count, next) = unpack(self.ticket.load(Ordering::Acquire));
            if next < count {
                if let Some(i) = self.claim() {
                    // SAFETY: index `i` of the current loop is claimed and not yet done, so
                    // the caller keeps `job` (and the closure it points at) alive.
                    let f = unsafe { &*(*self.job.get()).expect("a loop is running") };
                    if let Err(p) = catch_unwind(AssertUnwindSafe(|| f(i))) {
                        if let Ok(mut slot) = self.panic.lock() {
                            slot.get_or_insert(p);
                        }
                    }
                    self.done.fetch_add(1, Ordering::Release);
                }
                spins = 0;
                continue;
            }
            if self.stop.load(Ordering::Acquire) {
                return;
            }
            pause(&mut spins);
        }
    }
}

thread_local! {
    /// The team this thread leads, while inside [`with_team`].
    static CURRENT: Cell<*const Team> = const { Cell::new(std::ptr::null()) };
}

/// Runs `body` with a team of the current rayon pool's threads (see the module docs); on a
/// pool of one thread, or inside another team, just runs it.
pub fn with_team<R>(body: impl FnOnce() -> R) -> R {
    let threads = rayon::current_num_threads();
    if threads <= 1 || !CURRENT.with(|c| c.get().is_null()) {
        return body();
    }
    let team = Team {
        ticket: AtomicU64::new(0),
        done: AtomicUsize::new(0),
        job: UnsafeCell::new(None),
        stop: AtomicBool::new(false),
        panic: std::sync::Mutex::new(None),
        threads,
        generation: Cell::new(0),
    };
    rayon::in_place_scope(|scope| {
        for _ in 1..threads {
            let team = &team;
            scope.spawn(move |_| team.help());
        }
        struct Leave<'a>(&'a Team);
        impl Drop for Leave<'_> {
            fn drop(&mut self) {
                CURRENT.with(|c| c.set(std::ptr::null()));
                self.0.stop.store(true, Ordering::Release);
            }
        }
        CURRENT.with(|c| c.set(&team));
        let _leave = Leave(&team);
        body()
    })
}

/// Threads that share the work of a loop started here: the team's size inside
/// [`with_team`], else the rayon pool's.
pub fn threads() -> usize {
    let team = CURRENT.with(|c| c.get());
    if team.is_null() {
        rayon::current_num_threads()
    } else {
        // SAFETY: the pointer is set only while the team lives (inside `with_team`).
        unsafe { (*team).threads }
    }
}

/// Whether a loop started here runs on a team.
pub fn in_team() -> bool {
    !CURRENT.with(|c| c.get().is_null())
}

/// Runs `f(i)` for every `i < count`: on this thread's team inside [`with_team`], else on the
/// rayon pool; returns when all are done.
pub fn for_each(count: usize, f: impl Fn(usize) + Sync) {
    match count {
        0 => {}
        1 => f(0),
        _ => {
            let team = CURRENT.with(|c| c.get());
            if team.is_null() {
                (0..count).into_par_iter().for_each(&f);
            } else {
                // SAFETY: the pointer is set only while the team lives (inside `with_team`).
                unsafe { (*team).run(count, &f) };
            }
        }
    }
}

/// Work (multiply-adds, or values moved) below which a team loop runs as one task.
const TEAM_MIN_TASK: usize = 1 << 15;

/// Items per task of a loop over `items` items costing `cost` in all (multiply-adds or values
/// moved): one task on one thread or below twice the minimum task, else up to four tasks per
/// thread of at least the minimum each — on a team the minimum is [`TEAM_MIN_TASK`] (a claim
/// costs one atomic add), on rayon `rayon_min` — in multiples of `align` items. Of four, two
/// and one task per thread, the split whose busiest thread (tasks taken in turn) has the
/// fewest items wins, ties going to more tasks: rounding to `align` can otherwise leave the
/// threads uneven (14 rows in tasks of 2: 8 rows against 6, where tasks of 7 split evenly).
pub fn items_per_task(items: usize, cost: usize, rayon_min: usize, align: usize) -> usize {
    let threads = threads();
    let min = if in_team() { TEAM_MIN_TASK } else { rayon_min };
    if threads == 1 || cost < 2 * min || items == 0 {
        return items.max(1);
    }
    let max_tasks = (cost / min).clamp(1, 4 * threads);
    let align = align.max(1);
    let mut best = (usize::MAX, items);
    for per_thread in [4, 2, 1] {
        let tasks = (threads * per_thread).min(max_tasks);
        let per = (items.div_ceil(tasks).div_ceil(align) * align).max(1);
        let busiest = busiest_share(items, per, threads);
        if busiest < best.0 {
            best = (busiest, per);
        }
    }
    best.1
}

/// The most items one of `threads` threads gets when tasks of `per` items (the last one
/// shorter) are taken in turn.
fn busiest_share(items: usize, per: usize, threads: usize) -> usize {
    let tasks = items.div_ceil(per);
    (0..threads.min(tasks))
        .map(|t| {
            (t..tasks)
                .step_by(threads)
                .map(|i| per.min(items - i * per))
                .sum::<usize>()
        })
        .max()
        .unwrap_or(0)
}

/// A pointer that may cross threads (the caller guarantees disjoint use).
pub(crate) struct SendPtr<T>(pub *mut T);
impl<T> Clone for SendPtr<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for SendPtr<T> {}
impl<T> SendPtr<T> {
    /// The pointer (a method, so that closures capture the whole wrapper).
    #[inline(always)]
    pub(crate) fn get(self) -> *mut T {
        self.0
    }
}
// SAFETY: used only for disjoint writes, each index of a loop touching its own range.
unsafe impl<T> Send for SendPtr<T> {}
// SAFETY: as above.
unsafe impl<T> Sync for SendPtr<T> {}

/// Runs `f(i, chunk)` over `out` cut into chunks of `chunk_len` values (the last one
/// shorter), as [`for_each`].
pub fn for_each_chunk<T: Send>(
    out: &mut [T],
    chunk_len: usize,
    f: impl Fn(usize, &mut [T]) + Sync,
) {
    let len = out.len();
    if len == 0 {
        return;
    }
    let chunk_len = chunk_len.max(1);
    let ptr = SendPtr(out.as_mut_ptr());
    for_each(len.div_ceil(chunk_len), |i| {
        let start = i * chunk_len;
        let n = chunk_len.min(len - start);
        // SAFETY: chunk `i` is `start..start + n` of `out`, disjoint from every other chunk,
        // and each index runs once; `out` is borrowed mutably for the whole loop.
        let chunk = unsafe { std::slice::from_raw_parts_mut(ptr.get().add(start), n) };
        f(i, chunk)
    });
}

/// Runs `f(y, row)` over `out` cut into rows of `row_len` values, rows grouped into tasks by
/// [`items_per_task`] (each row costing `row_cost`), as [`for_each`].
pub fn for_each_row<T: Send>(
    out: &mut [T],
    row_len: usize,
    row_cost: usize,
    f: impl Fn(usize, &mut [T]) + Sync,
) {
    let row_len = row_len.max(1);
    let rows = out.len() / row_len;
    let per = items_per_task(rows, rows * row_cost, TEAM_MIN_TASK, 1);
    for_each_chunk(out, per * row_len, |t, chunk| {
        for (i, row) in chunk.chunks_mut(row_len).enumerate() {
            f(t * per + i, row);
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicU32;

    #[test]
    fn team_loops_visit_every_index_once() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        pool.install(|| {
            with_team(|| {
                assert!(in_team());
                assert_eq!(threads(), 3);
                for count in [0, 1, 2, 7, 100, 1000] {
                    let hits: Vec<AtomicU32> = (0..count).map(|_| AtomicU32::new(0)).collect();
                    for_each(count, |i| {
                        hits[i].fetch_add(1, Ordering::Relaxed);
                    });
                    assert!(hits.iter().all(|h| h.load(Ordering::Relaxed) == 1));
                }
                let mut v = vec![0usize; 1001];
                for_each_chunk(&mut v, 10, |i, c| c.iter_mut().for_each(|x| *x = i));
                assert!(v.iter().enumerate().all(|(j, &x)| x == j / 10));
            });
            assert!(!in_team());
        });
    }

    #[test]
    fn task_sizes_split_evenly_between_threads() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        pool.install(|| {
            with_team(|| {
                // 14 rows: two tasks of 7 rather than seven of 2 (8 rows against 6)
                assert_eq!(items_per_task(14, 1 << 22, 1, 1), 7);
                // whole multiples of the alignment, every item covered
                for (items, align) in [(196, 8), (64, 12), (1000, 16), (7, 1), (3, 4)] {
                    let per = items_per_task(items, 1 << 24, 1, align);
                    assert!(per % align == 0 || per == items, "{items} {align}: {per}");
                    assert!(per * items.div_ceil(per) >= items);
                }
            });
        });
        assert_eq!(busiest_share(14, 2, 2), 8);
        assert_eq!(busiest_share(14, 7, 2), 7);
        assert_eq!(busiest_share(10, 4, 3), 4);
    }

    #[test]
    fn concurrent_teams_on_one_pool_finish() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let total = AtomicUsize::new(0);
        pool.install(|| {
            rayon::join(
                || {
                    with_team(|| {
                        for _ in 0..200 {
                            for_each(8, |_| {
                                total.fetch_add(1, Ordering::Relaxed);
                            });
                        }
                    })
                },
                || {
                    with_team(|| {
                        for _ in 0..200 {
                            for_each(8, |_| {
                                total.fetch_add(1, Ordering::Relaxed);
                            });
                        }
                    })
                },
            )
        });
        assert_eq!(total.load(Ordering::Relaxed), 2 * 200 * 8);
    }

    #[test]
    fn a_panic_in_a_loop_reaches_the_caller() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let r = pool.install(|| {
            catch_unwind(AssertUnwindSafe(|| {
                with_team(|| for_each(64, |i| assert!(i != 40, "planted")))
            }))
        });
        assert!(r.is_err());
    }
}
