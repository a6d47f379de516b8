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
//! The protocol itself, and every unsafe step of it, is the team's crew (`crew.rs`); a team
//! is that crew on the pool it was built with, whose thread count is its worker count.

use super::crew::{Crew, RegionEnd};
use super::exec::Exec;
use rayon::ThreadPool;
use std::sync::Arc;

/// Why [`Team::region`] did not run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum RegionError {
    /// Another region of this team is running (on another thread, or this region's closure
    /// tried to enter the team again).
    #[error("the team is already running a parallel region; one region runs at a time")]
    Busy,
}

/// A team of the workers of a pool that runs parallel regions on it (see the module docs):
/// one worker per pool thread.
///
/// Build it once (one per simulation) and enter it with [`Team::region`] as often as
/// needed; the busy counters accumulate over all regions.
pub struct Team {
    /// The pool the regions run on.
    pool: Arc<ThreadPool>,
    /// The protocol's shared state, for the pool's thread count.
    crew: Crew,
}

impl Team {
    /// A team of the workers of `pool` (as many as it has threads).
    pub fn new(pool: Arc<ThreadPool>) -> Self {
        let crew = Crew::new(pool.current_num_threads());
        Self { pool, crew }
    }

    /// Number of workers: the pool's thread count.
    pub fn workers(&self) -> usize {
        self.crew.workers()
    }

    /// The pool the team runs on.
    pub fn pool(&self) -> &Arc<ThreadPool> {
        &self.pool
    }

    /// Seconds each worker has spent running its shares of phases since the team was made
    /// (worker order). Exact once a region has ended.
    pub fn busy_seconds(&self) -> impl ExactSizeIterator<Item = f64> + '_ {
        self.crew.busy_seconds()
    }

    /// Run `f` as one parallel region on the team's pool: `f` runs on pool thread 0 (the
    /// driver) and runs phases through the [`Exec`] it is given; the other pool threads serve
    /// those phases and stay awake in between. Returns `f`'s result.
    ///
    /// Returns (or re-raises a panic of `f` or of any share) only after every worker has
    /// left the region, so nothing `f` borrows is used after it. Refused with
    /// [`RegionError::Busy`] while another region of this team runs.
    ///
    /// Do not enter a region of another team on the same pool from inside `f`: the pool's
    /// other threads are busy serving this region, so that one would never start.
    pub fn region<R, F>(&self, f: F) -> Result<R, RegionError>
    where
        F: FnOnce(&Exec<'_>) -> R + Send,
        R: Send,
    {
        let crew = &self.crew;
        let _entry = crew.enter().ok_or(RegionError::Busy)?;
        crew.reset();
        let body = std::sync::Mutex::new(Some(f));
        let result = std::sync::Mutex::new(None);
        self.pool.broadcast(|ctx| {
            let me = ctx.index();
            if me == 0 {
                // Release the serving workers however the driver leaves: return or panic.
                let _end = RegionEnd(crew);
                let f = body.lock().unwrap_or_else(std::sync::PoisonError::into_inner).take();
                let r = f.expect("worker 0 drives the region once")(&Exec::team(crew));
                *result.lock().unwrap_or_else(std::sync::PoisonError::into_inner) = Some(r);
            } else {
                // SAFETY: inside this team's region, after `reset`: the entry is held until
                // the broadcast has returned, so no other region of the team runs. The crew
                // has a worker for each of the pool's threads (`Team::new`), and rayon runs
                // the broadcast once on each, so `me` is in 1..workers and served once.
                unsafe { crew.serve(me) };
            }
        });
        let r = result.into_inner().unwrap_or_else(std::sync::PoisonError::into_inner);
        Ok(r.expect("the driver returned, so it stored its result"))
    }
}

