//! The injected step slowdown: a test knob that makes every step of a run take `1 / (1 - F)`
//! times as long on every worker alike (`mpm run --inject-step-slowdown F`,
//! `mpm_spec::RunSpec::inject_step_slowdown`), so that a gate on the time per step can be
//! shown a regression of known size that leaves the parallel efficiency where it was.
//!
//! After each step, every worker of the solver's pool spins until one deadline, `F / (1 - F)`
//! times the step's own wall time later: the step with it takes `step / (1 - F)`, the steps
//! per second drop by `F`. A paired run slows its one-thread reference the same way, so the
//! ratio of the two (the paired efficiency) stays. The wait is on the clock, not a count of
//! instructions, so its share is `F` on a fast or a slow host; it touches no memory and
//! changes no result. Never a result: the summary records it (`inject_step_slowdown`,
//! `injected_step_s`), and the harness's analyses refuse such runs unless asked. (The knob
//! that moves the efficiency instead, `--inject-slowdown`, is the solver's own: every worker
//! but the first works longer.)

use rayon::ThreadPool;
use std::time::{Duration, Instant};

/// The step slowdown of one solver.
#[derive(Clone, Debug)]
pub struct StepSlowdown {
    /// The share of the steps per second to remove, in (0, 1).
    fraction: f64,
    /// Seconds added over every step so far.
    pub total_s: f64,
}

impl StepSlowdown {
    /// A slowdown of `fraction` (checked by the run's spec to lie in (0, 1)).
    pub fn new(fraction: f64) -> Self {
        Self { fraction, total_s: 0.0 }
    }

    /// After a step that took `step_s` seconds: every worker of `pool` spins until
    /// `F / (1 - F) step_s` has passed (all to one deadline). Returns the seconds it added.
    /// Called between steps, never inside one (the workers are free then), from the pool's
    /// driver or from outside the pool.
    pub fn after_step(&mut self, pool: &ThreadPool, step_s: f64) -> f64 {
        let extra = self.fraction / (1.0 - self.fraction) * step_s.max(0.0);
        let start = Instant::now();
        let deadline = start + Duration::from_secs_f64(extra);
        pool.broadcast(|_| {
            while Instant::now() < deadline {
                std::hint::spin_loop();
            }
        });
        let spent = start.elapsed().as_secs_f64();
        self.total_s += spent;
        spent
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The added time is F / (1 - F) of the step's (at least; the broadcast adds a little).
    #[test]
    fn adds_its_share_of_the_step() {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        let mut s = StepSlowdown::new(0.5);
        let spent = pool.install(|| s.after_step(&pool, 0.01));
        assert!(spent >= 0.01, "{spent}");
        assert_eq!(s.total_s, spent);
        assert!(StepSlowdown::new(0.1).after_step(&pool, 0.0) < 0.01);
    }
}
