//! A team of pool workers that stays awake for a whole parallel region (a time step), so that
//! the region's many short phases start without waking sleeping threads.
//!
//! Why: a [`rayon::ThreadPool::broadcast`] costs about 1 µs when the other workers are still
//! spinning, but 17-100 µs once they have gone to sleep (measured on the 2-core development
//! VM with 20-500 µs between broadcasts), and a step has 8 (AE) to 9 + 2T (DD) phases. OpenMP,
//! which the paper uses, keeps its threads actively waiting between the phases of a parallel
//! region; a [`Team`] does the same on top of rayon:
//!
//! * [`Team::region`] is one `broadcast`: worker 0 (the *driver*) runs the region's closure,
//!   the other workers *serve* its phases until the closure has returned or unwound;
//! * a phase ([`Exec::run`]) posts the phase closure, runs share 0 on the driver and waits
//!   until every worker has run its share: a barrier at the end of every phase, as after an
//!   OpenMP worksharing loop;
//! * waiting spins for a while, then yields the CPU, so oversubscribed runs (more workers than
//!   cores) still make progress;
//! * every worker adds the time it spends in its own shares to a busy counter
//!   ([`Team::busy_seconds`]; two `Instant::now()` per worker and phase, so it stays on). The
//!   spread of the counters is the load imbalance: the solver gives every worker an equal
//!   share, so on a shared host it shows a worker whose CPU was slowed from outside.
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
//! and that a second entry is refused.

use super::exec::Exec;
use super::sync::{spin_hint, yield_now, AtomicBool, AtomicU64, AtomicUsize, Mutex, Ordering, UnsafeCell};
use rayon::ThreadPool;
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

/// Why [`Team::region`] did not run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum RegionError {
    /// Another region of this team is running (on another thread, or this region's closure
    /// tried to enter the team again).
    #[error("the team is already running a parallel region; one region runs at a time")]
    Busy,
    /// The pool's thread count is not the team's worker count.
    #[error("the team has {want} workers but the pool has {got} threads")]
    PoolSize {
        /// Threads in the pool.
        got: usize,
        /// Workers in the team.
        want: usize,
    },
}

/// A team of `workers` pool workers that runs parallel regions (see the module docs).
///
/// Build it once (one per simulation) and enter it with [`Team::region`] as often as
/// needed; the busy counters accumulate over all regions.
pub struct Team {
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

// SAFETY: the one part of a `Team` that is not thread-safe by itself is the `phase` slot
// (a plain cell holding a pointer to a `Sync` closure). It is written only by the driver
// between phases: before the Release bump of `generation` that posts the phase, and after
// the driver has seen, with Acquire, every serving worker's Release increment of `done`
// for the previous phase. Serving workers read it only after seeing the bump with Acquire
// and stop using it before their increment. So no read races a write, and the closure may be
// called from several threads at once because it is `Sync` (see the module docs).
unsafe impl Sync for Team {}
// SAFETY: as above: the pointer in `phase` is dereferenced only under that protocol while its
// region runs, and is never used again after it; nothing else in a `Team` is tied to a thread.
unsafe impl Send for Team {}

impl Team {
    /// A team of `workers` workers (the thread count of the pools it will run in).
    pub fn new(workers: usize) -> Self {
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
    pub fn workers(&self) -> usize {
        self.workers
    }

    /// Seconds each worker has spent running its shares of phases since the team was made
    /// (worker order). Exact once a region has ended.
    pub fn busy_seconds(&self) -> impl ExactSizeIterator<Item = f64> + '_ {
        self.busy.iter().map(|c| c.0.load(std::sync::atomic::Ordering::Relaxed) as f64 * 1e-9)
    }

