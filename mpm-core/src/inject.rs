//! The injected slowdown: a test knob that makes a parallel run lose a known share of its
//! parallel efficiency, so that a regression gate can be shown a regression of known size
//! ([`crate::SimConfig::inject_slowdown`], `mpm run --inject-slowdown F`). Never a result:
//! the summary and the harness's rows record it, and the analyses refuse such rows unless
//! asked.
//!
//! Every step, after the grid update (booked to the grid-node stage), every worker but the
//! first runs a fixed number of iterations of a dependent multiply-add chain while the first
//! waits at the phase's barrier. The number is chosen so that the phase lasts
//! `F / (1 - F)` times the step without it: the `T`-thread step then takes `1 / (1 - F)`
//! times as long and its efficiency `T_1 / (T T_T)` drops by the fraction `F`, while the
//! one-thread run (a single worker: nothing to add) keeps its time. The iterations follow
//! the host: each step measures the previous step's time without the extra work and the
//! time one iteration took, so the share stays `F` on a slower or faster machine. The chain
//! goes through [`std::hint::black_box`] (no optimiser can drop or shorten it) and touches
//! no memory (nothing allocated, nothing shared). The work counters ([`crate::work`]) do not
//! count it.

use crate::parallel::Exec;
use std::hint::black_box;
use std::time::Instant;

/// Iterations of the first step's phase, which only measures the time of one.
const FIRST_ITERATIONS: u64 = 1 << 12;
/// At most this many iterations per step (a bound against a wrong measurement).
const MAX_ITERATIONS: u64 = 1 << 40;

/// The extra work of one worker: `iterations` dependent multiply-adds; returns the chain's
/// end so that it is used.
#[inline(never)]
pub fn busy_work(iterations: u64) -> f64 {
    let (a, b) = (black_box(0.999_999_9), black_box(1.0e-7));
    let mut x = black_box(2.0);
    for _ in 0..iterations {
        x = x * a + b;
    }
    black_box(x)
}

/// The injection state of one simulation.
#[derive(Clone, Debug)]
pub(crate) struct Injection {
    /// The efficiency share to remove, in (0, 1).
    fraction: f64,
    /// The stage timers' total at the previous injection point (`None` before the first).
    mark: Option<f64>,
    /// Seconds the previous step's injected phase took.
    spent: f64,
    /// Seconds per iteration, as last measured.
    seconds_per_iteration: Option<f64>,
    /// Seconds injected over every step (for the summary).
    pub total_seconds: f64,
}

impl Injection {
    /// An injection of `fraction` (checked by the caller to lie in (0, 1)).
    pub fn new(fraction: f64) -> Self {
        Self { fraction, mark: None, spent: 0.0, seconds_per_iteration: None, total_seconds: 0.0 }
    }

    /// The injected phase of a step: `timers_total` is the stage timers' total now (every
    /// earlier step's time and this step's so far). Returns the seconds it took, which the
    /// caller books to the grid-node stage.
    pub fn run(&mut self, exec: &Exec<'_>, timers_total: f64) -> f64 {
        let iterations = match (self.mark, self.seconds_per_iteration) {
            (Some(mark), Some(per)) if per > 0.0 => {
                // One whole step since the last injection point, less what was injected.
                let clean = (timers_total - mark - self.spent).max(0.0);
                let target = self.fraction / (1.0 - self.fraction) * clean;
                ((target / per).round() as u64).min(MAX_ITERATIONS)
            }
            _ => FIRST_ITERATIONS,
        };
        let start = Instant::now();
        exec.run(|w| {
            if w > 0 {
                busy_work(iterations);
            }
        });
        let spent = start.elapsed().as_secs_f64();
        if iterations > 0 {
            let per = spent / iterations as f64;
            // A running mean: one slow phase (a preempted worker) moves it by half.
            self.seconds_per_iteration = Some(self.seconds_per_iteration.map_or(per, |p| 0.5 * (p + per)));
        }
        self.mark = Some(timers_total);
        self.spent = spent;
        self.total_seconds += spent;
        spent
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_chain_is_computed() {
        assert_eq!(busy_work(0), 2.0);
        // x -> a x + b decays towards b / (1 - a) = 1.
        let x = busy_work(1000);
        assert!(x < 2.0 && x > 1.99, "{x}");
    }
}
