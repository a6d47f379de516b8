//! The crew of a [`Team`](super::Team): the protocol by which the region's driver posts
//! phases to the serving workers and waits for them, and each worker's busy time. Every
//! unsafe step of the team is here; [`super::Team`] runs it on its pool.
//!
//! # The protocol and why it is sound
//!
//! The phase closure lives on the driver's stack and is shared with the serving workers
//! through a raw pointer in the `phase` slot. Three counters order everything:
//!
//! 1. the driver writes the slot, sets `done = 0` and bumps `generation` (Release);
//! 2. a serving worker that sees the bump (Acquire) reads the slot, runs its share (catching
//!    a panic), and increments `done` (Release);
//! 3. the driver runs share 0, then waits until `done` is `workers - 1` (Acquire). A guard
//!    does this wait on every way out of the phase, so a panic in share 0 unwinds only after
//!    the serving workers have stopped using the closure and what it borrows;
//! 4. at the end of the region a guard sets `exit` and bumps `generation` once more, however
//!    the driver's closure left (return or panic), and the serving workers return.
//!
//! The slot is therefore written only while no worker can read it, and the closure outlives
//! every call. The protocol is model-checked with loom (the tests at the bottom, under
//! `--cfg loom`); the ordinary tests check barriers, panics in share 0 and in another share,
//! and that a second entry is refused (in `team.rs`, through the team).

use super::sync::{spin_hint, yield_now, AtomicBool, AtomicU64, AtomicUsize, Mutex, Ordering, UnsafeCell};
use std::any::Any;
use std::ops::DerefMut;
use std::panic::{catch_unwind, resume_unwind, AssertUnwindSafe};
use std::time::Instant;

/// Spin iterations before a waiting worker starts yielding its CPU (about 20-50 µs).
const SPINS: u32 = 1 << 14;
/// Spin iterations when the team has more workers than the machine has hardware threads:
/// a spinning worker would take the CPU from one that has work, so yield almost at once.
const SPINS_OVERSUBSCRIBED: u32 = 64;

/// Wait until `ready()`, spinning `max_spins` times first, then yielding.
#[inline]
fn wait_until(max_spins: u32, ready: impl Fn() -> bool) {
    let mut spins = 0u32;
    while !ready() {
        if spins < max_spins {
            spin_hint();
            spins += 1;
        } else {
            yield_now();
        }
    }
}

/// Lock `m`, also after a panic while it was held (the data is a plain value).
fn lock<T>(m: &Mutex<T>) -> impl DerefMut<Target = T> + '_ {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// One worker's busy time in nanoseconds, alone on its cache lines (each worker writes only
/// its own counter, once per phase; sharing a line would make that a coherence miss).
///
/// A std atomic even under loom: it is accounting, read after the region, not part of the
/// protocol.
#[repr(align(128))]
#[derive(Default)]
struct BusyCounter(std::sync::atomic::AtomicU64);

impl BusyCounter {
    /// Add the time since `start`.
    #[inline]
    fn charge(&self, start: Instant) {
        let ns = u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX);
        self.0.fetch_add(ns, std::sync::atomic::Ordering::Relaxed);
    }
}

/// A posted phase: the phase closure behind a type-erased pointer, and the function that
/// calls it with a share index.
#[derive(Clone, Copy)]
struct Phase {
    closure: *const (),
    call: unsafe fn(*const (), usize),
}

impl Phase {
    fn new<F: Fn(usize) + Sync>(f: &F) -> Self {
        Self { closure: (f as *const F).cast(), call: call_share::<F> }
    }
}

/// Run share `share` of the phase closure at `closure`.
///
/// # Safety
/// `closure` points to a live `F`.
unsafe fn call_share<F: Fn(usize) + Sync>(closure: *const (), share: usize) {
    // SAFETY: a live `F` (the caller's contract), used as a shared reference only, which
    // other threads may hold at the same time because `F: Sync`.
    let f = unsafe { &*closure.cast::<F>() };
    f(share);
}