#[cfg(all(test, not(loom)))]
mod tests {
    use super::*;
    use std::any::Any;
    use std::panic::{catch_unwind, AssertUnwindSafe};
    use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering, Ordering::SeqCst};
    use std::sync::Barrier;
    use std::time::Duration;

    /// A team on a pool of `threads` threads.
    fn team(threads: usize) -> Team {
        Team::new(crate::testing::pool(threads))
    }

    /// The team is whole again after a panic: a region runs every share once.
    fn assert_whole(team: &Team, workers: usize) {
        let ran = AtomicUsize::new(0);
        team.region(|exec| {
            exec.run(|_| {
                ran.fetch_add(1, SeqCst);
            })
        })
        .unwrap();
        assert_eq!(ran.load(SeqCst), workers);
    }

    /// The message of a panic payload.
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
            let team = team(workers);
            let slots: Vec<AtomicU64> = (0..workers).map(|_| AtomicU64::new(0)).collect();
            let errors = AtomicU64::new(0);
            // Fewer phases when the workers outnumber this machine's cores (they yield).
            let phases = if workers <= 2 { 2000u64 } else { 200 };
            team.region(|exec| {
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
        let team = team(workers);
        let nap = |j: usize| std::thread::sleep(Duration::from_millis(3 * (j as u64 + 1)));
        for region in 1..=2u32 {
            team.region(|exec| {
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
        let team = team(workers);
        // Caught inside the region: the other shares have finished when `run` unwinds.
        let finished = AtomicUsize::new(0);
        let (caught, count) = team
            .region(|exec| {
                let r = catch_unwind(AssertUnwindSafe(|| phase_with_a_panic(exec, 0, &finished)));
                (r.is_err(), finished.load(SeqCst))
            })
            .unwrap();
        assert!(caught);
        assert_eq!(count, workers - 1, "run unwound before the other shares finished");
        // Not caught: it leaves the region with its own message, after every worker left.
        let finished = AtomicUsize::new(0);
        let err =
            catch_unwind(AssertUnwindSafe(|| team.region(|exec| phase_with_a_panic(exec, 0, &finished)))).unwrap_err();
        assert_eq!(message(&*err), "share 0 fails on purpose");
        assert_eq!(finished.load(SeqCst), workers - 1);
        assert_whole(&team, workers);
    }

    /// A panic in another worker's share: re-raised on the driver, with its own message,
    /// after every other share has finished; the team works again afterwards.
    #[test]
    fn a_panic_in_a_serving_workers_share_reaches_the_caller() {
        let workers = 3;
        let team = team(workers);
        for failing in 1..workers {
            let finished = AtomicUsize::new(0);
            let (message_seen, count) = team
                .region(|exec| {
                    let err = catch_unwind(AssertUnwindSafe(|| phase_with_a_panic(exec, failing, &finished)))
                        .expect_err("the share's panic is re-raised on the driver");
                    (message(&*err).to_string(), finished.load(SeqCst))
                })
                .unwrap();
            assert_eq!(message_seen, format!("share {failing} fails on purpose"));
            assert_eq!(count, workers - 1);
            let finished = AtomicUsize::new(0);
            let err =
                catch_unwind(AssertUnwindSafe(|| team.region(|exec| phase_with_a_panic(exec, failing, &finished))))
                    .unwrap_err();
            assert_eq!(message(&*err), format!("share {failing} fails on purpose"));
            assert_eq!(finished.load(SeqCst), workers - 1);
        }
        assert_whole(&team, workers);
    }

    /// A panic in the driver between phases ends the region too (the serving workers are
    /// released instead of waiting for a phase forever).
    #[test]
    fn a_panic_between_phases_releases_the_workers() {
        let team = team(2);
        let err = catch_unwind(AssertUnwindSafe(|| {
            team.region(|exec| {
                exec.run(|_| {});
                panic!("the driver fails between phases");
            })
        }))
        .unwrap_err();
        assert_eq!(message(&*err), "the driver fails between phases");
        assert_eq!(team.region(|exec| exec.workers()), Ok(2));
    }

    /// While a region runs, a second entry is refused: from another thread and from inside
    /// the region itself. Once it has ended, the team can be entered again.
    #[test]
    fn a_second_entry_is_refused_while_a_region_runs() {
        let team = team(2);
        let (inside, leave) = (Barrier::new(2), Barrier::new(2));
        std::thread::scope(|s| {
            let first = s.spawn(|| {
                team.region(|exec| {
                    let nested = team.region(|_| ());
                    inside.wait();
                    leave.wait();
                    exec.run(|_| {});
                    nested
                })
            });
            inside.wait();
            assert_eq!(team.region(|_| ()), Err(RegionError::Busy));
            leave.wait();
            assert_eq!(first.join().unwrap(), Ok(Err(RegionError::Busy)), "a nested entry is refused");
        });
        assert_eq!(team.region(|exec| exec.workers()), Ok(2));
    }

    /// The team has one worker per thread of its pool, and a region runs a share on each.
    #[test]
    fn the_team_has_the_pools_threads() {
        for threads in [1, 2, 3] {
            let team = team(threads);
            assert_eq!(team.workers(), threads);
            assert_eq!(team.pool().current_num_threads(), threads);
            assert_whole(&team, threads);
        }
    }
}