    /// Run `f` as one parallel region in `pool`: `f` runs on pool thread 0 (the driver) and
    /// runs phases through the [`Exec`] it is given; the other pool threads serve those
    /// phases and stay awake in between. Returns `f`'s result.
    ///
    /// Returns (or re-raises a panic of `f` or of any share) only after every worker has
    /// left the region, so nothing `f` borrows is used after it. Refused with
    /// [`RegionError::Busy`] while another region of this team runs, and with
    /// [`RegionError::PoolSize`] unless the pool has exactly [`Team::workers`] threads.
    ///
    /// Do not enter a region of another team on the same pool from inside `f`: the pool's
    /// other threads are busy serving this region, so that one would never start.
    pub fn region<R, F>(&self, pool: &ThreadPool, f: F) -> Result<R, RegionError>
    where
        F: FnOnce(&Exec<'_>) -> R + Send,
        R: Send,
    {
        let got = pool.current_num_threads();
        if got != self.workers {
            return Err(RegionError::PoolSize { got, want: self.workers });
        }
        let _entry = Entry::enter(&self.entered).ok_or(RegionError::Busy)?;
        self.reset();
        let body = std::sync::Mutex::new(Some(f));
        let result = std::sync::Mutex::new(None);
        pool.broadcast(|ctx| {
            let me = ctx.index();
            if me == 0 {
                // Release the serving workers however the driver leaves: return or panic.
                let _end = RegionEnd(self);
                let f = body.lock().unwrap_or_else(std::sync::PoisonError::into_inner).take();
                let r = f.expect("worker 0 drives the region once")(&Exec::team(self));
                *result.lock().unwrap_or_else(std::sync::PoisonError::into_inner) = Some(r);
            } else {
                // SAFETY: inside this team's region, after `reset`: the entry is held until
                // the broadcast has returned, so no other region of the team runs. The pool
                // has `workers` threads, and rayon runs the broadcast once on each, so `me`
                // is in 1..workers and served once.
                unsafe { self.serve(me) };
            }
        });
        let r = result.into_inner().unwrap_or_else(std::sync::PoisonError::into_inner);
        Ok(r.expect("the driver returned, so it stored its result"))
    }

    /// Make the team ready for a region (no worker is serving: the previous region's
    /// broadcast has returned).
    fn reset(&self) {
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
    /// Only the driver of this team's current region may call it (the thread that runs the
    /// closure of [`Team::region`]; in the loom model, the thread that started the serving
    /// workers), and not from inside a share of a phase it posted.
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

    /// Driver: end the region; the serving workers return from [`Team::serve`].
    fn finish(&self) {
        self.exit.store(true, Ordering::Relaxed);
        self.generation.fetch_add(1, Ordering::Release);
    }

    /// Serving worker `me`: run share `me` of every posted phase until [`Team::finish`].
    ///
    /// # Safety
    /// Called once per region for each `me` in `1..workers`, each on its own thread, after
    /// [`Team::reset`] and while the region's driver runs (it returns after `finish`).
    unsafe fn serve(&self, me: usize) {
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

/// Holds a team's entry flag for one region.
struct Entry<'t>(&'t AtomicBool);

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
struct RegionEnd<'t>(&'t Team);

impl Drop for RegionEnd<'_> {
    fn drop(&mut self) {
        self.0.finish();
    }
}

/// Waits, when dropped, until every serving worker has finished the current phase.
struct PhaseEnd<'t>(&'t Team);

impl Drop for PhaseEnd<'_> {
    fn drop(&mut self) {
        let team = self.0;
        let others = team.workers - 1;
        wait_until(team.spins, || team.done.load(Ordering::Acquire) == others);
    }
}

