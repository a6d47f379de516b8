//! A team of pool workers that stays awake for a whole time step, so that the step's many
//! short parallel phases start without waking sleeping threads.
//!
//! Why: a [`rayon::ThreadPool::broadcast`] costs about 1 µs when the other workers are
//! still spinning, but 17-100 µs once they have gone to sleep (measured on the 2-core
//! development VM with 20-500 µs between broadcasts). A step has 8 (AE) to 9 + 2T (DD)
//! parallel phases, so on Model 1 at 2 threads the wake-ups alone cost about 15 % of the
//! step. OpenMP, which the paper uses, keeps its threads actively waiting between the
//! phases of a parallel region; a [`Team`] does the same on top of rayon:
//!
//! * the step is one `broadcast`: worker 0 runs the step (the driver), the other workers
//!   [`Team::serve`] phases until the driver finishes;
//! * [`Team::run`] posts a phase, runs share 0 itself and waits until every worker has run
//!   its share: a barrier at the end of every phase, as in an OpenMP worksharing loop;
//! * waiting spins for a while, then yields the CPU, so oversubscribed runs (more workers
//!   than cores) still make progress;
//! * every worker adds the time it spends in its own shares to a busy counter
//!   ([`Team::busy_seconds`]). Two `Instant::now()` per worker and phase, so it stays on.
//!   The spread of the counters is the load imbalance: on a shared host it shows a worker
//!   whose CPU was slowed from outside (measured on the development VM: the same
//!   stress-update share took 9.6 ms on one worker and 19.8 ms on the other for a whole
//!   run, then 9.6 ms on both in the next run).

use std::cell::UnsafeCell;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::time::Instant;

/// A phase: share `j` of some parallel work (stored with its lifetime erased).
type Phase = dyn Fn(usize) + Sync + 'static;

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
            std::hint::spin_loop();
            spins += 1;
        } else {
            std::thread::yield_now();
        }
    }
}

/// One worker's busy time in nanoseconds, alone on its cache lines (each worker writes only
/// its own counter, once per phase; sharing a line would make that a coherence miss).
#[repr(align(128))]
#[derive(Default)]
struct BusyCounter(AtomicU64);

impl BusyCounter {
    /// Add the time since `start`.
    #[inline]
    fn charge(&self, start: Instant) {
        let ns = u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX);
        self.0.fetch_add(ns, Ordering::Relaxed);
    }
}

/// Shared state of one team (see the module docs).
pub struct Team {
    workers: usize,
    spins: u32,
    /// Phase generation, bumped by the driver to post a phase (or the exit).
    generation: AtomicU64,
    /// Workers other than the driver that finished the current phase.
    done: AtomicUsize,
    /// Set before the last generation bump: the serving workers return.
    exit: AtomicBool,
    /// A serving worker's share panicked.
    panicked: AtomicBool,
    /// The current phase; written by the driver only between phases.
    phase: UnsafeCell<Option<*const Phase>>,
    /// Per worker: nanoseconds spent in its shares since the team was made.
    busy: Box<[BusyCounter]>,
}

// SAFETY: `phase` is written only by the driver while no serving worker reads it (before it
// bumps `generation` with Release, after every worker has reported `done` with Release),
// and read by serving workers only after observing the bump with Acquire. The pointee is
// `Sync`, so calling it from several threads at once is allowed.
unsafe impl Sync for Team {}
// SAFETY: as above; the raw pointer is only dereferenced under that protocol.
unsafe impl Send for Team {}

impl Team {
    /// A team of `workers` (the pool's thread count).
    pub fn new(workers: usize) -> Self {
        let hardware = std::thread::available_parallelism().map_or(1, |n| n.get());
        Self {
            workers,
            spins: if workers > hardware { SPINS_OVERSUBSCRIBED } else { SPINS },
            generation: AtomicU64::new(0),
            done: AtomicUsize::new(0),
            exit: AtomicBool::new(false),
            panicked: AtomicBool::new(false),
            phase: UnsafeCell::new(None),
            busy: (0..workers).map(|_| BusyCounter::default()).collect(),
        }
    }

    /// Number of workers.
    pub fn workers(&self) -> usize {
        self.workers
    }

