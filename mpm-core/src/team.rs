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
//!   than cores) still make progress.

use std::cell::UnsafeCell;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};

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
        }
    }

    /// Number of workers.
    pub fn workers(&self) -> usize {
        self.workers
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
        f(0);
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
            if std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| f(me))).is_err() {
                self.panicked.store(true, Ordering::Relaxed);
            }
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
}
