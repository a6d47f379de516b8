//! The paired design: several solvers of the same set-up in one process, each on its own
//! pinned pool, advancing in timed blocks of the same number of steps, one after the other
//! in rotating order ([`alternate`]). Block `b` of every solver covers the same simulated
//! steps, so the ratio of two solvers' block times compares the same work timed moments
//! apart, under nearly the same host conditions.
//!
//! `mpm run` with a paired spec runs the `T`-thread solver and a one-thread solver of the
//! same strategy this way (its summary's `paired` section); `mpm-bench paired` runs the
//! serial solver and several strategies at 1 and `T` threads in the harness's own process.

use crate::pinning::PinnedPool;
use crate::slowdown::StepSlowdown;
use crate::usage::UsageMeter;
use mpm_core::{SimError, Simulation, StageTimes};
use mpm_spec::summary::load_imbalance;
use std::time::Instant;

/// How far a solver may step: `Some(dt_max)`, or `None` when it has reached its end (an end
/// time) and must not step again.
pub type Limit<'a> = &'a (dyn Fn(&Simulation) -> Option<f64> + Sync);

/// No end: steps of any length.
pub fn unlimited(_: &Simulation) -> Option<f64> {
    Some(f64::INFINITY)
}

/// One solver of a paired measurement: its simulation on its pool, and per block its time.
pub struct Contender<'p> {
    /// The simulation.
    pub sim: Simulation,
    /// The pool it steps on.
    pub pool: &'p PinnedPool,
    /// Seconds per step of each timed block.
    pub seconds: Vec<f64>,
    /// Load imbalance of each timed block (largest worker busy time over the mean; NaN for
    /// the serial strategy, which has no team).
    pub imbalance: Vec<f64>,
    /// Its workers' CPU time against the wall time of its timed blocks.
    pub usage: UsageMeter,
    /// Wall time of its warm-up steps (s).
    pub warmup_wall_s: f64,
    /// Its stage timers when the timed blocks began.
    pub times_at_start: StageTimes,
    /// Its workers' busy counters when the timed blocks began.
    pub busy_at_start: Option<Vec<f64>>,
    /// Steps of each timed block actually taken (fewer than asked only at an end time).
    pub steps: Vec<u64>,
    /// The injected step slowdown after each step (a test knob; `None`: off).
    pub slowdown: Option<StepSlowdown>,
}

impl<'p> Contender<'p> {
    /// `sim` stepping on `pool` (of `sim`'s thread count).
    pub fn new(sim: Simulation, pool: &'p PinnedPool) -> Self {
        let workers = pool.pool.current_num_threads();
        let times_at_start = *sim.times();
        let busy_at_start = sim.worker_busy();
        Self {
            sim,
            usage: UsageMeter::new(workers, &pool.observed_cpus()),
            pool,
            seconds: Vec::new(),
            imbalance: Vec::new(),
            warmup_wall_s: 0.0,
            times_at_start,
            busy_at_start,
            steps: Vec::new(),
            slowdown: None,
        }
    }

    /// With the injected step slowdown `fraction` after every step (`None`: none).
    pub fn with_step_slowdown(mut self, fraction: Option<f64>) -> Self {
        self.slowdown = fraction.map(StepSlowdown::new);
        self
    }

    /// Take up to `steps` steps inside the pool; returns the steps taken and their wall time.
    pub fn advance(&mut self, steps: u64, limit: Limit<'_>) -> Result<(u64, f64), SimError> {
        let pool = &self.pool.pool;
        let (sim, slowdown) = (&mut self.sim, &mut self.slowdown);
        let t0 = Instant::now();
        let taken = pool.install(|| {
            let mut taken = 0;
            while taken < steps {
                let Some(dt_max) = limit(sim) else { break };
                let step = Instant::now();
                sim.step(dt_max)?;
                if let Some(s) = slowdown.as_mut() {
                    s.after_step(pool, step.elapsed().as_secs_f64());
                }
                taken += 1;
            }
            Ok::<u64, SimError>(taken)
        })?;
        Ok((taken, t0.elapsed().as_secs_f64()))
    }

    /// The warm-up: `steps` steps, timed apart; the timed blocks start after them.
    pub fn warm_up(&mut self, steps: u64, limit: Limit<'_>) -> Result<(), SimError> {
        let (_, wall) = self.advance(steps, limit)?;
        self.warmup_wall_s = wall;
        self.times_at_start = *self.sim.times();
        self.busy_at_start = self.sim.worker_busy();
        Ok(())
    }

    /// One timed block of `steps` steps (fewer at an end time); returns the steps taken.
    pub fn block(&mut self, steps: u64, limit: Limit<'_>) -> Result<u64, SimError> {
        let busy0 = self.sim.worker_busy();
        self.usage.begin(&self.pool.pool);
        let (taken, wall) = self.advance(steps, limit)?;
        self.usage.end(&self.pool.pool);
        if taken > 0 {
            self.seconds.push(wall / taken as f64);
            self.steps.push(taken);
            let imbalance = match (busy0, self.sim.worker_busy()) {
                (Some(before), Some(after)) => {
                    let d: Vec<f64> = after.iter().zip(&before).map(|(x, y)| x - y).collect();
                    load_imbalance(&d).unwrap_or(f64::NAN)
                }
                _ => f64::NAN,
            };
            self.imbalance.push(imbalance);
        }
        Ok(taken)
    }

    /// The wall time of its timed blocks (s).
    pub fn blocks_wall_s(&self) -> f64 {
        self.seconds.iter().zip(&self.steps).map(|(s, &n)| s * n as f64).sum()
    }
}

/// The largest difference of any particle coordinate between two solvers of the same set-up
/// (m): round-off only when they ran the same steps.
pub fn max_position_difference(a: &Simulation, b: &Simulation) -> f64 {
    a.particles()
        .x
        .iter()
        .zip(&b.particles().x)
        .flat_map(|(p, q)| (0..3).map(move |k| (p[k] - q[k]).abs()))
        .fold(0.0, f64::max)
}

/// `blocks` rounds of one timed block of `block_steps` steps per contender, round `b` in the
/// order `b, b + 1, ...` (mod the count), so that every contender runs first, second, ... as
/// often as the others. Stops early after a round in which a contender reached its end
/// (`limit`): only the rounds every contender completed in full are kept. `each(round, contender)` is called after every block (progress). Returns the
/// rounds completed and, per round, the index of the contender that ran first.
pub fn alternate(
    contenders: &mut [Contender<'_>],
    blocks: u64,
    block_steps: u64,
    limit: Limit<'_>,
    mut each: impl FnMut(u64, usize),
) -> Result<(u64, Vec<usize>), SimError> {
    let n = contenders.len();
    let mut first = Vec::new();
    for b in 0..blocks {
        let mut short = false;
        for k in 0..n {
            let i = (b as usize + k) % n;
            short |= contenders[i].block(block_steps, limit)? < block_steps;
            each(b, i);
        }
        first.push(b as usize % n);
        if short {
            let done =
                contenders.iter().map(|c| c.steps.iter().take_while(|&&s| s == block_steps).count()).min().unwrap_or(0);
            for c in contenders.iter_mut() {
                c.seconds.truncate(done);
                c.imbalance.truncate(done);
                c.steps.truncate(done);
            }
            first.truncate(done);
            return Ok((done as u64, first));
        }
    }
    Ok((blocks, first))
}