    /// Seconds each worker has spent running its shares of phases since the team was made
    /// (worker order). Exact once the region has ended; [`Team::reset`] keeps them.
    pub fn busy_seconds(&self) -> impl ExactSizeIterator<Item = f64> + '_ {
        self.busy.iter().map(|c| c.0.load(Ordering::Relaxed) as f64 * 1e-9)
    }

    /// Make the team ready for a new region (call before the broadcast).
    pub fn reset(&mut self) {
        *self.generation.get_mut() = 0;
        *self.done.get_mut() = 0;
        *self.exit.get_mut() = false;
        *self.panicked.get_mut() = false;
        *self.phase.get_mut() = None;
    }

    /// Driver only (worker 0): run `f(j)` on every worker `j` and return when all are done.
    pub fn run<'f>(&self, f: &'f (dyn Fn(usize) + Sync + 'f)) {
        // SAFETY: the lifetime of `f` is erased to store it in the shared slot. The serving
        // workers call it only between the generation bump below and their `done`
        // increment, and this function does not return (so `f` stays alive) before all of
        // them have incremented `done`. No worker reads the slot again before the next bump.
        let erased: *const Phase = unsafe { std::mem::transmute::<&'f (dyn Fn(usize) + Sync + 'f), &'static Phase>(f) };
        // SAFETY: no serving worker reads the slot now (they all finished the previous phase
        // and wait for the next generation), so the driver has exclusive access.
        unsafe { *self.phase.get() = Some(erased) };
        self.done.store(0, Ordering::Relaxed);
        self.generation.fetch_add(1, Ordering::Release);
        let start = Instant::now();
        f(0);
        self.busy[0].charge(start);
        let others = self.workers - 1;
        wait_until(self.spins, || self.done.load(Ordering::Acquire) == others);
        if self.panicked.load(Ordering::Relaxed) {
            panic!("a worker of the team panicked in a parallel phase");
        }
    }

    /// Driver only: release the serving workers at the end of the region.
    pub fn finish(&self) {
        self.exit.store(true, Ordering::Relaxed);
        self.generation.fetch_add(1, Ordering::Release);
    }

    /// Serving workers (`me > 0`): run every posted phase's share `me` until [`Team::finish`].
    pub fn serve(&self, me: usize) {
        let mut seen = 0u64;
        loop {
            wait_until(self.spins, || self.generation.load(Ordering::Acquire) != seen);
            seen = self.generation.load(Ordering::Acquire);
            if self.exit.load(Ordering::Relaxed) {
                return;
            }
            // SAFETY: the Acquire load above synchronises with the driver's Release bump,
            // after which the slot holds a live phase until this worker reports `done`.
            let f = unsafe { (*self.phase.get()).expect("a phase is posted with every generation") };
            // SAFETY: see `run`: the pointee outlives this call.
            let f = unsafe { &*f };
            let start = Instant::now();
            if std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| f(me))).is_err() {
                self.panicked.store(true, Ordering::Relaxed);
            }
            self.busy[me].charge(start);
            self.done.fetch_add(1, Ordering::Release);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicU64;

    /// Every phase must see every write of the previous phase (the barrier), and every
    /// share must run exactly once per phase. A missing or misordered barrier fails this.
    #[test]
    fn phases_are_separated_by_barriers() {
        for workers in [2, 3, 5, 8] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(workers).build().unwrap();
            let mut team = Team::new(workers);
            team.reset();
            let slots: Vec<AtomicU64> = (0..workers).map(|_| AtomicU64::new(0)).collect();
            let errors = AtomicU64::new(0);
            // Fewer phases when the workers outnumber this machine's cores (they yield).
            let phases = if workers <= 2 { 2000u64 } else { 200 };
            pool.broadcast(|ctx| {
                if ctx.index() == 0 {
                    for k in 1..=phases {
                        team.run(&|j| {
                            // The neighbour wrote k - 1 in the previous phase.
                            let n = slots[(j + 1) % workers].load(Ordering::Relaxed);
                            if n != k - 1 {
                                errors.fetch_add(1, Ordering::Relaxed);
                            }
                        });
                        team.run(&|j| slots[j].store(k, Ordering::Relaxed));
                    }
                    team.finish();
                } else {
                    team.serve(ctx.index());
                }
            });
            assert_eq!(errors.load(Ordering::Relaxed), 0, "{workers} workers");
            assert!(slots.iter().all(|s| s.load(Ordering::Relaxed) == phases));
        }
    }

    /// Each worker's busy counter holds the time of its own shares: worker `j` sleeps
    /// `(j + 1) x 3 ms` per phase, so its counter is at least that, and the counters keep
    /// accumulating across regions. A counter charged to the wrong worker, or reset by
    /// `reset`, fails this (lower bounds only, so a slow host cannot fail it).
    #[test]
    fn busy_counters_charge_each_worker_its_own_shares() {
        let workers = 2;
        let pool = rayon::ThreadPoolBuilder::new().num_threads(workers).build().unwrap();
        let mut team = Team::new(workers);
        let nap = |j: usize| std::thread::sleep(std::time::Duration::from_millis(3 * (j as u64 + 1)));
        for region in 1..=2u32 {
            team.reset();
            pool.broadcast(|ctx| {
                if ctx.index() == 0 {
                    team.run(&nap);
                    team.run(&nap);
                    team.finish();
                } else {
                    team.serve(ctx.index());
                }
            });
            let busy: Vec<f64> = team.busy_seconds().collect();
            assert_eq!(busy.len(), workers);
            for (j, b) in busy.iter().enumerate() {
                let least = f64::from(region) * 2.0 * 0.003 * (j as f64 + 1.0);
                assert!(*b >= least, "region {region}: worker {j} busy {b} s, slept at least {least} s");
            }
        }
        assert_eq!(Team::new(0).busy_seconds().len(), 0);
    }
}