/// The shared state of a team's `workers` workers: the phase slot, the counters that order
/// it, the entry flag and the busy counters (see the module docs).
pub(super) struct Crew {
    workers: usize,
    spins: u32,
    /// Set while a region runs: a second entry is refused.
    entered: AtomicBool,
    /// Phase generation, bumped by the driver to post a phase (or the end of the region).
    generation: AtomicU64,
    /// Serving workers that finished the current phase.
    done: AtomicUsize,
    /// Set before the last generation bump of a region: the serving workers return.
    exit: AtomicBool,
    /// A serving worker's share panicked in the current phase.
    panicked: AtomicBool,
    /// The first such panic's payload, re-raised on the driver.
    payload: Mutex<Option<Box<dyn Any + Send>>>,
    /// The current phase; written by the driver only between phases.
    phase: UnsafeCell<Option<Phase>>,
    /// Per worker: nanoseconds spent in its shares since the team was made.
    busy: Box<[BusyCounter]>,
}

// SAFETY: the one part of a `Crew` that is not thread-safe by itself is the `phase` slot
// (a plain cell holding a pointer to a `Sync` closure). It is written only by the driver
// between phases: before the Release bump of `generation` that posts the phase, and after
// the driver has seen, with Acquire, every serving worker's Release increment of `done`
// for the previous phase. Serving workers read it only after seeing the bump with Acquire
// and stop using it before their increment. So no read races a write, and the closure may be
// called from several threads at once because it is `Sync` (see the module docs).
unsafe impl Sync for Crew {}
// SAFETY: as above: the pointer in `phase` is dereferenced only under that protocol while its
// region runs, and is never used again after it; nothing else in a `Crew` is tied to a thread.
unsafe impl Send for Crew {}

impl Crew {
    /// A crew of `workers` workers (the thread count of the pool it runs on).
    pub(super) fn new(workers: usize) -> Self {
        assert!(workers >= 1, "a team needs at least one worker");
        let hardware = std::thread::available_parallelism().map_or(1, |n| n.get());
        Self {
            workers,
            spins: if workers > hardware { SPINS_OVERSUBSCRIBED } else { SPINS },
            entered: AtomicBool::new(false),
            generation: AtomicU64::new(0),
            done: AtomicUsize::new(0),
            exit: AtomicBool::new(false),
            panicked: AtomicBool::new(false),
            payload: Mutex::new(None),
            phase: UnsafeCell::new(None),
            busy: (0..workers).map(|_| BusyCounter::default()).collect(),
        }
    }

    /// Number of workers.
    pub(super) fn workers(&self) -> usize {
        self.workers
    }