#[cfg(all(test, not(loom)))]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering::SeqCst};
    use std::sync::Barrier;
    use std::time::Duration;

    fn pool(threads: usize) -> ThreadPool {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap()
    }

    /// The message of a panic payload.
    /// The team is whole again after a panic: a region runs every share once.
    fn assert_whole(pool: &ThreadPool, team: &Team, workers: usize) {
        let ran = AtomicUsize::new(0);
        team.region(pool, |exec| {
            exec.run(|_| {
                ran.fetch_add(1, SeqCst);
            })
        })
        .unwrap();
        assert_eq!(ran.load(SeqCst), workers);
    }

    fn message(payload: &(dyn Any + Send)) -> &str {
        payload
            .downcast_ref::<&str>()
            .copied()
            .or_else(|| payload.downcast_ref::<String>().map(|s| s.as_str()))
            .unwrap_or("")
    }

    /// Every phase must see every write of the previous phase (the barrier), and every
    /// share must run exactly once per phase. A missing or misordered barrier fails this.
    #[test]
    fn phases_are_separated_by_barriers() {
        for workers in [1, 2, 3, 5, 8] {
            let team = Team::new(workers);
            let slots: Vec<AtomicU64> = (0..workers).map(|_| AtomicU64::new(0)).collect();
            let errors = AtomicU64::new(0);
            // Fewer phases when the workers outnumber this machine's cores (they yield).
            let phases = if workers <= 2 { 2000u64 } else { 200 };
            team.region(&pool(workers), |exec| {
                for k in 1..=phases {
                    exec.run(|j| {
                        // The neighbour wrote k - 1 in the previous phase.
                        if slots[(j + 1) % workers].load(Ordering::Relaxed) != k - 1 {
                            errors.fetch_add(1, Ordering::Relaxed);
                        }
                    });
                    exec.run(|j| slots[j].store(k, Ordering::Relaxed));
                }
            })
            .unwrap();
            assert_eq!(errors.load(Ordering::Relaxed), 0, "{workers} workers");
            assert!(slots.iter().all(|s| s.load(Ordering::Relaxed) == phases));
        }
    }

    /// Each worker's busy counter holds the time of its own shares: worker `j` sleeps
    /// `(j + 1) x 3 ms` per phase, so its counter is at least that, and the counters keep
    /// accumulating across regions. A counter charged to the wrong worker, or reset between
    /// regions, fails this (lower bounds only, so a slow host cannot fail it).
    #[test]
    fn busy_counters_charge_each_worker_its_own_shares() {
        let workers = 2;
        let pool = pool(workers);
        let team = Team::new(workers);
        let nap = |j: usize| std::thread::sleep(Duration::from_millis(3 * (j as u64 + 1)));
        for region in 1..=2u32 {
            team.region(&pool, |exec| {
                exec.run(nap);
                exec.run(nap);
            })
            .unwrap();
            let busy: Vec<f64> = team.busy_seconds().collect();
            assert_eq!(busy.len(), workers);
            for (j, b) in busy.iter().enumerate() {
                let least = f64::from(region) * 2.0 * 0.003 * (j as f64 + 1.0);
                assert!(*b >= least, "region {region}: worker {j} busy {b} s, slept at least {least} s");
            }
        }
    }

    /// A phase in which share `failing` panics at once while every other share sleeps, then
    /// reads the phase's captured data (owned by the driver's frame) and counts itself.
    fn phase_with_a_panic(exec: &Exec<'_>, failing: usize, finished: &AtomicUsize) {
        let data: Vec<u64> = (0..1000).collect();
        exec.run(|j| {
            if j == failing {
                panic!("share {j} fails on purpose");
            }
            std::thread::sleep(Duration::from_millis(20));
            assert_eq!(data.iter().sum::<u64>(), 499_500);
            finished.fetch_add(1, SeqCst);
        });
    }

    /// A panic in share 0 (the driver's own share) while the other workers still use the
    /// phase's captured data: the phase unwinds only after they have all finished, the
    /// original panic reaches the caller of `region`, and the team works again afterwards.
    /// Without the wait on unwinding, the panic would arrive while the others still sleep
    /// (and the data they read would already be freed).
    #[test]
    fn a_panic_in_share_0_unwinds_after_every_worker_finished() {
        let workers = 3;
        let (pool, team) = (pool(workers), Team::new(workers));
        // Caught inside the region: the other shares have finished when `run` unwinds.
        let finished = AtomicUsize::new(0);
        let (caught, count) = team
            .region(&pool, |exec| {
                let r = catch_unwind(AssertUnwindSafe(|| phase_with_a_panic(exec, 0, &finished)));
                (r.is_err(), finished.load(SeqCst))
            })
            .unwrap();
        assert!(caught);
        assert_eq!(count, workers - 1, "run unwound before the other shares finished");
        // Not caught: it leaves the region with its own message, after every worker left.
        let finished = AtomicUsize::new(0);
        let err = catch_unwind(AssertUnwindSafe(|| team.region(&pool, |exec| phase_with_a_panic(exec, 0, &finished))))
            .unwrap_err();
        assert_eq!(message(&*err), "share 0 fails on purpose");
        assert_eq!(finished.load(SeqCst), workers - 1);
        assert_whole(&pool, &team, workers);
    }

    /// A panic in another worker's share: re-raised on the driver, with its own message,
    /// after every other share has finished; the team works again afterwards.
    #[test]
    fn a_panic_in_a_serving_workers_share_reaches_the_caller() {
        let workers = 3;
        let (pool, team) = (pool(workers), Team::new(workers));
        for failing in 1..workers {
            let finished = AtomicUsize::new(0);
            let (message_seen, count) = team
                .region(&pool, |exec| {
                    let err = catch_unwind(AssertUnwindSafe(|| phase_with_a_panic(exec, failing, &finished)))
                        .expect_err("the share's panic is re-raised on the driver");
                    (message(&*err).to_string(), finished.load(SeqCst))
                })
                .unwrap();
            assert_eq!(message_seen, format!("share {failing} fails on purpose"));
            assert_eq!(count, workers - 1);
            let finished = AtomicUsize::new(0);
            let err = catch_unwind(AssertUnwindSafe(|| {
                team.region(&pool, |exec| phase_with_a_panic(exec, failing, &finished))
            }))
            .unwrap_err();
            assert_eq!(message(&*err), format!("share {failing} fails on purpose"));
            assert_eq!(finished.load(SeqCst), workers - 1);
        }
        assert_whole(&pool, &team, workers);
    }

    /// A panic in the driver between phases ends the region too (the serving workers are
    /// released instead of waiting for a phase forever).
    #[test]
    fn a_panic_between_phases_releases_the_workers() {
        let (pool, team) = (pool(2), Team::new(2));
        let err = catch_unwind(AssertUnwindSafe(|| {
            team.region(&pool, |exec| {
                exec.run(|_| {});
                panic!("the driver fails between phases");
            })
        }))
        .unwrap_err();
        assert_eq!(message(&*err), "the driver fails between phases");
        assert_eq!(team.region(&pool, |exec| exec.workers()), Ok(2));
    }

    /// While a region runs, a second entry is refused: from another thread (on another
    /// pool) and from inside the region itself. Once it has ended, the team can be entered
    /// again.
    #[test]
    fn a_second_entry_is_refused_while_a_region_runs() {
        let team = Team::new(2);
        let (pool_a, pool_b) = (pool(2), pool(2));
        let (inside, leave) = (Barrier::new(2), Barrier::new(2));
        std::thread::scope(|s| {
            let first = s.spawn(|| {
                team.region(&pool_a, |exec| {
                    let nested = team.region(&pool_b, |_| ());
                    inside.wait();
                    leave.wait();
                    exec.run(|_| {});
                    nested
                })
            });
            inside.wait();
            assert_eq!(team.region(&pool_b, |_| ()), Err(RegionError::Busy));
            leave.wait();
            assert_eq!(first.join().unwrap(), Ok(Err(RegionError::Busy)), "a nested entry is refused");
        });
        assert_eq!(team.region(&pool_b, |exec| exec.workers()), Ok(2));
    }

    #[test]
    fn a_pool_of_the_wrong_size_is_refused() {
        let team = Team::new(3);
        assert_eq!(team.region(&pool(2), |_| ()), Err(RegionError::PoolSize { got: 2, want: 3 }));
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
    fn region(workers: usize, driver: impl FnOnce(&Team)) {
        let team = Arc::new(Team::new(workers));
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