    /// Seconds each worker has spent running its shares of phases since the team was made
    /// (worker order). Exact once a region has ended.
    pub(super) fn busy_seconds(&self) -> impl ExactSizeIterator<Item = f64> + '_ {
        self.busy.iter().map(|c| c.0.load(std::sync::atomic::Ordering::Relaxed) as f64 * 1e-9)
    }

    /// Take the entry flag for one region, or `None` while a region holds it.
    pub(super) fn enter(&self) -> Option<Entry<'_>> {
        Entry::enter(&self.entered)
    }

    /// Make the crew ready for a region (no worker is serving: the previous region's
    /// broadcast has returned).
    pub(super) fn reset(&self) {
        self.generation.store(0, Ordering::Relaxed);
        self.done.store(0, Ordering::Relaxed);
        self.exit.store(false, Ordering::Relaxed);
        self.panicked.store(false, Ordering::Relaxed);
        *lock(&self.payload) = None;
    }

    /// Driver: run `f(j)` on every worker `j` (share 0 on this thread) and return when all
    /// are done; re-raise the first panic of a serving worker's share.
    ///
    /// # Safety
    /// Only the driver of this crew's current region may call it (the thread that runs the
    /// closure of [`Team::region`](super::Team::region); in the loom model, the thread that
    /// started the serving workers), and not from inside a share of a phase it posted.
    pub(super) unsafe fn run<F: Fn(usize) + Sync>(&self, f: &F) {
        if self.panicked.swap(false, Ordering::Relaxed) {
            // Left from a phase whose share 0 panicked as well (that panic won).
            lock(&self.payload).take();
        }
        let phase = Phase::new(f);
        // SAFETY: no serving worker reads the slot now. A worker reads it only between a
        // generation bump and its own `done` increment, and this driver has seen every
        // increment of its previous phase (the `PhaseEnd` wait) or posted none yet.
        self.phase.with_mut(|slot| unsafe { *slot = Some(phase) });
        self.done.store(0, Ordering::Relaxed);
        self.generation.fetch_add(1, Ordering::Release);
        // From here the serving workers may call `f`, which lives on the caller's stack with
        // everything it borrows, until each has incremented `done`. So this function must
        // neither return nor unwind (if share 0 panics) before that: `end` waits for it on
        // every way out.
        let end = PhaseEnd(self);
        let start = Instant::now();
        f(0);
        self.busy[0].charge(start);
        drop(end);
        if self.panicked.swap(false, Ordering::Relaxed) {
            let payload = lock(&self.payload).take();
            resume_unwind(payload.unwrap_or_else(|| Box::new("a worker of the team panicked in a parallel phase")));
        }
    }

    /// Driver: end the region; the serving workers return from [`Crew::serve`].
    fn finish(&self) {
        self.exit.store(true, Ordering::Relaxed);
        self.generation.fetch_add(1, Ordering::Release);
    }

    /// Serving worker `me`: run share `me` of every posted phase until [`Crew::finish`].
    ///
    /// # Safety
    /// Called once per region for each `me` in `1..workers`, each on its own thread, after
    /// [`Crew::reset`] and while the region's driver runs (it returns after `finish`).
    pub(super) unsafe fn serve(&self, me: usize) {
        let mut seen = 0u64;
        loop {
            wait_until(self.spins, || self.generation.load(Ordering::Acquire) != seen);
            seen = self.generation.load(Ordering::Acquire);
            if self.exit.load(Ordering::Relaxed) {
                return;
            }
            // SAFETY: the Acquire load above synchronises with the driver's Release bump,
            // after which the slot holds this phase and is not written again before this
            // worker's `done` increment below.
            let phase = self.phase.with(|slot| unsafe { *slot });
            let phase = phase.expect("a phase is posted with every generation before the exit");
            let start = Instant::now();
            // SAFETY: the driver keeps the phase closure alive (`run` neither returns nor
            // unwinds) until this worker has incremented `done`, below.
            let outcome = catch_unwind(AssertUnwindSafe(|| unsafe { (phase.call)(phase.closure, me) }));
            self.busy[me].charge(start);
            if let Err(payload) = outcome {
                lock(&self.payload).get_or_insert(payload);
                self.panicked.store(true, Ordering::Relaxed);
            }
            self.done.fetch_add(1, Ordering::Release);
        }
    }
}

/// Holds a crew's entry flag for one region.
pub(super) struct Entry<'t>(&'t AtomicBool);

impl<'t> Entry<'t> {
    /// Take the flag, or `None` if a region holds it.
    fn enter(flag: &'t AtomicBool) -> Option<Self> {
        // Build the guard only on success: a guard dropped on failure would release the
        // region that holds the flag.
        let won = flag.compare_exchange(false, true, Ordering::Acquire, Ordering::Relaxed).is_ok();
        won.then(|| Entry(flag))
    }
}

impl Drop for Entry<'_> {
    fn drop(&mut self) {
        self.0.store(false, Ordering::Release);
    }
}

/// Ends the region when dropped (on the driver, by return or unwinding).
pub(super) struct RegionEnd<'t>(pub(super) &'t Crew);

impl Drop for RegionEnd<'_> {
    fn drop(&mut self) {
        self.0.finish();
    }
}

/// Waits, when dropped, until every serving worker has finished the current phase.
struct PhaseEnd<'t>(&'t Crew);

impl Drop for PhaseEnd<'_> {
    fn drop(&mut self) {
        let team = self.0;
        let others = team.workers - 1;
        wait_until(team.spins, || team.done.load(Ordering::Acquire) == others);
    }
}

/// Model checks of the protocol: `RUSTFLAGS="--cfg loom" cargo test -p mpm-core --lib
/// parallel::` (see scripts/test.sh). Loom runs every interleaving of the driver and the
/// serving threads under the C++ memory model (no preemption bound unless
/// `LOOM_MAX_PREEMPTIONS` sets one) and fails on any unsynchronised access to the `phase`
/// slot or to a test cell.
#[cfg(all(test, loom))]
mod loom_tests {
    use super::*;
    use loom::sync::Arc;

    /// Cells the shares of a phase access; loom checks every access for races.
    struct Cells<const N: usize>([UnsafeCell<usize>; N]);

    // SAFETY: test data whose accesses loom checks: a racy access fails the model.
    unsafe impl<const N: usize> Sync for Cells<N> {}

    impl<const N: usize> Cells<N> {
        fn new() -> Self {
            Self(std::array::from_fn(|_| UnsafeCell::new(0)))
        }
        fn get(&self, i: usize) -> usize {
            // SAFETY: loom checks this read against every write.
            self.0[i].with(|p| unsafe { *p })
        }
        fn set(&self, i: usize, v: usize) {
            // SAFETY: loom checks this write against every access.
            self.0[i].with_mut(|p| unsafe { *p = v })
        }
    }

    /// One region of a `workers`-team: the serving workers on loom threads, `driver` on this
    /// thread, then the end of the region.
    fn region(workers: usize, driver: impl FnOnce(&Crew)) {
        let team = Arc::new(Crew::new(workers));
        team.reset();
        let servers: Vec<_> = (1..workers)
            .map(|me| {
                let team = Arc::clone(&team);
                // SAFETY: one serving thread per index in 1..workers, after reset, while this
                // thread drives the region.
                loom::thread::spawn(move || unsafe { team.serve(me) })
            })
            .collect();
        {
            let _end = RegionEnd(&team);
            driver(&team);
        }
        for s in servers {
            s.join().unwrap();
        }
    }

    /// Two workers, two phases: every share of phase 2 reads what the other share wrote in
    /// phase 1 (the barrier orders them), and after `run` returns the driver may overwrite
    /// the cells (no share still uses them). The phase slot itself is a loom cell, so posting
    /// phase 2 while the serving worker still reads phase 1 would fail too.
    ///
    /// Two workers, not three: with two serving workers, loom also explores the schedules in
    /// which two waiting threads take turns yielding to each other forever while the third,
    /// which has work, never runs; those never end (over 20 000 thread switches, minutes per
    /// test). Three and more workers run in the ordinary tests above.
    #[test]
    fn phases_are_ordered_and_run_returns_after_every_share() {
        loom::model(|| {
            region(2, |team| {
                let (written, read) = (Cells::<2>::new(), Cells::<2>::new());
                // SAFETY: this thread drives the region, outside any share.
                unsafe {
                    team.run(&|j| written.set(j, j + 1));
                    team.run(&|j| read.set(j, written.get(1 - j)));
                }
                for j in 0..2 {
                    assert_eq!(read.get(j), 2 - j);
                    written.set(j, 0);
                }
            })
        });
    }

    /// Share 0 panics while the other share reads captured data: `run` unwinds only after
    /// that read, so the driver's write after catching the panic does not race it.
    #[test]
    fn a_panic_in_share_0_unwinds_after_the_other_shares() {
        loom::model(|| {
            region(2, |team| {
                let data = Cells::<1>::new();
                let r = catch_unwind(AssertUnwindSafe(|| {
                    // SAFETY: this thread drives the region, outside any share.
                    unsafe {
                        team.run(&|j| {
                            if j == 0 {
                                std::panic::resume_unwind(Box::new("share 0 fails on purpose"));
                            }
                            data.get(0);
                        })
                    }
                }));
                assert!(r.is_err());
                data.set(0, 1);
            })
        });
    }

    /// Two threads try to enter twice each: a thread inside has the data to itself. A failed
    /// attempt that released the flag (a guard dropped on failure) would let the other
    /// thread in on its second attempt, and loom would see the two accesses race.
    #[test]
    fn one_region_at_a_time() {
        loom::model(|| {
            let flag = Arc::new(AtomicBool::new(false));
            let inside = Arc::new(Cells::<1>::new());
            let threads: Vec<_> = (0..2)
                .map(|_| {
                    let (flag, inside) = (Arc::clone(&flag), Arc::clone(&inside));
                    loom::thread::spawn(move || {
                        for _ in 0..2 {
                            if let Some(_entry) = Entry::enter(&flag) {
                                inside.set(0, inside.get(0) + 1);
                            }
                        }
                    })
                })
                .collect();
            for t in threads {
                t.join().unwrap();
            }
            assert!((1..=4).contains(&inside.get(0)));
        });
    }
}
